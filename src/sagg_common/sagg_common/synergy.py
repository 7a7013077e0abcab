"""Parameterised motor synergies π_θ and their conversion to joint trajectories (paper Sec. 4-5).
ROS-free; shared by the synergy learner (which sends trajectories) and the bridge (which runs them).

A synergy turns its parameter vector θ into a joint trajectory: sample times t_k and, per joint,
either positions (the quadruped's sinusoids, tracked by position controllers) or velocities (the
fishing rod's constant joint velocities, tracked by velocity controllers). The trajectory is what
travels as ``trajectory_msgs/JointTrajectory`` on ``/<controller>/joint_trajectory``; the
in-process run executes the same arrays, so both ways drive the simulator identically.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def canonical_times(t: np.ndarray) -> np.ndarray:
    """Times rounded to whole nanoseconds, as ``int_ns / 1e9``: exactly what a receiver gets back
    from a ``builtin_interfaces/Duration`` (sec, nanosec) with :func:`duration_seconds`, so the graph
    and the in-process run interpolate the same numbers."""
    return np.round(np.asarray(t, dtype=float) * 1e9) / 1e9


def duration_seconds(sec: int, nanosec: int) -> float:
    """A (sec, nanosec) duration in seconds, computed as ``total_ns / 1e9`` (see canonical_times)."""
    return (int(sec) * 1_000_000_000 + int(nanosec)) / 1e9


def yaw_quaternion(phi: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation by ``phi`` about z, NOT sign-normalised: for phi in (-2π, 2π] the
    sign of w and z keeps the turn count, so :func:`quaternion_yaw` recovers phi (not only phi mod
    2π). This is how the quadruped's unwrapped yaw φ ∈ [-2π, 2π] travels in a PoseStamped."""
    return (math.cos(phi / 2.0), 0.0, 0.0, math.sin(phi / 2.0))


def quaternion_yaw(w: float, z: float) -> float:
    """Inverse of :func:`yaw_quaternion`: ``2·atan2(z, w)`` in (-2π, 2π]."""
    return 2.0 * math.atan2(z, w)


def transported_outcome(y):
    """The outcome as the learner receives it through the graph: a 3-D outcome (u, v, φ) travels as
    a PoseStamped, so φ goes through the quaternion and back (bit-level rounding); 2-D outcomes travel
    unchanged. The in-process run applies the same so both ways see identical numbers. None stays None."""
    if y is None:
        return None
    y = np.asarray(y, dtype=float).copy()
    if y.shape == (3,):
        w, _, _, z = yaw_quaternion(float(y[2]))
        y[2] = quaternion_yaw(w, z)
    return y


def _vec(name: str, value, n: int) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: got shape {arr.shape}; allowed: {n} finite values")
    return arr


@dataclass
class Trajectory:
    """Joint trajectory: ``times`` (K,) from 0, and ``positions`` or ``velocities`` (K, n)."""

    joint_names: list[str]
    times: np.ndarray
    positions: np.ndarray | None = None
    velocities: np.ndarray | None = None

    def __post_init__(self):
        self.times = np.asarray(self.times, dtype=float)
        k, n = len(self.times), len(self.joint_names)
        if k < 1 or np.any(np.diff(self.times) <= 0) or self.times[0] < 0:
            raise ValueError("trajectory times: allowed: at least one point, strictly increasing, >= 0")
        for name in ("positions", "velocities"):
            arr = getattr(self, name)
            if arr is not None:
                arr = np.asarray(arr, dtype=float).reshape(k, -1) if np.size(arr) else None
                if arr is not None and (arr.shape != (k, n) or not np.all(np.isfinite(arr))):
                    raise ValueError(f"trajectory {name}: got shape {arr.shape}; allowed: ({k}, {n}) finite")
                setattr(self, name, arr)
        if self.positions is None and self.velocities is None:
            raise ValueError("trajectory: allowed: positions or velocities (or both)")

    def sample_velocities(self, t: float) -> np.ndarray:
        """Velocity targets at time ``t``: the value of the last point at or before ``t`` (held)."""
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        return self.velocities[max(i, 0)].copy()


class SinusoidSynergy:
    """Quadruped synergy of paper Sec. 4.2: joint i tracks ``rest_i + am_i · sin(ω t + ph_i)``.

    θ = (am_1..am_n, ph_1..ph_n) (the paper lists phases first; the order is immaterial), with
    ``am_i ∈ [0, amplitude_max_i]`` and ``ph_i ∈ [0, 2π]`` (negative amplitudes would duplicate a
    phase shift of π: our choice). ``rate`` points per second are sent (the controller interpolates
    linearly between them): vague in the paper; ours 50 Hz, exposed as a parameter.
    """

    def __init__(self, joint_names, rest, amplitude_max, omega: float, duration: float, rate: float):
        self.joint_names = list(joint_names)
        n = len(self.joint_names)
        self.rest = _vec("rest_posture", rest, n)
        self.amplitude_max = _vec("synergy.amplitude_max", amplitude_max, n)
        if np.any(self.amplitude_max <= 0):
            raise ValueError("synergy.amplitude_max: allowed: every value > 0")
        for name, v in (("synergy.omega", omega), ("synergy.duration", duration), ("synergy.rate", rate)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: got {v!r}; allowed: a number > 0")
        self.omega, self.duration, self.rate = float(omega), float(duration), float(rate)

    @property
    def dim(self) -> int:
        return 2 * len(self.joint_names)

    @property
    def lower(self) -> np.ndarray:
        return np.zeros(self.dim)

    @property
    def upper(self) -> np.ndarray:
        return np.concatenate([self.amplitude_max, np.full(len(self.joint_names), 2 * math.pi)])

    def times(self) -> np.ndarray:
        k = max(1, int(round(self.duration * self.rate)))
        return canonical_times(np.linspace(0.0, self.duration, k + 1))

    def trajectory(self, theta) -> Trajectory:
        """θ → joint position trajectory ``q_i(t_k) = rest_i + am_i · sin(ω t_k + ph_i)`` (Sec. 4.2)."""
        theta = _vec("theta", theta, self.dim)
        n = len(self.joint_names)
        am, ph = theta[:n], theta[n:]
        t = self.times()
        pos = self.rest[None, :] + am[None, :] * np.sin(self.omega * t[:, None] + ph[None, :])
        return Trajectory(self.joint_names, t, positions=pos)


class VelocitySynergy:
    """Fishing-rod synergy of paper Sec. 5.1: θ = (v_1..v_n) ∈ [0, 1]^n, joint i tracks the constant
    velocity ``velocity_lower_i + v_i · (velocity_upper_i − velocity_lower_i)`` (rad/s) for
    ``duration`` (2 s), then stops (velocity 0). The paper gives θ ∈ [0, 1] but not the joint speeds
    it stands for: the mapping range is ours, a parameter. Points are sent at ``rate`` Hz plus a final
    zero-velocity point at ``duration``."""

    def __init__(self, joint_names, velocity_lower, velocity_upper, duration: float, rate: float):
        self.joint_names = list(joint_names)
        n = len(self.joint_names)
        self.velocity_lower = _vec("synergy.velocity_lower", velocity_lower, n)
        self.velocity_upper = _vec("synergy.velocity_upper", velocity_upper, n)
        if np.any(self.velocity_upper <= self.velocity_lower):
            raise ValueError("synergy.velocity_upper: allowed: every value > synergy.velocity_lower")
        for name, v in (("synergy.duration", duration), ("synergy.rate", rate)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: got {v!r}; allowed: a number > 0")
        self.duration, self.rate = float(duration), float(rate)

    @property
    def dim(self) -> int:
        return len(self.joint_names)

    @property
    def lower(self) -> np.ndarray:
        return np.zeros(self.dim)

    @property
    def upper(self) -> np.ndarray:
        return np.ones(self.dim)

    def joint_velocities(self, theta) -> np.ndarray:
        theta = _vec("theta", theta, self.dim)
        return self.velocity_lower + theta * (self.velocity_upper - self.velocity_lower)

    def trajectory(self, theta) -> Trajectory:
        """θ → velocity trajectory: constant joint velocities on [0, duration), then 0 (Sec. 5.1)."""
        vel = self.joint_velocities(theta)
        k = max(1, int(round(self.duration * self.rate)))
        t = canonical_times(np.linspace(0.0, self.duration, k + 1))
        v = np.repeat(vel[None, :], k + 1, axis=0)
        v[-1] = 0.0
        return Trajectory(self.joint_names, t, velocities=v)


class PostureSynergy:
    """The arm in the fixed context (learner parameter ``context`` = 'fixed'): θ = the absolute joint
    targets themselves, within the joint limits. One experiment = a return to the rest posture, then
    ONE position command θ (the hardware contract of the evolving arm: std_msgs/Float64MultiArray on
    ``/<controller>/commands``); the outcome is the settled tip. No trajectory: :meth:`command` is
    what goes out, in the order of ``joint_names``."""

    def __init__(self, joint_names, lower, upper, rest):
        self.joint_names = list(joint_names)
        n = len(self.joint_names)
        self._lower = _vec("joint_limits.lower", lower, n)
        self._upper = _vec("joint_limits.upper", upper, n)
        self.rest = _vec("rest_posture", rest, n)
        if np.any(self._upper <= self._lower):
            raise ValueError("joint_limits.upper: allowed: every value > joint_limits.lower")
        if np.any(self.rest < self._lower) or np.any(self.rest > self._upper):
            raise ValueError("rest_posture: allowed: within the joint limits")

    @property
    def dim(self) -> int:
        return len(self.joint_names)

    @property
    def lower(self) -> np.ndarray:
        return self._lower.copy()

    @property
    def upper(self) -> np.ndarray:
        return self._upper.copy()

    def command(self, theta) -> np.ndarray:
        """θ → the position command: the joint targets, clipped to the limits."""
        return np.clip(_vec("theta", theta, self.dim), self._lower, self._upper)
