"""MuJoCo planar N-DOF arm: the simulated robot of the paper's Sec. 3 (ROS-free core).

The arm is a serial chain of ``dof`` hinge joints (axes along z) lying in the xy plane, its base
at the origin; joint angles are relative (joint i turns link i relative to link i-1) and α = 0
points the whole arm along +x. The task-space observation y is the (x, y) position of the site
"tip" at the end effector, in the same "units" as ``total_length`` (paper: a 50-unit arm).

Two ways of executing a micro-action (``ArmSpec.mode``):

- ``"kinematic"``: ideal position control. The (noisy, clipped) target is written to qpos and
  only ``mj_kinematics`` runs. This is the paper's simulated arm and the fast default.
- ``"dynamic"``: MuJoCo position actuators drive the joints through the physics; the simulator
  steps until the joints have settled on the commanded posture (or a step budget runs out) and
  then reports the measured posture. This stands in for a real position-controlled arm.

Everything the paper leaves open (joint ranges, rest posture, noise model, dynamics) is a field
of :class:`ArmSpec` with the choice documented next to it.

Also here: the reachable area of an arm (occupancy grid estimated from the same forward
kinematics) and the paper's independent test-goal set (Sec. 3.7).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

from sagg_common.diagnostics import all_finite
from sagg_common.params import is_int, is_real

GOLDEN_RATIO = (1.0 + math.sqrt(5.0)) / 2.0
MODES = ("kinematic", "dynamic")
LINK_PROFILES = ("equal", "golden")
REST_SHAPES = ("arc", "zigzag")
MAX_DOF = 100
# Grids larger than this are refused (memory guard for reachable_area): ~100 MB of bool.
MAX_GRID_CELLS = 100_000_000
# Motor-noise factors are drawn this many micro-actions at a time (speed; same stream).
NOISE_BLOCK = 256


@dataclass(frozen=True)
class ArmSpec:
    """Everything that defines one simulated arm. Keys of :meth:`from_dict` are these field names."""

    # Number of joints (= links). Paper: 7, 15, 30 (simulation), 8 (real arm).
    dof: int = 8
    # Total length of the arm, in task-space units. Paper: 50 units.
    total_length: float = 50.0
    # "equal": all links total_length/dof. "golden": link i ∝ φ^-i (φ = golden ratio), so lengths
    # decrease from the base and each link is φ times the next one (paper Sec. 3.8: "we use the
    # golden number to specify the relative size of each part"), normalised to total_length.
    link_profile: str = "equal"
    # Ratio between consecutive links, generalising link_profile: l_i = l_{i-1}/link_ratio,
    # normalised so that the links sum to total_length (1 = equal links, φ = 1.618... = golden,
    # 1.5 = the peer comparison's 7-DOF arm, explauto's "mid_dimensional" arm; < 1 makes links grow
    # from the base). 0 (default) = the ratio named by link_profile (equal: 1, golden: φ), so
    # existing configs keep bit-identical link lengths; a nonzero link_ratio requires
    # link_profile "equal" (one way of saying the geometry, never two that could disagree).
    link_ratio: float = 0.0
    # Symmetric range ±joint_limit (rad) of joints 1..dof-1. The paper gives no ranges. Choice:
    # ±π/2, wide enough that a 7-30 DOF arm can curl back and reach almost the whole disk of
    # radius total_length (the paper's figures draw the reachable area as a full half-disk in
    # x ≥ 0 for Y = [0,150]×[-150,150]) while excluding links folding flat onto each other.
    joint_limit: float = math.pi / 2
    # Symmetric range ±base_limit (rad) of the base joint 0. Choice: ±π/2, so the first link
    # points into the half-plane x ≥ 0 in which the paper's task spaces lie (Y = [0,150]×[-150,150]).
    base_limit: float = math.pi / 2
    # Total bend (rad) of the rest posture, spread evenly over joints 1..dof-1 (each bent by
    # rest_bend/(dof-1), counter-clockwise); the base angle is then chosen so that the rest tip
    # lies on the +x axis. Paper: the rest position is "not straight and slightly bent" (to avoid
    # starting at the fully-unfolded singularity). Choice: π/3 (60° in total), which puts the
    # rest tip at ~95% of the arm's length (47.7 units for a 50-unit equal-link arm).
    # With dof == 1 there is nothing to bend and the rest posture is [0].
    rest_bend: float = math.pi / 3
    # Shape of the rest bend over joints 1..dof-1 (paper: "not straight and slightly bent", to avoid
    # starting at the unfolded singularity). "arc" (default): every joint bent by rest_bend/(dof-1) the
    # same way, a C. "zigzag": joints bent alternately by ±rest_bend/(dof-1) (+ first), an accordion: as
    # far from straight per joint as the arc, but with no net curl. Which one
    # (docs/notes/reaching-joint-limits.md): a C-shaped rest commits the arm to curling its way when the
    # tip must come in toward the base, which is harmless when the base joint's range covers every
    # direction of the task space (the paper's arm and every arm config here but one: base ±π/2, Y
    # in x ≥ 0), and fatal when it does not: on config/arm7_ratio15.yaml (base ±π/3, Y reaching x < 0)
    # goals beside the base beyond −π/3 need the opposite curl (every IK solution of (0.151, -0.42) has
    # joints 1-3 at -π/3), and such test goals are missed even with the true Jacobian. "zigzag" leaves
    # the curl to the goal's side, but lies near the unfolded singularity: use it with the learner's
    # reach_damping (with J⁺ it misses more of those goals, and on the 15-DOF arm it is far worse than
    # "arc"). In both shapes the base angle then puts the rest tip on the +x axis.
    rest_shape: str = "arc"
    # "kinematic" (qpos set + mj_kinematics) | "dynamic" (position actuators + physics).
    mode: str = "kinematic"
    # Multiplicative motor noise on each commanded joint displacement:
    # realised Δα_i = Δα_i · (1 + motor_noise · N(0,1)), independently per joint and per
    # micro-action, drawn from the simulator's own generator, then clipped to the joint limits.
    # Paper: the real 8-DOF arm had "low quality motors whose averaged noise is 20%" -> 0.2.
    # The paper's simulated arm is noise-free -> default 0.
    motor_noise: float = 0.0
    # --- dynamic mode only ------------------------------------------------------------------
    # Choices (not in the paper): rotor inertia (armature) dominates the light links, so each joint
    # behaves like a decoupled, critically damped servo with natural frequency
    # sqrt(kp/armature) = 100 rad/s and damping ratio damping/(2·sqrt(kp·armature)) = 1; with timestep
    # 0.01 s (ω·h = 1, stable with the implicitfast integrator) a 0.05 rad micro-action settles to
    # 1e-4 rad in ~16 steps, a move back to rest from anywhere in ~25-35 steps. Gravity is off (hinge
    # axes are z anyway) and contacts disabled.
    timestep: float = 0.01          # s, physics step
    kp: float = 1.0e4               # position actuator gain (N·m/rad in MuJoCo units)
    damping: float = 200.0          # joint viscous damping (N·m·s/rad)
    armature: float = 1.0           # rotor inertia added to each joint (kg·m²)
    arm_mass: float = 5.0e-4        # total link mass (kg): half evenly, half ∝ link length
    settle_tolerance: float = 1.0e-4   # settled when ||qpos - ctrl||_2 < this (rad) ...
    settle_velocity: float = 1.0e-2    # ... and ||qvel||_2 < this (rad/s)
    max_settle_steps: int = 1000       # give up settling after this many physics steps
    settle_check_every: int = 2        # physics steps between settle checks

    # ------------------------------------------------------------------ validation / io
    def validate(self) -> None:
        """Raise ValueError naming the first bad field and its allowed range."""

        def real(name: str, lo: float, hi: float, lo_open: bool = False, hi_open: bool = False) -> float:
            v = getattr(self, name)
            if not is_real(v) or not math.isfinite(float(v)):
                raise ValueError(f"ArmSpec.{name} must be a finite number, got {v!r}")
            v = float(v)
            bad_lo = v <= lo if lo_open else v < lo
            bad_hi = v >= hi if hi_open else v > hi
            if bad_lo or bad_hi:
                rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
                raise ValueError(f"ArmSpec.{name} must be in {rng}, got {v!r}")
            return v

        def integer(name: str, lo: int, hi: int) -> int:
            v = getattr(self, name)
            if not is_int(v) or not lo <= int(v) <= hi:
                raise ValueError(f"ArmSpec.{name} must be an integer in [{lo}, {hi}], got {v!r}")
            return int(v)

        integer("dof", 1, MAX_DOF)
        real("total_length", 0.0, 1.0e6, lo_open=True)
        if self.link_profile not in LINK_PROFILES:
            raise ValueError(f"ArmSpec.link_profile must be one of {LINK_PROFILES}, got {self.link_profile!r}")
        if real("link_ratio", 0.0, 100.0) != 0.0:
            if float(self.link_ratio) < 0.01:
                raise ValueError(f"ArmSpec.link_ratio must be 0 (from link_profile) or in [0.01, 100], "
                                 f"got {self.link_ratio!r}")
            if self.link_profile != "equal":
                raise ValueError(f"ArmSpec.link_ratio={self.link_ratio!r} and link_profile="
                                 f"{self.link_profile!r} both set the link lengths; allowed: link_ratio 0 "
                                 f"with any link_profile, or a link_ratio with link_profile 'equal'")
        real("joint_limit", 0.0, math.pi, lo_open=True)
        real("base_limit", 0.0, math.pi, lo_open=True)
        real("rest_bend", 0.0, 2.0 * math.pi)
        if self.rest_shape not in REST_SHAPES:
            raise ValueError(f"ArmSpec.rest_shape must be one of {REST_SHAPES}, got {self.rest_shape!r}")
        if self.mode not in MODES:
            raise ValueError(f"ArmSpec.mode must be one of {MODES}, got {self.mode!r}")
        real("motor_noise", 0.0, 2.0)
        real("timestep", 0.0, 0.1, lo_open=True)
        real("kp", 0.0, 1.0e9, lo_open=True)
        real("damping", 0.0, 1.0e9)
        real("armature", 0.0, 1.0e9, lo_open=True)
        real("arm_mass", 0.0, 1.0e9, lo_open=True)
        real("settle_tolerance", 0.0, 1.0, lo_open=True)
        real("settle_velocity", 0.0, 1.0e3, lo_open=True)
        integer("max_settle_steps", 1, 10_000_000)
        integer("settle_check_every", 1, 10_000)
        # the rest posture must lie within the limits
        if self.dof > 1 and self.rest_bend / (self.dof - 1) > self.joint_limit:
            raise ValueError(
                f"ArmSpec.rest_bend must be in [0, (dof-1)*joint_limit] = "
                f"[0, {(self.dof - 1) * self.joint_limit:g}] so that each joint's share is within its limit, "
                f"got {self.rest_bend!r}")
        base = float(self._rest_unchecked()[0])
        if abs(base) > self.base_limit:
            raise ValueError(
                f"ArmSpec.rest_bend={self.rest_bend!r} needs a rest base angle {base:.4f} outside "
                f"±base_limit={self.base_limit:g}: lower rest_bend or raise base_limit")

    @classmethod
    def from_dict(cls, d: dict) -> "ArmSpec":
        """Build from a mapping of field names (e.g. a YAML block); unknown key -> ValueError."""
        if not isinstance(d, dict):
            raise ValueError(f"ArmSpec.from_dict expects a dict, got {type(d).__name__}")
        names = {f.name: f for f in dataclasses.fields(cls)}
        kw = {}
        for k, v in d.items():
            if k not in names:
                raise ValueError(f"ArmSpec: unknown key {k!r}; allowed keys: {sorted(names)}")
            default = names[k].default
            # YAML gives ints for floats ("kp: 10000"): accept and convert.
            if isinstance(default, float) and is_int(v):
                v = float(v)
            kw[k] = v
        spec = cls(**kw)
        spec.validate()
        return spec

    # ------------------------------------------------------------------ geometry
    def ratio(self) -> float:
        """The ratio l_{i-1}/l_i between consecutive links: ``link_ratio`` when set, else the one
        ``link_profile`` names (equal: 1, golden: φ)."""
        if float(self.link_ratio) != 0.0:
            return float(self.link_ratio)
        return GOLDEN_RATIO if self.link_profile == "golden" else 1.0

    def link_lengths(self) -> np.ndarray:
        """l_i ∝ ratio^-i (i = 0 at the base), normalised to ``total_length``. (ratio 1 gives
        exact ones, ratio φ the same floats as the former golden formula φ^-i: existing arms'
        lengths are bit-identical.)"""
        n = int(self.dof)
        w = self.ratio() ** (-np.arange(n, dtype=float))
        return w * (float(self.total_length) / w.sum())

    def limits(self) -> tuple[np.ndarray, np.ndarray]:
        upper = np.full(int(self.dof), float(self.joint_limit))
        upper[0] = float(self.base_limit)
        return -upper, upper

    def _rest_unchecked(self) -> np.ndarray:
        n = int(self.dof)
        a = np.zeros(n)
        if n == 1:
            return a
        a[1:] = float(self.rest_bend) / (n - 1)
        if self.rest_shape == "zigzag":
            a[2::2] *= -1.0
        tip = forward_kinematics(a[None, :], self.link_lengths())[0]
        a[0] = -math.atan2(tip[1], tip[0])
        return a

    def rest_posture(self) -> np.ndarray:
        """α_rest: even bend over joints 1..n-1, base angle putting the tip on the +x axis."""
        return self._rest_unchecked()

    def joint_names(self) -> list[str]:
        return [f"joint_{i}" for i in range(int(self.dof))]


def forward_kinematics(alphas: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Batched planar FK, base at the origin: (N, n) relative joint angles -> (N, 2) tip positions."""
    c = np.cumsum(alphas, axis=1)
    return np.stack((np.cos(c) @ lengths, np.sin(c) @ lengths), axis=1)


def tip_jacobian(alpha: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Analytic Jacobian ∂y/∂α (2, n) of :func:`forward_kinematics` at one posture: with
    c_i = Σ_{j≤i} α_j, ∂y/∂α_j = Σ_{i≥j} l_i (−sin c_i, cos c_i). (A reference for tests and
    checks of the reacher; the learner itself only ever uses its learned local Jacobian.)"""
    c = np.cumsum(np.asarray(alpha, dtype=float))
    lengths = np.asarray(lengths, dtype=float)
    tail_x = np.cumsum((lengths * np.cos(c))[::-1])[::-1]
    tail_y = np.cumsum((lengths * np.sin(c))[::-1])[::-1]
    return np.stack((-tail_y, tail_x))


def _f(x: float) -> str:
    return repr(float(x))  # full precision, so that MuJoCo and numpy FK agree to ~1e-14


def arm_mjcf(spec: ArmSpec) -> str:
    """Generated MJCF of the arm: radians, base at the origin, arm in the xy plane, α=0 along +x,
    site "tip" at the end effector, one position actuator per joint (used in dynamic mode)."""
    spec.validate()
    n = int(spec.dof)
    lengths = spec.link_lengths()
    lower, upper = spec.limits()
    # half of the mass spread evenly, half ∝ length: no link of a long golden arm (lengths down
    # to φ^-99) gets a mass MuJoCo would reject
    masses = float(spec.arm_mass) * (0.5 / n + 0.5 * lengths / lengths.sum())
    radius = 0.01 * float(spec.total_length)  # visual thickness only
    out = [
        '<mujoco model="sagg_planar_arm">',
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="{_f(spec.timestep)}" gravity="0 0 0" integrator="implicitfast">',
        '    <flag contact="disable"/>',
        '  </option>',
        '  <worldbody>',
    ]
    indent = "    "
    for i in range(n):
        pos = "0 0 0" if i == 0 else f"{_f(lengths[i - 1])} 0 0"
        li, mi = float(lengths[i]), float(masses[i])
        # solid cylinder of the link's length and radius (always a valid inertia)
        i_perp = mi * (3.0 * radius * radius + li * li) / 12.0
        i_axis = 0.5 * mi * radius * radius
        out += [
            f'{indent}<body name="link_{i}" pos="{pos}">',
            f'{indent}  <joint name="joint_{i}" type="hinge" axis="0 0 1" limited="true" '
            f'range="{_f(lower[i])} {_f(upper[i])}" damping="{_f(spec.damping)}" armature="{_f(spec.armature)}"/>',
            f'{indent}  <inertial pos="{_f(li / 2)} 0 0" mass="{_f(mi)}" '
            f'diaginertia="{_f(i_axis)} {_f(i_perp)} {_f(i_perp)}"/>',
            (f'{indent}  <geom name="link_{i}_geom" type="capsule" fromto="0 0 0 {_f(li)} 0 0" '
             if li > 1e-6 * float(spec.total_length) else  # visual only; MuJoCo rejects tiny fromto
             f'{indent}  <geom name="link_{i}_geom" type="sphere" ')
            + f'size="{_f(radius)}" contype="0" conaffinity="0" rgba="0.3 0.5 0.8 1"/>',
        ]
        indent += "  "
    out.append(f'{indent}<site name="tip" pos="{_f(lengths[-1])} 0 0" size="{_f(2 * radius)}"/>')
    for i in range(n - 1, -1, -1):
        indent = indent[:-2]
        out.append(f"{indent}</body>")
    out += ['  </worldbody>', '  <actuator>']
    for i in range(n):
        out.append(
            f'    <position name="act_{i}" joint="joint_{i}" kp="{_f(spec.kp)}" ctrllimited="true" '
            f'ctrlrange="{_f(lower[i])} {_f(upper[i])}"/>')
    out += ['  </actuator>', '</mujoco>']
    return "\n".join(out) + "\n"


class ArmSim:
    """The simulated arm: micro-actions in, measured (α, y) out.

    ``data.ctrl`` holds the last clipped command in dynamic mode; kinematic mode never touches
    it after reset (it stays at the rest posture), to keep command() minimal."""

    task_dim = 2

    def __init__(self, spec: ArmSpec, seed: int):
        if not isinstance(spec, ArmSpec):
            raise ValueError(f"ArmSim.spec must be an ArmSpec, got {type(spec).__name__}")
        spec.validate()
        if not is_int(seed) or int(seed) < 0:
            raise ValueError(f"ArmSim.seed must be an integer >= 0, got {seed!r}")
        self.spec = spec
        self.seed = int(seed)
        self.n_joints = int(spec.dof)
        self.joint_names = spec.joint_names()
        self.lower, self.upper = spec.limits()
        self.rest = spec.rest_posture()
        self.link_lengths = spec.link_lengths()
        for arr in (self.lower, self.upper, self.rest, self.link_lengths):
            arr.flags.writeable = False  # shared with callers: protect from accidental edits
        self.rng = np.random.default_rng(self.seed)
        self.model = mujoco.MjModel.from_xml_string(arm_mjcf(spec))
        self.data = mujoco.MjData(self.model)
        self._dynamic = spec.mode == "dynamic"
        self._noise = float(spec.motor_noise)
        # views into MjData (no per-call allocation)
        self._qpos = self.data.qpos
        self._qvel = self.data.qvel
        self._ctrl = self.data.ctrl
        tip_id = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SITE, "tip")
        self._tip = self.data.site_xpos[tip_id, :2]
        self._shape = (self.n_joints,)
        self._buf = np.empty(self.n_joints)
        self._nbuf = np.empty(self.n_joints)
        self._nblock: np.ndarray | None = None   # pre-drawn noise factors (see _draw_noise_block)
        self._nidx = NOISE_BLOCK                 # next row of _nblock; NOISE_BLOCK = none left
        self._block_state: dict | None = None    # rng state at the start of _nblock
        self._tol = float(spec.settle_tolerance)
        self._vtol = float(spec.settle_velocity)
        self._max_steps = int(spec.max_settle_steps)
        self._every = int(spec.settle_check_every)
        self.last_settle_steps = 0     # physics steps used by the last dynamic command
        self.last_settled = True       # whether it met the settle criteria
        self.reset()

    def reseed(self, seed: int) -> None:
        """Restart the motor-noise generator as ``ArmSim(spec, seed)`` starts it (the physics state is
        left alone: ``reset`` restores it). Lets one instance serve many independent reaches."""
        if not is_int(seed) or int(seed) < 0:
            raise ValueError(f"ArmSim.seed must be an integer >= 0, got {seed!r}")
        self.seed = int(seed)
        self.rng = np.random.default_rng(self.seed)
        self._nblock, self._block_state, self._nidx = None, None, NOISE_BLOCK

    # ------------------------------------------------------------------ protocol
    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        """Teleport to the rest posture with zero velocity; no noise, no RNG draw."""
        mujoco.mj_resetData(self.model, self.data)
        self._qpos[:] = self.rest
        self._ctrl[:] = self.rest
        mujoco.mj_kinematics(self.model, self.data)
        self.last_settle_steps, self.last_settled = 0, True
        return self._qpos.copy(), self._tip.copy()

    def command(self, alpha_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One micro-action toward ``alpha_target`` (absolute joint angles, rad).

        Realised posture = clip(α + Δ·(1 + motor_noise·N(0,1)), limits) with Δ = target - α and α
        the measured posture before the command (noise on the displacement, as a motor that
        over/undershoots its move; choice). Kinematic mode writes it to qpos; dynamic mode to
        the actuators' ctrl and steps the physics until settled. Returns the measured (α, y)
        afterwards (fresh arrays). Written for speed: no per-call allocation besides the two
        returned copies."""
        t = alpha_target if type(alpha_target) is np.ndarray else np.asarray(alpha_target, dtype=float)
        if t.shape != self._shape:
            raise ValueError(f"alpha_target must have shape ({self.n_joints},), got {np.shape(alpha_target)}")
        if not all_finite(t):
            raise ValueError("alpha_target must be finite (no NaN/inf)")
        qpos = self._qpos
        if self._noise > 0.0:
            if self._nidx >= NOISE_BLOCK:
                self._draw_noise_block()
            buf = self._buf
            np.subtract(t, qpos, out=buf)
            buf *= self._nblock[self._nidx]   # 1 + motor_noise·N(0,1), pre-drawn
            self._nidx += 1
            buf += qpos
            t = buf
        if self._dynamic:
            ctrl = self._ctrl
            np.maximum(t, self.lower, out=ctrl)
            np.minimum(ctrl, self.upper, out=ctrl)
            self._settle()
        else:
            np.maximum(t, self.lower, out=qpos)
            np.minimum(qpos, self.upper, out=qpos)
            mujoco.mj_kinematics(self.model, self.data)
        return qpos.copy(), self._tip.copy()

    def _draw_noise_block(self) -> None:
        """Draw the factors (1 + motor_noise·N(0,1)) of the next NOISE_BLOCK micro-actions at
        once (one generator call instead of one per micro-action; the stream of normals is the
        same as drawing them one command at a time). The generator state at the block start is
        kept so that get_state/set_state can rebuild the block exactly."""
        self._block_state = self.rng.bit_generator.state
        block = self.rng.standard_normal((NOISE_BLOCK, self.n_joints))
        block *= self._noise
        block += 1.0
        self._nblock = block
        self._nidx = 0

    def _settle(self) -> None:
        """Step the physics until ||qvel|| < settle_velocity and ||qpos - ctrl|| < settle_tolerance
        (Euclidean norms over the joints: stricter than per-joint bounds, and cheap to test),
        checking every settle_check_every steps, at most max_settle_steps steps."""
        m, d = self.model, self.data
        qpos, qvel, ctrl = self._qpos, self._qvel, self._ctrl
        every, tol2, vtol2 = self._every, self._tol * self._tol, self._vtol * self._vtol
        buf = self._nbuf
        steps = 0
        settled = False
        max_steps = self._max_steps
        while steps < max_steps:
            k = every if steps + every <= max_steps else max_steps - steps
            mujoco.mj_step(m, d, nstep=k)
            steps += k
            if qvel.dot(qvel) < vtol2:
                np.subtract(qpos, ctrl, out=buf)
                if buf.dot(buf) < tol2:
                    settled = True
                    break
        # after mj_step, site_xpos belongs to the posture before the last step: refresh it
        mujoco.mj_kinematics(m, d)
        self.last_settle_steps, self.last_settled = steps, settled

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        return self._qpos.copy(), self._tip.copy()

    def joint_velocities(self) -> np.ndarray:
        """The joints' velocities (dynamic mode; zeros in kinematic mode)."""
        return self._qvel.copy()

    def set_targets(self, targets: np.ndarray) -> None:
        """Write joint targets to the position actuators, without stepping the physics (the
        MuJoCo bridge's real-time dynamic mode steps it itself)."""
        self._ctrl[:] = targets

    def tip_positions(self, alphas: np.ndarray) -> np.ndarray:
        """Batched numpy FK: (N, n) -> (N, 2), or (n,) -> (2,). Same frames as the MuJoCo model."""
        a = np.asarray(alphas, dtype=float)
        single = a.ndim == 1
        a2 = a[None, :] if single else a
        if a2.ndim != 2 or a2.shape[1] != self.n_joints:
            raise ValueError(f"alphas must have shape (N, {self.n_joints}) or ({self.n_joints},), got {a.shape}")
        y = forward_kinematics(a2, self.link_lengths)
        return y[0] if single else y

    # ------------------------------------------------------------------ checkpointing
    def get_state(self) -> dict:
        """JSON-able snapshot: physics state, controls, solver warm start and the noise RNG."""
        d = self.data
        return {
            "n_joints": self.n_joints,
            "mode": self.spec.mode,
            "time": float(d.time),
            "qpos": d.qpos.tolist(),
            "qvel": d.qvel.tolist(),
            "act": d.act.tolist(),
            "ctrl": d.ctrl.tolist(),
            "qacc_warmstart": d.qacc_warmstart.tolist(),
            # noise generator: state at the start of the current pre-drawn block + position in
            # it (noise_index None: no block drawn yet, "rng" is the generator's current state)
            "rng": self._block_state if self._nblock is not None else self.rng.bit_generator.state,
            "noise_index": int(self._nidx) if self._nblock is not None else None,
            "last_settle_steps": int(self.last_settle_steps),
            "last_settled": bool(self.last_settled),
        }

    def set_state(self, state: dict) -> None:
        if not isinstance(state, dict):
            raise ValueError(f"state must be a dict from get_state, got {type(state).__name__}")
        if state.get("n_joints") != self.n_joints:
            raise ValueError(f"state.n_joints must be {self.n_joints}, got {state.get('n_joints')!r}")
        d = self.data
        arrays = {}
        for key, size in (("qpos", self.model.nq), ("qvel", self.model.nv), ("act", self.model.na),
                          ("ctrl", self.model.nu), ("qacc_warmstart", self.model.nv)):
            v = np.asarray(state.get(key, []), dtype=float)
            if v.shape != (size,) or not np.all(np.isfinite(v)):
                raise ValueError(f"state.{key} must be {size} finite numbers")
            arrays[key] = v
        rng_state = state.get("rng")
        if not isinstance(rng_state, dict) or rng_state.get("bit_generator") != type(self.rng.bit_generator).__name__:
            raise ValueError(f"state.rng must be a {type(self.rng.bit_generator).__name__} state dict")
        nidx = state.get("noise_index")
        if nidx is not None and not (is_int(nidx) and 0 <= nidx <= NOISE_BLOCK):
            raise ValueError(f"state.noise_index must be None or an integer in [0, {NOISE_BLOCK}], got {nidx!r}")
        if nidx is not None and self._noise == 0.0:
            raise ValueError("state.noise_index must be None for a noise-free arm (motor_noise = 0)")
        self.rng.bit_generator.state = rng_state
        if nidx is None:
            self._nblock, self._block_state, self._nidx = None, None, NOISE_BLOCK
        else:
            self._draw_noise_block()   # same block as when the state was taken
            self._nidx = int(nidx)
        d.time = float(state.get("time", 0.0))
        for key, v in arrays.items():
            getattr(d, key)[:] = v
        self.last_settle_steps = int(state.get("last_settle_steps", 0))
        self.last_settled = bool(state.get("last_settled", True))
        mujoco.mj_kinematics(self.model, self.data)


# ---------------------------------------------------------------------- reachable area
@dataclass
class ReachableArea:
    """Occupancy grid of reachable effector positions inside the box [lower, upper]: 2-D (the
    planar arm's tip, or a model arm with two task axes) or 3-D (a model arm's effector in space).

    The box is tiled by mask.shape cells (cell_size = (upper-lower)/mask.shape, at most
    ``resolution`` per side); mask[i, j(, k)] is True when some sampled configuration put the
    effector in that cell (i along the first task axis, j along the second, ...). ``cell_points``
    (optional) holds one actually reached position per True cell, in np.flatnonzero(mask) order (a
    row is NaN in the rare case where no sample's float64 position confirmed that cell; see
    reachable_area)."""

    lower: np.ndarray
    upper: np.ndarray
    resolution: float
    mask: np.ndarray
    cell_points: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.lower = np.asarray(self.lower, dtype=float)
        self.upper = np.asarray(self.upper, dtype=float)
        self.mask = np.asarray(self.mask, dtype=bool)
        if self.mask.ndim not in (2, 3):
            raise ValueError(f"ReachableArea.mask must be a 2-D or 3-D bool grid, got shape {self.mask.shape}")
        if self.lower.shape != (self.mask.ndim,) or self.upper.shape != (self.mask.ndim,):
            raise ValueError(f"ReachableArea.lower/upper must have {self.mask.ndim} values each (one per "
                             f"mask dimension), got {self.lower.tolist()}, {self.upper.tolist()}")

    @property
    def dim(self) -> int:
        """Number of task dimensions (2 or 3)."""
        return self.mask.ndim

    @property
    def cell_size(self) -> np.ndarray:
        return (np.asarray(self.upper, float) - np.asarray(self.lower, float)) / np.asarray(self.mask.shape)

    def contains(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=float)
        d = self.mask.ndim
        if p.ndim != 2 or p.shape[1] != d:
            raise ValueError(f"points must have shape (N, {d}), got {p.shape}")
        lo, hi = np.asarray(self.lower, float), np.asarray(self.upper, float)
        inside = np.all((p >= lo) & (p <= hi), axis=1)
        shape = np.asarray(self.mask.shape)
        ij = np.floor((np.where(inside[:, None], p, lo) - lo) / self.cell_size).astype(np.int64)
        ij = np.clip(ij, 0, shape - 1)  # p == upper belongs to the last cell
        return inside & self.mask[tuple(ij.T)]

    def boundary_cells(self) -> int:
        """Reachable cells with an unreachable neighbour inside the box (cells beyond the box edge
        are not counted as unreachable: the box cuts the reachable set exactly there). Neighbours:
        in 2-D the 4 that share an edge (the planar arm's estimate, unchanged); in 3-D all 26 that
        share a face, an edge or a corner: a voxel cut by a slanted surface usually keeps its 6 face
        neighbours reachable while lying partly outside (on a spherical-shell workspace, 6 neighbours
        overestimate the volume more than 26 underestimate it; test_model_arm)."""
        m = self.mask
        pad = np.pad(m, 1, mode="constant", constant_values=True)
        if m.ndim == 2:
            offsets = [(-1, 0), (1, 0), (0, -1), (0, 1)]
        else:
            offsets = [o for o in np.ndindex(*(3,) * m.ndim) if o != (1,) * m.ndim]
            offsets = [tuple(int(k) - 1 for k in o) for o in offsets]
        nb_all = np.ones_like(m)
        for off in offsets:
            nb_all &= pad[tuple(slice(1 + k, pad.shape[i] - 1 + k) for i, k in enumerate(off))]
        return int(np.count_nonzero(m & ~nb_all))

    def area(self) -> float:
        """Estimated reachable area (2-D) or volume (3-D) inside the box. Boundary cells are on
        average half covered, so they count 1/2 (removes most of the bias of plain cell counting:
        +half a cell layer over the whole boundary)."""
        n = np.count_nonzero(self.mask) - 0.5 * self.boundary_cells()
        return float(n * np.prod(self.cell_size))

    def share(self) -> float:
        """Reachable area (volume) / area (volume) of the bounds box."""
        return self.area() / float(np.prod(np.asarray(self.upper, float) - np.asarray(self.lower, float)))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n points: a reachable cell chosen uniformly, then a uniform point inside it."""
        if not is_int(n) or n < 0:
            raise ValueError(f"n must be an integer >= 0, got {n!r}")
        cells = np.flatnonzero(self.mask)
        if cells.size == 0:
            raise ValueError("ReachableArea.mask has no reachable cell inside the bounds")
        pick = cells[rng.integers(0, cells.size, size=n)]
        ij = np.stack(np.unravel_index(pick, self.mask.shape), axis=1)
        return np.asarray(self.lower, float) + (ij + rng.random((n, self.mask.ndim))) * self.cell_size


def check_bounds(lower, upper, dim: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """``lower``/``upper`` as float arrays of ``dim`` finite numbers with upper > lower, else ValueError."""
    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    if lo.shape != (dim,) or hi.shape != (dim,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError(f"lower/upper must be {dim} finite numbers each, got {lower!r}, {upper!r}")
    if np.any(hi <= lo):
        raise ValueError(f"upper must be > lower in every dimension, got lower={lo.tolist()}, upper={hi.tolist()}")
    return lo, hi


def _global_configs(n: int, count: int, lower: np.ndarray, upper: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Configurations mixing straight, curled and random shapes: base uniform in its range; the
    other joints at clip(c + s²·u, -1, 1)·limit with a common curl c = U(-1,1)·U(0,1)² and a
    spread s = U(0,1) around it, u = U(-1,1) per joint. (Plain uniform joint angles concentrate
    a long chain's tip near the base, leaving the outer workspace unsampled.)"""
    a = np.empty((count, n))
    a[:, 0] = rng.uniform(lower[0], upper[0], size=count)
    if n > 1:
        c = rng.uniform(-1.0, 1.0, (count, 1)) * rng.random((count, 1)) ** 2
        s = rng.random((count, 1)) ** 2
        u = rng.uniform(-1.0, 1.0, (count, n - 1))
        a[:, 1:] = np.clip(c + s * u, -1.0, 1.0) * upper[1:]
    return a


def occupancy_grid(lo: np.ndarray, hi: np.ndarray, resolution, center: np.ndarray, radius: float,
                   jlo: np.ndarray, jhi: np.ndarray,
                   draw_global: Callable[[int, np.random.Generator], np.ndarray],
                   fk_fast: Callable[[np.ndarray], np.ndarray],
                   fk_exact: Callable[[np.ndarray], np.ndarray] | None,
                   samples: int, seed: int, refine_rounds: int, batch: int,
                   flatten_power: float) -> ReachableArea:
    """The sampling engine of :func:`reachable_area`, for any arm and any number of task
    dimensions (the box [lo, hi] has as many as the effector positions ``fk_fast`` returns).

    ``samples`` joint configurations in 1 + ``refine_rounds`` rounds: the first drawn by
    ``draw_global(count, rng)``, each later one re-drawing the previous round's configurations
    with probability ∝ (hit count of their cell)^-flatten_power and perturbing them with Gaussian
    noise of log-uniform scale (1e-3..0.5 of each joint range [jlo, jhi]), clipped to it.
    ``fk_fast`` maps (N, joints) configurations to (N, d) positions for the occupancy; one
    exactly reached position per cell is then kept, from ``fk_exact`` (None: ``fk_fast`` is
    exact), if it falls in the same cell. Only cells within ``radius`` of ``center`` (a ball that
    holds every effector position) are tracked."""
    if not is_real(resolution) or not math.isfinite(float(resolution)) or float(resolution) <= 0:
        raise ValueError(f"resolution must be a finite number > 0, got {resolution!r}")
    resolution = float(resolution)
    if not is_int(samples) or samples < 1:
        raise ValueError(f"samples must be an integer >= 1, got {samples!r}")
    if not is_int(refine_rounds) or refine_rounds < 0:
        raise ValueError(f"refine_rounds must be an integer >= 0, got {refine_rounds!r}")
    if not is_real(flatten_power) or not 0.0 <= float(flatten_power) <= 10.0:
        raise ValueError(f"flatten_power must be in [0, 10], got {flatten_power!r}")
    if not is_int(batch) or batch < 1:
        raise ValueError(f"batch must be an integer >= 1, got {batch!r}")
    if not is_int(seed) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    fpow = float(flatten_power)
    d = lo.shape[0]
    shape = np.maximum(np.ceil((hi - lo) / resolution - 1e-9).astype(np.int64), 1)
    ncells = math.prod(int(s) for s in shape)
    if ncells > MAX_GRID_CELLS:
        raise ValueError(f"resolution={resolution:g} gives {ncells} cells for the box; "
                         f"must give at most {MAX_GRID_CELLS} (raise resolution)")
    cell = (hi - lo) / shape
    # Work on the sub-grid of cells that can hold the effector (within radius of center).
    i0 = np.clip(np.floor((center - radius - lo) / cell).astype(np.int64), 0, shape)
    i1 = np.clip(np.floor((center + radius - lo) / cell).astype(np.int64) + 1, 0, shape)
    sub = i1 - i0
    mask = np.zeros(tuple(shape), dtype=bool)
    if np.any(sub <= 0):
        return ReachableArea(lo, hi, resolution, mask, np.zeros((0, d)))
    nsub = math.prod(int(s) for s in sub)
    counts = np.zeros(nsub, dtype=np.int64)
    has_pt = np.zeros(nsub, dtype=bool)
    best_pt = np.full((nsub, d), np.nan)
    n = int(jlo.shape[0])
    rng = np.random.default_rng(seed)
    rounds = 1 + int(refine_rounds)
    per_round = max(1, int(samples) // rounds)

    def cells_of(p: np.ndarray) -> np.ndarray:
        inside = np.all((p >= lo) & (p <= hi), axis=1)
        ij = np.clip(np.floor((p - lo) / cell).astype(np.int64), 0, shape - 1) - i0
        ok = inside & np.all((ij >= 0) & (ij < sub), axis=1)
        flat = ij[:, 0]
        for k in range(1, d):  # row-major index in the sub-grid
            flat = flat * sub[k] + ij[:, k]
        return np.where(ok, flat, -1)

    def record(a: np.ndarray) -> np.ndarray:
        p = fk_fast(a)
        f = cells_of(p)
        okrows = np.flatnonzero(f >= 0)
        fo = f[okrows]
        counts[:] += np.bincount(fo, minlength=nsub)
        # one exactly reached point per cell: the first sample hitting a cell that has none yet,
        # kept if its exact position falls in that same cell
        uniq, first = np.unique(fo, return_index=True)
        need = ~has_pt[uniq]
        if np.any(need):
            cand = uniq[need]
            rows = okrows[first[need]]
            pe = p[rows] if fk_exact is None else fk_exact(a[rows])
            same = cells_of(pe) == cand
            best_pt[cand[same]] = pe[same]
            has_pt[cand[same]] = True
        return f

    configs = []
    for r in range(rounds):
        if r == 0:
            done = 0
            while done < per_round:
                k = min(batch, per_round - done)
                a = draw_global(k, rng)
                f = record(a)
                done += k
                configs.append((a, f))
            continue
        new_configs = []
        for a_prev, f_prev in configs:
            w = np.where(f_prev >= 0, np.maximum(counts[np.maximum(f_prev, 0)], 1) ** -fpow, 0.0)
            tot = w.sum()
            k = a_prev.shape[0]
            idx = rng.choice(k, size=k, p=w / tot) if tot > 0 else rng.integers(0, k, size=k)
            scale = 0.5 * (jhi - jlo)[None, :] * np.exp(rng.uniform(math.log(1e-3), 0.0, (k, 1)))
            a = np.clip(a_prev[idx] + scale * rng.standard_normal((k, n)), jlo, jhi)
            new_configs.append((a, record(a)))
        configs = new_configs

    sub_mask = (counts > 0).reshape(tuple(sub))
    mask[tuple(slice(int(a), int(b)) for a, b in zip(i0, i1))] = sub_mask
    # reached points in np.flatnonzero(mask) order (row-major over the full grid = row-major
    # over the sub-grid, since the sub-grid is a contiguous block)
    pts = best_pt[np.flatnonzero(counts > 0)]
    return ReachableArea(lo, hi, resolution, mask, pts)


def reachable_area(spec: ArmSpec, lower, upper, resolution: float | None = None,
                   samples: int = 400_000, seed: int = 0, refine_rounds: int = 7,
                   batch: int = 100_000, flatten_power: float = 2.0) -> ReachableArea:
    """Occupancy grid of the tip positions the planar arm can reach inside the box [lower, upper].

    Method (choice; the paper only draws the contour): ``samples`` random joint configurations
    within the limits, pushed through the same FK as :meth:`ArmSim.tip_positions`
    (:func:`occupancy_grid`). A first batch is drawn globally (:func:`_global_configs`); each of
    ``refine_rounds`` further batches re-draws the previous batch's configurations with
    probability ∝ (hit count of their cell)^-flatten_power and perturbs them with Gaussian noise
    of log-uniform scale (1e-3..0.5 of each joint range), which evens out the sample density over
    the task space and pushes it out to the hard-to-reach parts of the workspace boundary
    (extreme curls).
    Defaults: resolution = total_length/100 (0.5 units for the paper's arm), 400k samples in 8
    rounds, flatten_power 2: the area of a 15-DOF, 50-unit arm with ±π joints is within 0.5% of the
    disk area π·50², and with the default ±π/2 limits within ~1% of a 4M-sample estimate (7 to 30
    DOF).
    The estimate can only miss reachable cells (every marked cell was reached), never invent
    them; missed cells sit at the hardest-to-reach edge.
    """
    spec.validate()
    lo, hi = check_bounds(lower, upper)
    if resolution is None:
        resolution = float(spec.total_length) / 100.0
    n = int(spec.dof)
    lengths = spec.link_lengths()
    lengths32 = lengths.astype(np.float32)
    jlo, jhi = spec.limits()

    def fk32(a: np.ndarray) -> np.ndarray:
        # Occupancy from float32 trigonometry (much cheaper than float64; tip error ~1e-6 of the
        # arm length, far below any sensible resolution); the kept points are float64.
        c = np.cumsum(a, axis=1)
        c -= (2 * math.pi) * np.round(c * (0.5 / math.pi))  # wrap to [-π, π] before casting
        c = c.astype(np.float32)
        return np.stack((np.cos(c) @ lengths32, np.sin(c) @ lengths32), axis=1).astype(float)

    return occupancy_grid(lo, hi, resolution, np.zeros(2), float(spec.total_length) * (1 + 1e-9), jlo, jhi,
                          lambda k, rng: _global_configs(n, k, jlo, jhi, rng), fk32,
                          lambda a: forward_kinematics(a, lengths), samples, seed, refine_rounds, batch,
                          flatten_power)


def goals_in_area(area: ReachableArea, n: int, seed: int) -> np.ndarray:
    """n test goals from a reachable set: actually reached effector positions (``cell_points``)
    of reachable cells drawn uniformly, distinct cells when there are enough of them
    (Sec. 3.7: "uniformly distributed in the reachable area", at the grid resolution)."""
    pts = area.cell_points
    if pts is not None:
        pts = pts[np.all(np.isfinite(pts), axis=1)]
    if pts is None or len(pts) == 0:
        raise ValueError("no reachable tip position inside the bounds [lower, upper]")
    rng = np.random.default_rng([int(seed), 0x7E57])  # a stream separate from reachable_area's
    # distinct cells when there are enough of them
    idx = rng.choice(len(pts), size=n, replace=n > len(pts))
    return pts[idx].copy()


def test_goals(spec: ArmSpec, lower, upper, n: int = 100, seed: int = 0,
               area: ReachableArea | None = None) -> np.ndarray:
    """Paper Sec. 3.7: n test goals "uniformly distributed in the reachable area", here of the
    reachable area ∩ the box [lower, upper]. Choice: each goal is an actually reached tip
    position (from reachable_area's samples) in a reachable cell drawn uniformly, so every goal
    is exactly reachable and the set is uniform at the grid resolution (:func:`goals_in_area`).
    Reproducible from ``seed`` (the area uses ``seed`` too unless ``area`` is given)."""
    if not is_int(n) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if not is_int(seed) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    lo, hi = check_bounds(lower, upper)
    if area is None:
        area = reachable_area(spec, lo, hi, seed=seed)
    return goals_in_area(area, n, seed)


# not a pytest test despite the name
test_goals.__test__ = False  # type: ignore[attr-defined]
