"""Parameters of the MuJoCo bridge (ROS-free schema; the node declares them with descriptors)."""
from __future__ import annotations

from sagg_common.params import ConfigError, Param, Schema, dataclass_schema

from .arm import ArmSpec

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


SCHEMA: Schema = (
    Param("seed", "int", 0, "Run seed; the simulator's motor-noise stream is derived from it.", low=0),
) + dataclass_schema("arm", ArmSpec, _ARM_DOC, {"link_profile": ("equal", "golden"), "rest_shape": ("arc", "zigzag"),
                                               "mode": ("kinematic", "dynamic")})


def arm_spec_from_params(params: dict) -> ArmSpec:
    """Build and validate the arm from resolved ``arm.*`` parameters (errors name the parameter)."""
    fields = {k[len("arm."):]: v for k, v in params.items() if k.startswith("arm.")}
    try:
        return ArmSpec.from_dict(fields)
    except ValueError as exc:
        raise ConfigError(str(exc).replace("ArmSpec.", "parameter arm.")) from exc
