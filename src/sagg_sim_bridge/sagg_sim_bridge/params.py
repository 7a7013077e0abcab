"""Parameters of the MuJoCo bridge (ROS-free schema; the node declares them with descriptors).

One ``arm.*`` schema for both arms: ``arm.model`` empty (the default) is the generated planar arm
(:class:`.arm.ArmSpec`, its geometry fields); ``arm.model`` set is a robot from its MJCF/URDF file
(:class:`.model_arm.ModelArmSpec`): the planar-only fields are then ignored and the model fields
apply. ``arm.mode``, ``arm.motor_noise`` and the dynamic-mode fields mean the same for both."""
from __future__ import annotations

import dataclasses

from sagg_common.params import ConfigError, Param, Schema, dataclass_schema
from sagg_common.scene_params import SCENE_PARAMS, SceneParams

from .arm import ArmSpec
from .model_arm import SHARED_FIELDS, ModelArmSpec

_PLANAR = " (planar arm only: ignored when arm.model is set)"
_ARM_DOC = {
    "dof": "Number of joints of the planar arm (paper: 7, 15, 30; real arm 8).",
    "total_length": "Total arm length in task units (paper: 50).",
    "link_profile": "'equal' links or 'golden' (each link φ times the next, decreasing from the base).",
    "link_ratio": "l_i = l_{i-1}/link_ratio, normalised to total_length (1 = equal, 1.618... = "
                  "golden, 1.5 = config/arm7_ratio15.yaml). 0 = the ratio link_profile names; a "
                  "nonzero value needs link_profile 'equal'.",
    "joint_limit": "Symmetric limit ±rad of joints 1..n-1 (paper: none given; ours ±π/2).",
    "base_limit": "Symmetric limit ±rad of the base joint (ours ±π/2: the arm faces x ≥ 0).",
    "rest_bend": "Total bend (rad) of the rest posture, spread over the joints; tip on +x.",
    "rest_shape": "'arc': rest bend spread evenly one way (a C; default: right when the base "
                  "joint's range covers every direction of Y, as on the paper's arm); 'zigzag': "
                  "alternately ±rest_bend/(dof-1), no net curl, so the goal's side chooses how the arm "
                  "curls (needed when the base range does not cover Y, e.g. config/arm7_ratio15.yaml; "
                  "near-singular, so use it with the learner's reach_damping; see arm.py ArmSpec).",
    "mode": "'kinematic' (ideal position control, kinematics only) or 'dynamic' (MuJoCo physics, "
            "position actuators, settle criterion).",
    "motor_noise": "Multiplicative motor noise: realised Δα = Δα·(1 + noise·N(0,1)) per joint "
                   "(paper real arm: 20% -> 0.2).",
    "timestep": "Dynamic mode: physics step (s).",
    "kp": "Dynamic mode: position actuator gain.",
    "damping": "Dynamic mode: joint damping.",
    "armature": "Dynamic mode: rotor inertia per joint.",
    "arm_mass": "Dynamic mode: total link mass.",
    "settle_tolerance": "Dynamic mode: settled when max |q − target| is below this (rad) ...",
    "settle_velocity": "Dynamic mode: ... and max |q̇| below this (rad/s).",
    "max_settle_steps": "Dynamic mode: give up settling after this many physics steps.",
    "settle_check_every": "Dynamic mode: physics steps between settle checks.",
}


for _f in dataclasses.fields(ArmSpec):
    if _f.name not in SHARED_FIELDS:
        _ARM_DOC[_f.name] += _PLANAR

# The model arm's own parameters (used only when arm.model is set; rest_posture is not under arm.:
# the config gives it once under '/**' for every node that needs it). List parameters cannot be empty
# (ROS parameter arrays need a type): "not given" is a documented one-element default.
MODEL_SCHEMA: Schema = (
    Param("arm.model", "str", "",
          "Robot model file: MuJoCo MJCF (.xml) or URDF (.urdf), relative to the config file's directory. "
          "Empty (default) = the generated planar arm (arm.dof, arm.total_length, ...). When set, the "
          "planar-only arm.* fields are ignored and the arm.* model fields apply."),
    Param("arm.package_paths", "str_list", ["."],
          "Model arm: directories holding ROS package folders, for package://PKG/... URIs in the model "
          "(looked up as <dir>/PKG/..., then as <prefix>/share/PKG/... for each AMENT_PREFIX_PATH prefix); "
          "relative to the config file's directory. Default ['.']: the config's own directory. A mesh "
          "found nowhere is dropped in kinematic mode (said once, naming the files), an error in dynamic "
          "mode."),
    Param("arm.effector", "str", "",
          "Model arm: name of the body / URDF link (its origin) or site whose world position is the "
          "effector (e.g. tool0, flange). Required when arm.model is set; an unknown name is an error "
          "listing the model's bodies and sites."),
    Param("arm.task_axes", "str", "xyz",
          "Model arm: the world coordinates forming the task point, in that order: 'xyz' (default) or two "
          "of them ('xy' for a camera looking down on a table, 'xz', 'yz'). task_space.lower/upper then "
          "have one value per axis; the task point travels as a PointStamped's x, y (, z) in this order. "
          "(A string, not a list: a ROS parameter file reads a bare y as a boolean.)",
          choices=("xyz", "xy", "xz", "yz")),
    Param("arm.joints", "str_list", ["*"],
          "Model arm: the commanded joints, in command order. Default ['*']: every hinge/slide joint that "
          "moves the effector, in model order; the model's other joints are held at their rest value."),
    Param("arm.joint_limits.lower", "float_list", [0.0],
          "Model arm: lower joint limits (rad or m), one per commanded joint, with arm.joint_limits.upper. "
          "Default [0.0] (with upper [0.0]) = not given: the model's joint ranges; needed when a commanded "
          "joint has no range in the model; when given they must lie within the model's ranges."),
    Param("arm.joint_limits.upper", "float_list", [0.0],
          "Model arm: upper joint limits, one per commanded joint (see arm.joint_limits.lower)."),
    Param("arm.calibration.length_scale", "float", 1.0,
          "Model arm, simulated only: a calibration gap (sagg_sim_bridge/calibration.py): every translation "
          "of the chain (link lengths, tool offset) times this factor. 1 = the arm is its model file. The "
          "learner's model and a prior from a nominal simulation do not know it; the published task point "
          "and the evaluation do.", low=0.5, high=2.0),
    Param("arm.calibration.joint_offsets", "float_list", [],
          "Model arm, simulated only: joint zero offsets (rad), one per commanded joint: the true angle is "
          "the reported one plus the offset, as on an arm whose encoder zeros differ from its URDF. [] = "
          "none.", empty_ok=True),
    Param("rest_posture", "float_list", [0.0],
          "Model arm: rest posture, one value per commanded joint (arm.joints order), used when the model "
          "has no keyframe named 'home' (which wins when present). Not under arm.: give it once in the "
          "config's '/**' section, where the learner node reads the same parameter. Default [0.0] = not "
          "given (then the model needs the keyframe; a 1-joint arm resting at 0 too). Ignored by the "
          "planar arm."),
)

# scene.* (sagg_common.scene_params): given once under '/**', read by the learner (which checks every
# move) and by the simulated arm (its physics meets the floor and boxes; it counts the contacts)
SCHEMA: Schema = (
    Param("seed", "int", 0, "Run seed; the simulator's motor-noise stream is derived from it.", low=0),
) + dataclass_schema("arm", ArmSpec, _ARM_DOC, {"link_profile": ("equal", "golden"), "rest_shape": ("arc", "zigzag"),
                                               "mode": ("kinematic", "dynamic")}) + MODEL_SCHEMA + SCENE_PARAMS


def arm_spec_from_params(params: dict, base_dir: str | None = None) -> ArmSpec | ModelArmSpec:
    """Build and validate the arm from resolved ``arm.*`` parameters (errors name the parameter):
    the planar :class:`ArmSpec` when ``arm.model`` is empty, else a :class:`ModelArmSpec` whose
    relative paths are resolved against ``base_dir`` (the config file's directory). A model arm
    meets the scene ``scene.*`` when it declares a floor or boxes (the spec's ``scene``, else
    None: the arm as without a scene); the planar arm has no scene (ConfigError if one is declared)."""
    fields = {k[len("arm."):]: v for k, v in params.items() if k.startswith("arm.")}
    scene = SceneParams.from_params(params)
    if fields.get("model", ""):
        if "rest_posture" in params:
            fields["rest_posture"] = params["rest_posture"]
        return ModelArmSpec.from_params(fields, base_dir, scene if scene.obstacles else None)
    if fields.get("calibration.length_scale", 1.0) != 1.0 or fields.get("calibration.joint_offsets"):
        raise ConfigError("parameter 'arm.calibration.*': set, but the planar arm (arm.model empty) has no model "
                          "file to differ from; allowed: a calibration gap for a model arm (arm.model)")
    if scene.obstacles:
        name = "scene.floor" if scene.floor is not None else "scene.boxes"
        raise ConfigError(f"parameter '{name}': set, but the planar arm (arm.model empty) lives in its task plane "
                          "and has no scene; allowed: a scene for a model arm (arm.model), else no scene.floor "
                          "(-1000.0) and scene.boxes []")
    planar = {f.name for f in dataclasses.fields(ArmSpec)}
    try:
        return ArmSpec.from_dict({k: v for k, v in fields.items() if k in planar})
    except ValueError as exc:
        raise ConfigError(str(exc).replace("ArmSpec.", "parameter arm.")) from exc
