"""Any robot from its model file: the model arm (ROS-free core).

The robot is a MuJoCo MJCF (``.xml``) or URDF (``.urdf``) file, loaded as a
:class:`sagg_common.robot_model.RobotModel` (the file parsed with ``package://`` meshes resolved;
joints, limits, rest posture, effector, forward kinematics, base point and reach: the rules are in
that module's docstring, shared with the learner's ``task_source: model``); the learner commands
some of its hinge/slide joints and sees the world position of one effector point (a site, or a
body / URDF link origin) on the chosen task axes. It speaks exactly the protocol of the planar
:class:`~.arm.ArmSim` (``reset``, ``command``, ``observe``, ``tip_positions``,
``get_state``/``set_state``, ``reseed``; same motor-noise model, drawn in the same blocks, and the
same dynamic-mode settling), so every runner can take either.

What this module adds to the robot model (parameters ``arm.*``, see :mod:`.params`):

- ``rest_posture`` is given once in the config's ``/**`` section: the learner node reads the same one;
- ``arm.mode`` kinematic (qpos set, ``mj_kinematics``; meshes that cannot be found are dropped) or
  dynamic (every mesh required; position actuators added where the model has none for a commanded
  joint: gain ``arm.kp``, the joint's damping ``arm.damping`` and armature ``arm.armature``, as the
  planar arm's critically damped servos; physics step ``arm.timestep`` replaces the model's;
  gravity and contacts off: an ideal position-controlled arm that holds any posture, as a real
  arm's controller with gravity compensation does);
- the scene (``scene.*``, :mod:`sagg_common.scene_params`), when it declares a floor or boxes: in
  dynamic mode they are in the physics and block the arm (contacts on between the moving links
  and them only: links among themselves still pass through each other, the servos would fight
  it); in kinematic mode the arm is set by qpos and nothing blocks. In both modes every command's
  motion (the straight joint-space segment from the posture before it to the posture after it) is
  checked with a :class:`sagg_common.scene.SceneChecker` of the simulated arm, and counted in
  :attr:`ModelArmSim.contacts` when the checker would refuse it (closer than ``scene.clearance``
  to an obstacle, or links overlapping): what a learner that checks its moves should never cause.

The reachable set of the effector (2-D or 3-D occupancy grid, :func:`model_reachable_area`) is
estimated by sampling the joint space through the model's own forward kinematics
(:class:`sagg_common.model_kin.ChainFK`, checked against ``mj_kinematics``), like the planar arm's.
"""
from __future__ import annotations

import dataclasses
import os
import sys
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from sagg_common.diagnostics import all_finite
from sagg_common.model_load import compile_spec, load_spec
from sagg_common.params import ConfigError, is_int
from sagg_common.robot_model import AXES, PostureFK, RobotModel, ament_prefixes, check_robot_fields
from sagg_common.scene import CAUSES, Refusal, SceneChecker
from sagg_common.scene_model import SceneModel, add_scene_physics
from sagg_common.scene_params import SceneParams

from .arm import NOISE_BLOCK, ArmSim, ArmSpec, ReachableArea, check_bounds, goals_in_area, occupancy_grid
from .calibration import Calibration, apply_calibration

# ArmSpec fields that mean the same for the model arm (mode, noise, dynamic-mode servo and settling);
# the other ArmSpec fields describe the planar arm's geometry and are ignored when arm.model is set.
SHARED_FIELDS = ("mode", "motor_noise", "timestep", "kp", "damping", "armature", "settle_tolerance",
                 "settle_velocity", "max_settle_steps", "settle_check_every")
# Default grid resolution of the reachable set: reach/100 per side in 2-D (the planar arm's
# total_length/100), reach/25 in 3-D; default samples: 400k in 2-D (as the planar arm), 2M in 3-D.
# On the example arms (a ~0.95 m UR5-like and Panda-like arm, box ±1.05 reach), reach/25 and 2M
# samples (~70k cells) give the volume within 0.6% of an 8M-sample estimate; reach/50 (~540k cells)
# needs about four times the samples (and the time) to fill, and 2M leave it short.
CELLS_PER_REACH = {2: 100.0, 3: 25.0}
DEFAULT_SAMPLES = {2: 400_000, 3: 2_000_000}
# Loaded models kept per process (a run's evaluation builds 100 simulators of one spec).
_CACHE_SIZE = 8


_SAID: set[str] = set()  # notices already printed by this process


def _said(text: str) -> None:
    """Print a notice about a model once per process (stderr: every runner shows it)."""
    if text not in _SAID:
        _SAID.add(text)
        print(f"sagg_sim_bridge: {text}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class ModelArmSpec:
    """Everything that defines one model arm: the parameters ``arm.*`` with paths resolved (built by
    :meth:`from_params`; field ``rest`` is ``rest_posture``, ``joint_lower/upper`` are
    ``arm.joint_limits.lower/upper``; empty tuples = not given). Hashable and plain (picklable by
    multiprocessing); the loaded model is kept per process, keyed by the spec."""

    model: str                               # absolute path of the .xml/.urdf file
    effector: str = ""
    task_axes: tuple[str, ...] = AXES
    joints: tuple[str, ...] = ()             # () = every hinge/slide joint moving the effector
    joint_lower: tuple[float, ...] = ()      # () = the model's ranges
    joint_upper: tuple[float, ...] = ()
    rest: tuple[float, ...] = ()             # () = the model's keyframe 'home'
    package_paths: tuple[str, ...] = ()      # absolute directories holding PKG folders
    mode: str = ArmSpec.mode
    motor_noise: float = ArmSpec.motor_noise
    timestep: float = ArmSpec.timestep
    kp: float = ArmSpec.kp
    damping: float = ArmSpec.damping
    armature: float = ArmSpec.armature
    settle_tolerance: float = ArmSpec.settle_tolerance
    settle_velocity: float = ArmSpec.settle_velocity
    max_settle_steps: int = ArmSpec.max_settle_steps
    settle_check_every: int = ArmSpec.settle_check_every
    scene: SceneParams | None = None         # None = no floor, no box (scene.*): no contact counting
    calibration: Calibration | None = None   # None = the arm is its model file (arm.calibration.*)

    # ------------------------------------------------------------------ building
    @classmethod
    def from_params(cls, fields: dict[str, Any], base_dir: str | None,
                    scene: SceneParams | None = None) -> "ModelArmSpec":
        """The spec from the resolved ``arm.*`` parameters (names without ``arm.``) of the
        schema in :mod:`.params`: ``arm.model`` and relative ``arm.package_paths`` are relative to
        ``base_dir`` (the config file's directory; package paths default to the model file's
        directory when it is None); ``rest_posture`` is the bridge's parameter of that name (not
        under ``arm.``: one value for every node). Planar-only fields are ignored. ``scene``: the
        scene the arm meets (None: none). Validated (model loaded); ConfigError names the parameter."""
        model = fields.get("model", "")
        if not isinstance(model, str) or not model:
            raise ConfigError(f"parameter arm.model: got {model!r}; allowed: the path of a .xml (MJCF) or "
                              ".urdf file")
        if not os.path.isabs(model):
            if base_dir is None:
                raise ConfigError(f"parameter arm.model: {model!r} is relative and no config directory is "
                                  "known to resolve it; give an absolute path")
            model = os.path.join(base_dir, model)
        model = os.path.normpath(os.path.abspath(model))
        pkg_base = base_dir if base_dir is not None else os.path.dirname(model)
        paths = tuple(os.path.normpath(os.path.abspath(os.path.join(pkg_base, p))) if isinstance(p, str) else p
                      for p in fields.get("package_paths", ()))
        joints = tuple(fields.get("joints", ()))
        if joints == ("*",):
            joints = ()
        lower, upper = tuple(fields.get("joint_limits.lower", ())), tuple(fields.get("joint_limits.upper", ()))
        if lower == (0.0,) and upper == (0.0,):  # the schema's "not given"
            lower, upper = (), ()
        rest = tuple(fields.get("rest_posture", ()))
        if rest == (0.0,):  # the schema's "not given"
            rest = ()
        kw = {f: fields[f] for f in SHARED_FIELDS if f in fields}
        for f in ("timestep", "kp", "damping", "armature", "motor_noise", "settle_tolerance", "settle_velocity"):
            if f in kw and is_int(kw[f]):
                kw[f] = float(kw[f])
        calibration = Calibration(fields.get("calibration.length_scale", 1.0),
                                  tuple(fields.get("calibration.joint_offsets", ())))
        spec = cls(model=model, effector=fields.get("effector", ""), task_axes=tuple(fields.get("task_axes", "xyz")),
                   joints=joints, joint_lower=lower, joint_upper=upper, rest=rest, package_paths=paths, scene=scene,
                   calibration=None if calibration.nominal else calibration, **kw)
        spec.validate()
        return spec

    def validate_fields(self) -> None:
        """Check the fields without loading the model; ConfigError names the parameter."""
        check_robot_fields(self.model, self.effector, self.task_axes, self.joints, self.joint_lower,
                           self.joint_upper, self.rest, self.package_paths)
        try:
            ArmSpec(**{f: getattr(self, f) for f in SHARED_FIELDS}).validate()
        except ValueError as exc:
            raise ConfigError(str(exc).replace("ArmSpec.", "parameter arm.")) from exc

    def validate(self) -> None:
        """Fields, then the model (loaded once per process); ConfigError names the parameter."""
        self.validate_fields()
        self.loaded()

    def nominal(self) -> "ModelArmSpec":
        """This arm as its model file says (no calibration gap): what the learner knows of it."""
        return self if self.calibration is None else dataclasses.replace(self, calibration=None)

    def loaded(self) -> "LoadedArm":
        """The loaded model and everything derived from it (kept per process)."""
        prefixes = ament_prefixes()
        key = (self, prefixes)
        arm = _LOADED.get(key)
        if arm is None:
            self.validate_fields()
            arm = LoadedArm(self, prefixes)
            if len(_LOADED) >= _CACHE_SIZE:
                _LOADED.pop(next(iter(_LOADED)))
            _LOADED[key] = arm
            for note in arm.notices:
                _said(note)
        return arm

    # ------------------------------------------------------------------ what callers need
    @property
    def task_dim(self) -> int:
        return len(self.task_axes)

    def joint_names(self) -> list[str]:
        return list(self.loaded().joint_names)

    def limits(self) -> tuple[np.ndarray, np.ndarray]:
        arm = self.loaded()
        return arm.lower.copy(), arm.upper.copy()

    def rest_posture(self) -> np.ndarray:
        return self.loaded().rest.copy()

    def reach(self) -> float:
        """The arm's reach in task units: the largest distance, on the task axes, from
        :meth:`base_point` to the effector over the joint space within the limits, found by
        :func:`sagg_common.robot_model.farthest_reach` (a seeded search: deterministic; within ~1e-4
        of the true maximum); of the model file (:meth:`nominal`: the task-unit defaults derived
        from it are the same with or without a calibration gap).
        The planar arm's analogue is its total length."""
        return self.nominal().loaded().reach

    def base_point(self) -> np.ndarray:
        """The arm's base in task coordinates: the point the first moving joint turns the arm
        about (:meth:`sagg_common.robot_model.RobotModel.base_point`; a UR5's shoulder, a planar
        arm's base)."""
        return self.loaded().base_point()


_LOADED: dict[tuple, "LoadedArm"] = {}


def _position_servo(m: mujoco.MjModel, a: int) -> bool:
    """Whether actuator ``a`` is a MuJoCo position servo (what ``<position>`` compiles to)."""
    kp = float(m.actuator_gainprm[a, 0])
    return (int(m.actuator_gaintype[a]) == int(mujoco.mjtGain.mjGAIN_FIXED)
            and int(m.actuator_biastype[a]) == int(mujoco.mjtBias.mjBIAS_AFFINE)
            and kp > 0 and float(m.actuator_biasprm[a, 0]) == 0.0 and float(m.actuator_biasprm[a, 1]) == -kp
            and float(m.actuator_gear[a, 0]) == 1.0)


class LoadedArm(RobotModel):
    """A model arm: its :class:`~sagg_common.robot_model.RobotModel` (joints, limits, rest,
    effector, forward kinematics, reach; loaded for kinematics in kinematic mode) and what
    simulating it needs: ``sim_model``, the MjModel the simulator runs (the robot's own in
    kinematic mode; in dynamic mode every mesh is required and a position servo is added per
    commanded joint), the servos' actuator ids ``act`` and the rest controls ``ctrl_rest``;
    ``scene_params``, the spec's scene (None: none), whose floor and boxes are in ``sim_model`` in
    dynamic mode (:func:`sagg_common.scene_model.add_scene_physics`); :meth:`scene_model`, the
    collision model the simulators' contact counting shares."""

    def __init__(self, spec: ModelArmSpec, prefixes: tuple[str, ...]):
        path = spec.model
        kinematic = spec.mode == "kinematic"
        mjspec, dropped = load_spec(path, spec.package_paths, prefixes, kinematic)
        if spec.calibration is not None:  # the commanded joints are the nominal arm's
            apply_calibration(mjspec, spec.calibration, list(spec.nominal().loaded().joint_names))
        super().__init__(path, compile_spec(mjspec, path), spec.effector, spec.task_axes, spec.joints,
                         spec.joint_lower, spec.joint_upper, spec.rest, dropped, spec.package_paths, prefixes)
        m, key, jids, rest = self.model, self.key, self.jids, self.rest
        self.scene_params = spec.scene
        self._scene_model: SceneModel | None = None
        if self.scene_params is not None and not kinematic:
            add_scene_physics(mjspec, m, jids, self.qpos_rest, self.scene_params)
        # ---- dynamic mode: a position servo per commanded joint
        self.act = np.zeros(0, dtype=np.int64)
        if not kinematic:
            m = self._add_servos(mjspec, m, spec, path, list(self.joint_names), self.lower, self.upper)
            self.act = np.array([self._servo_of(m, j) for j in jids], dtype=np.int64)
        self.sim_model = m
        ctrl = m.key_ctrl[key].copy() if key >= 0 else np.zeros(m.nu)
        if key < 0:  # position servos of held joints hold their rest value
            for a in range(m.nu):
                if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and _position_servo(m, a):
                    ctrl[a] = self.qpos_rest[m.jnt_qposadr[m.actuator_trnid[a, 0]]]
        if not kinematic:
            ctrl[self.act] = rest
        self.ctrl_rest = ctrl
        self.ctrl_rest.flags.writeable = False

    def scene_model(self) -> SceneModel:
        """The collision model of this arm in its scene (built on first use, then shared)."""
        if self._scene_model is None:
            if self.scene_params is None:
                raise ValueError("this arm has no scene")
            self._scene_model = SceneModel(self, self.scene_params)
        return self._scene_model

    @staticmethod
    def _servo_of(m: mujoco.MjModel, j: int) -> int:
        acts = [a for a in range(m.nu)
                if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT) and int(m.actuator_trnid[a, 0]) == j]
        return acts[0] if acts else -1

    def _add_servos(self, mjspec: mujoco.MjSpec, m: mujoco.MjModel, spec: ModelArmSpec, path: str,
                    names: list[str], lower: np.ndarray, upper: np.ndarray) -> mujoco.MjModel:
        """Dynamic mode: keep the model's position servos of commanded joints, add one (gain
        arm.kp; the joint's damping arm.damping and armature arm.armature) where there is none;
        physics step arm.timestep, gravity off, contacts off unless a scene is declared (then
        between the links and its obstacles only), implicitfast integrator."""
        for i, j in enumerate(self.jids):
            acts = [a for a in range(m.nu) if int(m.actuator_trntype[a]) == int(mujoco.mjtTrn.mjTRN_JOINT)
                    and int(m.actuator_trnid[a, 0]) == int(j)]
            if len(acts) > 1 or (acts and not _position_servo(m, acts[0])):
                raise ConfigError(
                    f"parameter arm.mode: 'dynamic' drives joint {names[i]!r} of {path} with a position servo, but "
                    f"the model gives it actuator(s) {[m.actuator(a).name for a in acts]} that are not exactly one "
                    "position actuator; remove them or use arm.mode 'kinematic'")
            if acts:
                continue
            act = mjspec.add_actuator(name=f"sagg_position_{names[i]}", target=names[i],
                                      trntype=mujoco.mjtTrn.mjTRN_JOINT)
            act.set_to_position(kp=float(spec.kp))
            act.ctrlrange = [float(lower[i]), float(upper[i])]
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            joint = mjspec.joint(names[i])
            joint.damping = [float(spec.damping), 0.0, 0.0]
            joint.armature = float(spec.armature)
        mjspec.option.timestep = float(spec.timestep)
        mjspec.option.gravity = [0.0, 0.0, 0.0]
        if spec.scene is None:
            mjspec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        else:
            mjspec.option.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        mjspec.option.integrator = int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST)
        return compile_spec(mjspec, path)


class ModelArmSim(ArmSim):
    """A model arm speaking :class:`~.arm.ArmSim`'s protocol (inherits its motor-noise blocks,
    ``reseed`` and ``get_state``/``set_state``: the same noise stream and checkpoint format).

    ``command`` realises clip(α + Δ·(1 + motor_noise·N(0,1)), limits) on the commanded joints
    exactly as the planar arm; ``observe``/``command`` return the commanded joints' values (in
    ``joint_names`` order) and the effector's world position on the task axes. The MjModel is
    shared by every simulator of the spec (read-only); each has its own MjData.

    With a scene (``spec.scene``): ``scene`` is this simulator's :class:`~sagg_common.scene.SceneChecker`
    (else None), ``contacts`` counts the commands whose motion it refuses (since this simulator
    was built; not part of :meth:`get_state`), ``contacts_by_cause`` by cause (self, floor, box),
    ``last_contact`` the latest refusal."""

    def __init__(self, spec: ModelArmSpec, seed: int):
        # (ArmSim.__init__ is not called: it generates the planar model; the attributes its
        # inherited methods use are set here)
        if not isinstance(spec, ModelArmSpec):
            raise ValueError(f"ModelArmSim.spec must be a ModelArmSpec, got {type(spec).__name__}")
        if not is_int(seed) or int(seed) < 0:
            raise ValueError(f"ModelArmSim.seed must be an integer >= 0, got {seed!r}")
        arm = spec.loaded()
        self.spec = spec
        self.seed = int(seed)
        self.arm = arm
        self.n_joints = len(arm.joint_names)
        self.joint_names = list(arm.joint_names)
        self.lower, self.upper, self.rest = arm.lower, arm.upper, arm.rest  # read-only arrays
        self.task_dim = len(arm.axes)
        self.rng = np.random.default_rng(self.seed)
        self.model = arm.sim_model
        view = PostureFK(arm, arm.qadr, self.model)  # this simulator's MjData and its views
        self.data = view.data
        self._dynamic = spec.mode == "dynamic"
        self._noise = float(spec.motor_noise)
        self._qpos = self.data.qpos
        self._qvel = self.data.qvel
        self._ctrl = self.data.ctrl
        self._qsel = view.sel
        self._dsel = arm.dofadr.copy()
        self._csel = arm.act.copy()
        self._eff = view.eff
        self._axes = view.axes
        self._shape = (self.n_joints,)
        self._buf = np.empty(self.n_joints)
        self._cbuf = np.empty(self.n_joints)
        self._nbuf = np.empty(self.n_joints)
        self._nblock: np.ndarray | None = None
        self._nidx = NOISE_BLOCK
        self._block_state: dict | None = None
        self._tol = float(spec.settle_tolerance)
        self._vtol = float(spec.settle_velocity)
        self._max_steps = int(spec.max_settle_steps)
        self._every = int(spec.settle_check_every)
        self.last_settle_steps = 0
        self.last_settled = True
        self.contacts = 0
        self.contacts_by_cause = dict.fromkeys(CAUSES, 0)
        self.last_contact: Refusal | None = None
        self.scene: SceneChecker | None = None
        if spec.scene is not None:
            self.scene = SceneChecker(arm, spec.scene, model=arm.scene_model())
            for note in [spec.scene.describe(), *self.scene.notices]:
                _said(note)
        self.reset()

    # ------------------------------------------------------------------ protocol
    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        """Teleport to the rest posture (held joints at theirs) with zero velocity; no RNG draw."""
        mujoco.mj_resetData(self.model, self.data)
        self._qpos[:] = self.arm.qpos_rest
        self._ctrl[:] = self.arm.ctrl_rest
        mujoco.mj_kinematics(self.model, self.data)
        self.last_settle_steps, self.last_settled = 0, True
        return self.observe()

    def command(self, alpha_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One micro-action toward ``alpha_target`` (absolute joint values of the commanded joints):
        the planar arm's :meth:`~.arm.ArmSim.command` (noise on the displacement, clipped to the
        limits; kinematic: qpos; dynamic: the servos' ctrl, then settle). Returns (α, y), fresh."""
        t = alpha_target if type(alpha_target) is np.ndarray else np.asarray(alpha_target, dtype=float)
        if t.shape != self._shape:
            raise ValueError(f"alpha_target must have shape ({self.n_joints},), got {np.shape(alpha_target)}")
        if not all_finite(t):
            raise ValueError("alpha_target must be finite (no NaN/inf)")
        q = self._qpos[self._qsel]
        q0 = None if self.scene is None else q.copy()
        if self._noise > 0.0:
            if self._nidx >= NOISE_BLOCK:
                self._draw_noise_block()
            buf = self._buf
            np.subtract(t, q, out=buf)
            buf *= self._nblock[self._nidx]
            self._nidx += 1
            buf += q
            t = buf
        c = self._cbuf
        np.maximum(t, self.lower, out=c)
        np.minimum(c, self.upper, out=c)
        if self._dynamic:
            self._ctrl[self._csel] = c
            self._settle()
        else:
            self._qpos[self._qsel] = c
            mujoco.mj_kinematics(self.model, self.data)
        if q0 is not None:
            self.note_motion(q0, self._qpos[self._qsel])
        return self.observe()

    def note_motion(self, alpha0: np.ndarray, alpha1: np.ndarray) -> Refusal | None:
        """Check the straight joint-space motion from ``alpha0`` to ``alpha1`` (commanded joints)
        against the scene and count it in :attr:`contacts` if it is refused; returns the refusal
        (None when free or without a scene). ``command`` calls it; a real-time runner, whose arm
        moves between commands, calls it with the postures at two commands."""
        if self.scene is None:
            return None
        refusal = self.scene.segment(alpha0, alpha1)
        if refusal is not None:
            self.contacts += 1
            self.contacts_by_cause[refusal.cause] += 1
            self.last_contact = refusal
        return refusal

    def _settle(self) -> None:
        """:meth:`ArmSim._settle` on the commanded joints: step until ||qvel|| < settle_velocity
        (every dof) and ||q - ctrl|| < settle_tolerance, at most max_settle_steps steps."""
        m, d = self.model, self.data
        qvel, ctrl, qpos = self._qvel, self._ctrl, self._qpos
        every, tol2, vtol2 = self._every, self._tol * self._tol, self._vtol * self._vtol
        steps, settled, max_steps = 0, False, self._max_steps
        while steps < max_steps:
            k = every if steps + every <= max_steps else max_steps - steps
            mujoco.mj_step(m, d, nstep=k)
            steps += k
            if qvel.dot(qvel) < vtol2:
                diff = qpos[self._qsel] - ctrl[self._csel]
                if diff.dot(diff) < tol2:
                    settled = True
                    break
        mujoco.mj_kinematics(m, d)  # after mj_step the positions belong to the state before the last step
        self.last_settle_steps, self.last_settled = steps, settled

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        return self._qpos[self._qsel].copy(), self._eff[self._axes].copy()

    def joint_velocities(self) -> np.ndarray:
        """The commanded joints' velocities (dynamic mode; zeros in kinematic mode)."""
        return self._qvel[self._dsel].copy()

    def set_targets(self, targets: np.ndarray) -> None:
        """Write the commanded joints' targets to their servos, without stepping the physics."""
        self._ctrl[self._csel] = targets

    def tip_positions(self, alphas: np.ndarray) -> np.ndarray:
        """Effector positions on the task axes of postures of the commanded joints (the others at
        rest): (N, n) -> (N, task_dim) through the vectorised :class:`sagg_common.model_kin.ChainFK`
        for batches, or (n,) -> (task_dim,) through ``mj_kinematics`` (:meth:`fk_mujoco`: for one
        posture numpy's per-call overhead would dominate). The two agree to ~1e-15."""
        a = np.asarray(alphas, dtype=float)
        single = a.ndim == 1
        a2 = a[None, :] if single else a
        if a2.ndim != 2 or a2.shape[1] != self.n_joints:
            raise ValueError(f"alphas must have shape (N, {self.n_joints}) or ({self.n_joints},), got {a.shape}")
        if single:
            return self.fk_mujoco(a2)[0]
        return self.arm.task_points(a2)

    def fk_mujoco(self, alphas: np.ndarray) -> np.ndarray:
        """Effector positions on the task axes of (N, n) postures through ``mj_kinematics``, row by
        row (:meth:`sagg_common.robot_model.RobotModel.task_point`: the model's own MjData; the
        simulator's state is left alone): the reference."""
        a = np.asarray(alphas, dtype=float)
        if a.ndim != 2 or a.shape[1] != self.n_joints:
            raise ValueError(f"alphas must have shape (N, {self.n_joints}), got {a.shape}")
        out = np.empty((a.shape[0], len(self.arm.axes)))
        point = self.arm.task_point
        for i in range(a.shape[0]):
            out[i] = point(a[i])
        return out


# ---------------------------------------------------------------------- reachable set, test goals
def model_reachable_area(spec: ModelArmSpec, lower, upper, resolution: float | None = None,
                         samples: int | None = None, seed: int = 0, refine_rounds: int = 7,
                         batch: int = 100_000, flatten_power: float = 2.0) -> ReachableArea:
    """Occupancy grid (2-D or 3-D, one dimension per task axis) of the effector positions the
    model arm reaches inside the box [lower, upper].

    Method (the planar arm's, :func:`.arm.occupancy_grid`): ``samples`` joint configurations
    through the model's own forward kinematics, the first round uniform within the joint limits,
    ``refine_rounds`` more re-drawing configurations of rarely hit cells and perturbing them.
    Defaults: resolution = reach/100 per side in 2-D, reach/25 in 3-D (:meth:`ModelArmSpec.reach`);
    samples 400k (2-D), 2M (3-D). Seeded by ``seed``; every marked cell was reached (the estimate
    can only miss cells)."""
    spec.validate()
    arm = spec.loaded()
    d = len(arm.axes)
    lo, hi = check_bounds(lower, upper, d)
    if resolution is None:
        resolution = arm.reach / CELLS_PER_REACH[d]
    if samples is None:
        samples = DEFAULT_SAMPLES[d]
    jlo, jhi = arm.lower, arm.upper
    n = len(jlo)
    axes = arm.axes
    kin = arm.kin
    radius = arm.bound * (1 + 1e-9) + 1e-12  # the ball holds every position; float slack
    return occupancy_grid(lo, hi, resolution, arm.center[axes], radius, jlo, jhi,
                          lambda k, rng: rng.uniform(jlo, jhi, size=(k, n)),
                          lambda a: kin.positions(a)[:, axes], None, samples, seed, refine_rounds, batch,
                          flatten_power)


def model_test_goals(spec: ModelArmSpec, lower, upper, n: int = 100, seed: int = 0,
                     area: ReachableArea | None = None) -> np.ndarray:
    """The planar rule (:func:`.arm.test_goals`) for a model arm: n reached effector positions in
    reachable cells drawn uniformly (distinct cells when there are enough), seeded by ``seed`` (the
    reachable set too, unless ``area`` is given)."""
    if not is_int(n) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if not is_int(seed) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    lo, hi = check_bounds(lower, upper, spec.task_dim)
    if area is None:
        area = model_reachable_area(spec, lo, hi, seed=seed)
    return goals_in_area(area, n, seed)
