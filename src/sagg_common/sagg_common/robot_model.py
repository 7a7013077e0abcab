"""A robot's kinematic model from its MJCF/URDF file (ROS-free).

Every node that needs a robot's geometry uses this one class: the bridge's simulated model arm
(``sagg_sim_bridge.model_arm`` builds its simulator on it) and the learner, which computes the task
point of a measured ``/joint_states`` posture with the model's forward kinematics (``task_source:
model``, :class:`TaskFromJoints`), so a real driver need only publish joint states.

What comes from the model, what from the parameters (named as the bridge's ``arm.*``):

- the file: :mod:`.model_load` parses it with ``mujoco.MjSpec``, resolving ``package://`` meshes;
  :meth:`RobotModel.load` loads it for kinematics (meshes that cannot be found are dropped and
  named in :attr:`RobotModel.notices`);
- effector: a site of that name (its origin), else a body / URDF link (its origin);
- joints: every hinge/slide joint that moves the effector, in model order, unless ``joints``
  selects and orders some (the others are held at their rest value). Choice: joints that cannot
  move the effector (a gripper's fingers when the effector is the flange) are left out of the
  default, since no learner could learn them; naming one is an error;
- limits: the model's joint ranges; a joint without one needs ``joint_limits.lower/upper``
  (which, when given, set the limits of every commanded joint and must lie within the model's
  ranges where it has them);
- rest posture: the model's keyframe named ``home``, else the parameter ``rest_posture``, else an
  error naming both;
- forward kinematics: :meth:`RobotModel.task_point` for one posture (``mj_kinematics`` on the
  model's own MjData), :meth:`RobotModel.task_points` for batches (:class:`.model_kin.ChainFK`,
  equal to ``mj_kinematics`` to ~1e-15); the base point (center of the chain's bounding ball) and
  the reach (:func:`farthest_reach`).
"""
from __future__ import annotations

import math
import os
from typing import Sequence

import mujoco
import numpy as np

from .model_kin import HINGE, SLIDE, ChainFK
from .model_load import MODEL_SUFFIXES, compile_spec, load_spec
from .params import ConfigError, is_real

AXES = ("x", "y", "z")
HOME_KEY = "home"


def ament_prefixes() -> tuple[str, ...]:
    """The install prefixes of ``AMENT_PREFIX_PATH`` (where ``package://`` meshes are looked up)."""
    return tuple(p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p)


def check_robot_fields(model: str, effector: str, task_axes: tuple, joints: tuple, joint_lower: tuple,
                       joint_upper: tuple, rest: tuple, package_paths: tuple) -> None:
    """Check a robot's parameters without loading the model; ConfigError names the parameter
    (``arm.*``; ``rest_posture`` is one value for every node)."""
    if not isinstance(model, str) or not model.lower().endswith(MODEL_SUFFIXES):
        raise ConfigError(f"parameter arm.model: got {model!r}; allowed: a MuJoCo MJCF (.xml) or "
                          "URDF (.urdf) file")
    if not os.path.isfile(model):
        raise ConfigError(f"parameter arm.model: no file {model!r}")
    if not isinstance(effector, str):
        raise ConfigError(f"parameter arm.effector: got {effector!r}; allowed: a body, link or site name")
    ax = task_axes
    if (not isinstance(ax, tuple) or not ax or any(a not in AXES for a in ax)
            or list(ax) != sorted(set(ax), key=AXES.index)):
        raise ConfigError(f"parameter arm.task_axes: got {list(ax) if isinstance(ax, tuple) else ax!r}; "
                          "allowed: a non-empty subset of [x, y, z] in that order (e.g. [x, y, z], [x, y])")
    if len(ax) == 1:
        raise ConfigError(f"parameter arm.task_axes: got {list(ax)}; allowed: 2 or 3 axes (the reachable "
                          "set and the task space are 2-D or 3-D)")
    if not all(isinstance(j, str) and j for j in joints) or len(set(joints)) != len(joints):
        raise ConfigError(f"parameter arm.joints: got {list(joints)}; allowed: distinct joint names, "
                          "or ['*'] for every hinge/slide joint that moves the effector")
    for name, v in (("joint_limits.lower", joint_lower), ("joint_limits.upper", joint_upper),
                    ("rest_posture", rest)):
        if not all(is_real(x) and math.isfinite(float(x)) for x in v):
            raise ConfigError(f"parameter {'' if name == 'rest_posture' else 'arm.'}{name}: got {list(v)}; "
                              "allowed: finite numbers")
    if len(joint_lower) != len(joint_upper):
        raise ConfigError(f"parameters arm.joint_limits.lower/upper: got {len(joint_lower)} and "
                          f"{len(joint_upper)} values; allowed: one per joint each")
    bad = [i for i, (lo, hi) in enumerate(zip(joint_lower, joint_upper)) if not hi > lo]
    if bad:
        raise ConfigError(f"parameters arm.joint_limits.lower/upper: upper must be > lower, not so at "
                          f"position(s) {bad}")
    if not all(isinstance(p, str) for p in package_paths):
        raise ConfigError(f"parameter arm.package_paths: got {list(package_paths)}; allowed: directories")


def farthest_reach(kin: ChainFK, lower: np.ndarray, upper: np.ndarray, base: np.ndarray,
                   axes: np.ndarray, draws: int = 20_000, keep: int = 100, rounds: int = 30) -> float:
    """The largest distance on ``axes`` from ``base`` to the effector found by a seeded search
    over the joint box [lower, upper]: ``draws`` uniform postures, then ``rounds`` rounds of
    Gaussian perturbations of the ``keep`` farthest so far (σ shrinking geometrically from 10% to
    0.01% of each joint range), clipped to the limits. Deterministic (its own fixed seed); a lower
    bound of the true maximum (the sum of the link lengths for a chain that can stretch out)."""
    rng = np.random.default_rng(0x2EAC)
    a = rng.uniform(lower, upper, size=(draws, len(lower)))

    def dist(x: np.ndarray) -> np.ndarray:
        return np.linalg.norm(kin.positions(x)[:, axes] - base, axis=1)

    d = dist(a)
    for sigma in np.geomspace(0.1, 1e-4, rounds):
        top = np.argsort(d)[-keep:]
        a, d = a[top], d[top]
        trial = np.clip(a + sigma * (upper - lower) * rng.standard_normal(a.shape), lower, upper)
        dt = dist(trial)
        a, d = np.concatenate((a, trial)), np.concatenate((d, dt))
    return float(d.max())


class PostureFK:
    """The effector point on the task axes of one posture of some joints (``qadr``: their qpos
    addresses, in the order of a posture's values), every other joint at its rest value, through
    ``mj_kinematics`` on an MjData of its own (of ``model``, default ``robot.model``: any model
    with the robot's bodies and joints, e.g. the simulator's with servos added; the MjModel is
    shared, read-only). For a single posture this is cheaper than the batched
    :class:`.model_kin.ChainFK`, whose numpy overhead dominates there.

    Public views, for a simulator that runs this MjData itself: ``data``, ``sel`` (the joints'
    qpos: a slice when contiguous, else an index array), ``eff`` (the effector's world position, a
    view into ``data``) and ``axes`` (the task axes: a slice or an index array)."""

    def __init__(self, robot: "RobotModel", qadr: np.ndarray, model: mujoco.MjModel | None = None):
        self.model = robot.model if model is None else model
        self.data = mujoco.MjData(self.model)
        self.data.qpos[:] = robot.qpos_rest
        q = np.asarray(qadr, dtype=np.int64)
        contiguous = bool(np.all(np.diff(q) == 1)) if len(q) > 1 else True
        self.sel = slice(int(q[0]), int(q[0]) + len(q)) if contiguous else q.copy()
        self.eff = self.data.site_xpos[robot.site] if robot.site >= 0 else self.data.xpos[robot.body]
        self.axes = slice(0, 3) if robot.axes.tolist() == [0, 1, 2] else robot.axes.copy()
        self._qpos = self.data.qpos

    def point(self, alpha: np.ndarray) -> np.ndarray:
        """(n,) finite joint values (the caller checks them) -> a new (task_dim,) array."""
        self._qpos[self.sel] = alpha
        mujoco.mj_kinematics(self.model, self.data)
        return self.eff[self.axes].copy()


class RobotModel:
    """A robot's compiled MuJoCo model and what is derived from it (see the module docstring):
    commanded joints (``joint_names``, ids ``jids``, qpos/dof addresses ``qadr``/``dofadr``), their
    limits ``lower``/``upper`` and ``rest`` values, the full rest qpos ``qpos_rest`` (held joints
    included), the effector (``body``, point ``local`` in its frame, ``site`` id or -1), task axes
    ``axes`` (indices into x, y, z), forward kinematics ``kin``, bounding ball (``center``,
    ``bound``), ``reach``, the model's keyframe ``home`` id ``key`` (-1 if none), the hinge/slide
    joints that move the effector ``moving_joints`` (names, model order), and ``notices`` (what a
    caller should say once: dropped meshes, an ignored rest_posture).

    Built from a compiled model (``path`` names the file in errors; ``dropped``: the mesh URIs
    :func:`.model_load.load_spec` dropped); :meth:`load` loads a file for kinematics. Arrays are
    read-only."""

    def __init__(self, path: str, model: mujoco.MjModel, effector: str = "", task_axes: Sequence[str] = AXES,
                 joints: Sequence[str] = (), joint_lower: Sequence[float] = (), joint_upper: Sequence[float] = (),
                 rest: Sequence[float] = (), dropped: tuple[str, ...] = (), package_paths: Sequence[str] = (),
                 prefixes: tuple[str, ...] | None = None):
        m = model
        self.path, self.model, self.effector, self.task_axes = path, m, effector, tuple(task_axes)
        # where the file's package:// meshes were looked up (a model built again from the file, e.g.
        # the scene's collision model, looks in the same places; prefixes None = AMENT_PREFIX_PATH's)
        self.package_paths, self.prefixes = tuple(package_paths), prefixes
        self.notices: list[str] = []
        self.mesh_notice = ""  # (the one notice that also concerns a model used for kinematics only)
        if dropped:
            self.mesh_notice = (f"arm.model {path}: {len(dropped)} mesh file(s) not found, their geometry dropped "
                                f"(kinematic mode does not need it; dynamic mode would): {', '.join(dropped)}")
            self.notices.append(self.mesh_notice)
        self.dropped = dropped
        # ---- effector
        body, local = self._effector(m, effector, path)
        ancestors = set()
        b = body
        while b != 0:
            ancestors.add(b)
            b = int(m.body_parentid[b])
        # ---- commanded joints
        movable = [j for j in range(m.njnt) if int(m.jnt_type[j]) in (HINGE, SLIDE)]
        moving = [j for j in movable if int(m.jnt_bodyid[j]) in ancestors]
        self.moving_joints = tuple(m.joint(j).name for j in moving)
        jids = self._joints(m, tuple(joints), effector, path, movable, moving)
        names = [m.joint(j).name for j in jids]
        n = len(jids)
        self.joint_names = tuple(names)
        self.jids = np.array(jids, dtype=np.int64)
        self.qadr = np.array([m.jnt_qposadr[j] for j in jids], dtype=np.int64)
        self.dofadr = np.array([m.jnt_dofadr[j] for j in jids], dtype=np.int64)
        # ---- limits
        limited = np.array([bool(m.jnt_limited[j]) for j in jids])
        model_lo = np.array([m.jnt_range[j, 0] for j in jids], dtype=float)
        model_hi = np.array([m.jnt_range[j, 1] for j in jids], dtype=float)
        if joint_lower:
            if len(joint_lower) != n:
                raise ConfigError(f"parameters arm.joint_limits.lower/upper: got {len(joint_lower)} values; "
                                  f"allowed: {n}, one per commanded joint {names}")
            lower, upper = np.array(joint_lower, float), np.array(joint_upper, float)
            outside = [f"{names[i]} [{lower[i]:g}, {upper[i]:g}] vs [{model_lo[i]:g}, {model_hi[i]:g}]"
                       for i in range(n) if limited[i] and (lower[i] < model_lo[i] or upper[i] > model_hi[i])]
            if outside:
                raise ConfigError("parameters arm.joint_limits.lower/upper: must lie within the model's joint "
                                  f"ranges; not so for {', '.join(outside)}")
        else:
            free = [names[i] for i in range(n) if not limited[i]]
            if free:
                raise ConfigError(
                    f"parameters arm.joint_limits.lower/upper: joint(s) {', '.join(free)} of {path} have no range; "
                    f"give the limits of every commanded joint, in the order {names}")
            lower, upper = model_lo, model_hi
        self.lower, self.upper = lower, upper
        # ---- rest posture (and the held joints' values)
        key = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_KEY, HOME_KEY)
        if key >= 0:
            qpos_rest = m.key_qpos[key].copy()
            rest_q = qpos_rest[self.qadr].copy()
            source = f"keyframe '{HOME_KEY}' of {path}"
            if rest and tuple(float(x) for x in rest) != tuple(rest_q.tolist()):
                self.notices.append(f"rest_posture ignored: the keyframe '{HOME_KEY}' of {path} gives the "
                                    "rest posture")
        elif rest:
            if len(rest) != n:
                raise ConfigError(f"parameter rest_posture: got {len(rest)} values; allowed: {n}, one "
                                  f"per commanded joint {names}")
            qpos_rest = m.qpos0.copy()
            rest_q = np.array(rest, dtype=float)
            qpos_rest[self.qadr] = rest_q
            source = "parameter rest_posture"
        else:
            raise ConfigError(f"parameter rest_posture: {path} has no keyframe named '{HOME_KEY}'; give the "
                              f"rest posture once in the config's '/**' section (rest_posture: {n} values, for "
                              f"{names}) or add a keyframe '{HOME_KEY}' to the model")
        bad = [f"{names[i]}={rest_q[i]:g} outside [{lower[i]:g}, {upper[i]:g}]" for i in range(n)
               if not lower[i] <= rest_q[i] <= upper[i]]
        if bad:
            raise ConfigError(f"rest posture from {source}: {', '.join(bad)}")
        self.rest, self.qpos_rest, self.key = rest_q, qpos_rest, int(key)
        # ---- effector, kinematics, reach
        self.body, self.local = body, local
        self.site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, effector)
        self.axes = np.array([AXES.index(a) for a in self.task_axes], dtype=np.int64)
        self.kin = ChainFK(m, body, local, jids, qpos_rest, lower, upper)
        center, radius = self.kin.ball()
        self.center, self.bound = center, float(radius)
        self.reach = farthest_reach(self.kin, lower, upper, center[self.axes], self.axes)
        for arr in (self.lower, self.upper, self.rest, self.qpos_rest, self.center):
            arr.flags.writeable = False
        self._fk: PostureFK | None = None  # task_point's own MjData, made on first use

    @classmethod
    def load(cls, path: str, effector: str = "", task_axes: Sequence[str] = AXES,
             package_paths: Sequence[str] = (), joints: Sequence[str] = (), joint_lower: Sequence[float] = (),
             joint_upper: Sequence[float] = (), rest: Sequence[float] = (),
             prefixes: tuple[str, ...] | None = None) -> "RobotModel":
        """The robot of the model file ``path`` (absolute), loaded for kinematics: meshes that
        cannot be found (``package://`` through ``package_paths`` then ``prefixes``, default
        :func:`ament_prefixes`) are dropped and named in :attr:`notices`. ``joints`` () = every
        hinge/slide joint that moves the effector; ``joint_lower/upper`` () = the model's ranges;
        ``rest`` () = the keyframe ``home``. ConfigError names the parameter (``arm.*``)."""
        fields = (path, effector, tuple(task_axes), tuple(joints), tuple(joint_lower), tuple(joint_upper),
                  tuple(rest), tuple(package_paths))
        check_robot_fields(*fields)
        prefixes = ament_prefixes() if prefixes is None else prefixes
        mjspec, dropped = load_spec(path, tuple(package_paths), prefixes, True)
        return cls(path, compile_spec(mjspec, path), effector, task_axes, joints, joint_lower, joint_upper, rest,
                   dropped, tuple(package_paths), prefixes)

    # ------------------------------------------------------------------ what callers need
    @property
    def task_dim(self) -> int:
        return len(self.axes)

    def base_point(self) -> np.ndarray:
        """The robot's base in task coordinates: the point the first moving joint turns the arm
        about (the center of :meth:`.model_kin.ChainFK.ball`; a UR5's shoulder)."""
        return self.center[self.axes].copy()

    def task_point(self, alpha: np.ndarray) -> np.ndarray:
        """The effector on the task axes for one posture (n,) of the commanded joints (the others
        at rest), through ``mj_kinematics`` on this model's own MjData (one MjData per model: not
        for concurrent threads)."""
        if self._fk is None:
            self._fk = PostureFK(self, self.qadr)
        return self._fk.point(alpha)

    def task_points(self, alphas: np.ndarray) -> np.ndarray:
        """(N, n) postures of the commanded joints -> (N, task_dim) effector points, batched
        through :class:`.model_kin.ChainFK`."""
        return self.kin.positions(alphas)[:, self.axes]

    # ------------------------------------------------------------------ building
    @staticmethod
    def _effector(m: mujoco.MjModel, name: str, path: str) -> tuple[int, np.ndarray]:
        """(body id, point in the body frame) of the effector: a site of that name, else a body."""
        if name:
            sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
            if sid >= 0:
                return int(m.site_bodyid[sid]), m.site_pos[sid].copy()
            bid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
            if bid > 0:
                return bid, np.zeros(3)
        bodies = [m.body(i).name for i in range(1, m.nbody) if m.body(i).name]
        sites = [m.site(i).name for i in range(m.nsite) if m.site(i).name]
        raise ConfigError(f"parameter arm.effector: got {name!r}; allowed: a body/link or site of {path}: "
                          f"sites {sites}, bodies {bodies}")

    @staticmethod
    def _joints(m: mujoco.MjModel, joints: tuple[str, ...], effector: str, path: str, movable: list[int],
                moving: list[int]) -> list[int]:
        """The commanded joint ids (see the module docstring)."""
        if not joints:
            unnamed = [j for j in moving if not m.joint(j).name]
            if unnamed:
                raise ConfigError(f"parameter arm.model: joint(s) number {unnamed} of {path} have no name; "
                                  "every commanded joint needs one (joint states map joints by name)")
            if not moving:
                raise ConfigError(f"parameter arm.effector: no hinge or slide joint of {path} moves "
                                  f"{effector!r}")
            return moving
        out = []
        for name in joints:
            j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
            if j < 0 or j not in movable:
                raise ConfigError(f"parameter arm.joints: {name!r} is not a hinge or slide joint of {path}; "
                                  f"allowed: {[m.joint(k).name for k in movable]}")
            if j not in moving:
                raise ConfigError(f"parameter arm.joints: joint {name!r} does not move the effector "
                                  f"{effector!r}; allowed: {[m.joint(k).name for k in moving]}")
            out.append(j)
        return out


class TaskFromJoints:
    """The task point of a measured posture, for a learner whose driver publishes only joint
    states (``task_source: model``): ``joints`` are the learner's joint names in its command
    order; each must be a hinge/slide joint of the model that moves the effector (else one
    ConfigError naming the parameter ``joints`` and the model's joints that do); every other
    joint of the model is held at its rest value (``robot.qpos_rest``).

    :meth:`point` runs on every accepted joint state: one ``mj_kinematics`` call on an MjData of
    its own (:class:`PostureFK`), the joints written straight into its qpos in the learner's order."""

    def __init__(self, robot: RobotModel, joints: Sequence[str]):
        names = list(joints)
        allowed = list(robot.moving_joints)
        unknown = [j for j in names if j not in allowed]
        if unknown or not names or len(set(names)) != len(names):
            what = (f"{unknown} not joint(s) of {robot.path} that move the effector {robot.effector!r}" if unknown
                    else "no joints" if not names else "repeated joint names")
            raise ConfigError(f"parameter joints: got {names} ({what}); allowed: distinct names among the model's "
                              f"joints {allowed}")
        m = robot.model
        qadr = np.array([m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j)] for j in names],
                        dtype=np.int64)
        self.robot = robot
        self.joint_names = tuple(names)
        self.task_dim = robot.task_dim
        self._fk = PostureFK(robot, qadr)

    def point(self, alpha: np.ndarray) -> np.ndarray:
        """(n,) finite joint values in :attr:`joint_names` order -> (task_dim,) task point."""
        return self._fk.point(alpha)


def task_from_params(p: dict, joints: Sequence[str], m: int, base_dir: str) -> TaskFromJoints:
    """A learner's ``task_source: model``: the task point of a measured posture through the robot's
    model given by the learner's parameters ``p`` (``task_model.file``, ``.effector``,
    ``.task_axes``, ``.package_paths``: relative ones relative to ``base_dir``; ``joints``,
    ``joint_limits.*`` and ``rest_posture``: the learner's), its ``joints`` by name, ``m`` task
    dimensions. ConfigError names the learner's parameter."""
    if not p["task_model.file"]:
        raise ConfigError("parameter 'task_model.file': empty; allowed: the robot's MJCF (.xml) or URDF (.urdf) "
                          "file (task_source 'model')")
    robot = robot_from_params(p, joints, base_dir, m)
    try:
        return TaskFromJoints(robot, joints)
    except ConfigError as exc:  # (the model's errors name the bridge's arm.* parameters)
        raise ConfigError(in_learner_terms(str(exc))) from exc


def robot_from_params(p: dict, joints: Sequence[str], base_dir: str, m: int | None = None) -> RobotModel:
    """The robot's model from a learner's parameters ``p`` (``task_model.file``, ``.effector``,
    ``.task_axes``, ``.package_paths``: relative ones relative to ``base_dir``; ``joint_limits.*``
    and ``rest_posture``), its commanded joints ``joints`` in the learner's order; ``m`` (when
    given) the task dimensions the task axes must match. Shared by :func:`task_from_params` and
    the scene's collision checker (:func:`sagg_common.scene.scene_from_params`). ConfigError names
    the learner's parameter."""
    if m is not None and len(p["task_model.task_axes"]) != m:
        raise ConfigError(f"parameter 'task_model.task_axes': {p['task_model.task_axes']!r}; allowed: {m} axes, "
                          "one per task_space dimension")
    try:
        return RobotModel.load(os.path.normpath(os.path.join(base_dir, p["task_model.file"])),
                               p["task_model.effector"], tuple(p["task_model.task_axes"]),
                               [os.path.normpath(os.path.join(base_dir, d)) for d in p["task_model.package_paths"]],
                               joints=joints, joint_lower=p["joint_limits.lower"], joint_upper=p["joint_limits.upper"],
                               rest=p["rest_posture"])
    except ConfigError as exc:  # (the model's errors name the bridge's arm.* parameters)
        raise ConfigError(in_learner_terms(str(exc))) from exc


def in_learner_terms(text: str) -> str:
    """A RobotModel error or notice, which names the bridge's ``arm.*`` parameters, in the
    learner's parameter names (``task_model.*``: :func:`task_from_params`)."""
    for bridge, learner in LEARNER_NAMES:
        text = text.replace(bridge, learner)
    return text


# the bridge's parameter names in RobotModel's errors -> the learner's (task_from_params)
LEARNER_NAMES = (("arm.model", "task_model.file"), ("arm.effector", "task_model.effector"),
                 ("arm.task_axes", "task_model.task_axes"), ("arm.package_paths", "task_model.package_paths"),
                 ("arm.joint_limits", "joint_limits"), ("arm.joints", "joints"))
