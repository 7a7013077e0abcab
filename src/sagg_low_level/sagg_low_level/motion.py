"""How a move reaches a real arm (ROS-free): within its velocity limits, watched for following.

A micro-action (or a step of the return to rest, or of a reach) is one *move*: from the measured
posture to the commanded one along the straight joint-space line. A forward position controller
does not interpolate (a setpoint far from the posture is a jump at the servo's full speed), so a
move goes out as *setpoints streamed* at ``command_rate`` Hz, each one at most the scaled velocity
limit / ``command_rate`` from the previous one (:func:`streamed_setpoints`), or, with
``command_interface: trajectory``, as one ``trajectory_msgs/JointTrajectory`` whose time is set by
the same limits (:func:`move_duration`). The learner still learns from the settled end point: a
move stays one micro-action.

The limits: URDF ``<limit velocity>`` of the learner's joints (:func:`urdf_velocity_limits`), or
the parameter ``joint_velocity_limits`` (MJCF and tracker set-ups, or to override; empty, the
default: from the model), scaled by
``velocity_scale``. Without any (no URDF value, no parameter) a move is one setpoint, as for the
simulator, and the learner says so once at start.

The arm may stop following (a protective stop, an e-stop, a driver that ignores commands):
:class:`FollowWatch` tells it from the measured postures, and the learner then holds instead of
streaming on (:mod:`.holds`, ``follow``), probing now and then with one small setpoint
(:func:`probe_setpoint`).
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from typing import Sequence

import numpy as np

from sagg_common.params import ConfigError


def urdf_velocity_limits(path: str, joints: Sequence[str]) -> np.ndarray | None:
    """The ``<limit velocity>`` of ``joints`` in a URDF file (rad/s or m/s).

    Parameters
    ----------
    path : str
        The model file; not a ``.urdf``: None (MJCF has no velocity limit).
    joints : sequence of str
        The learner's joint names, in its command order; n = their number.

    Returns
    -------
    ndarray, shape (n,) or None
        The limits; NaN for a joint without one. None when the file is no URDF or no joint has one.
    """
    if not path.lower().endswith(".urdf") or not os.path.isfile(path):
        return None
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ConfigError(f"parameter 'task_model.file': {path!r} is no readable URDF ({exc})") from exc
    found = {}
    for joint in root.iter("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("velocity") is not None:
            try:
                found[joint.get("name")] = float(limit.get("velocity"))
            except ValueError:
                continue
    out = np.array([found.get(j, math.nan) for j in joints], dtype=float)
    return None if np.isnan(out).all() else out


def velocity_limits(p: dict, joints: Sequence[str], model_path: str) -> tuple[np.ndarray | None, str]:
    """The scaled velocity limits of the learner's joints and where they come from.

    Parameters
    ----------
    p : dict
        The learner's parameters: ``joint_velocity_limits`` (empty = from the model),
        ``velocity_scale``.
    joints : sequence of str
        The learner's joints; n = their number.
    model_path : str
        The robot's model file (absolute; '' = none).

    Returns
    -------
    (ndarray, shape (n,), or None; str)
        The limits times ``velocity_scale`` (None: none known, moves are single setpoints), and
        their source in words.
    """
    given = list(p["joint_velocity_limits"])
    if given:  # (empty, the default: from the model)
        if len(given) != len(joints) or not all(math.isfinite(v) and v > 0 for v in given):
            raise ConfigError(f"parameter 'joint_velocity_limits': got {given}; allowed: {len(joints)} positive "
                              f"values (rad/s), one per joint {list(joints)}")
        raw, source = np.array(given, dtype=float), "joint_velocity_limits"
    else:
        raw = urdf_velocity_limits(model_path, joints) if model_path else None
        if raw is None:
            return None, "none known (no URDF <limit velocity>, joint_velocity_limits empty)"
        missing = [j for j, v in zip(joints, raw) if not (math.isfinite(v) and v > 0)]
        if missing:
            raise ConfigError(f"parameter 'joint_velocity_limits': the URDF {model_path} gives no positive velocity "
                              f"limit for {missing}; allowed: give all {len(joints)} (rad/s)")
        source = f"<limit velocity> of {os.path.basename(model_path)}"
    return raw * float(p["velocity_scale"]), f"{source} x velocity_scale {p['velocity_scale']:g}"


def move_duration(start: np.ndarray, target: np.ndarray, vmax: np.ndarray) -> float:
    """The time of the straight joint-space move from ``start`` to ``target`` when no joint moves
    faster than its limit: max_j |Δα_j| / v_j (every joint arrives together).

    Parameters
    ----------
    start, target : ndarray, shape (n,)
        Postures (rad).
    vmax : ndarray, shape (n,)
        Positive velocity limits (rad/s), already scaled.

    Returns
    -------
    float
        Seconds, >= 0.
    """
    return float(np.max(np.abs(target - start) / vmax)) if len(start) else 0.0


def streamed_setpoints(start: np.ndarray, target: np.ndarray, vmax: np.ndarray, rate: float) -> np.ndarray:
    """The setpoints of one move streamed at ``rate`` Hz along the straight joint-space line: k of
    them, equally spaced, the last one ``target``, with k = ceil(:func:`move_duration` x rate)
    (at least 1), so no setpoint changes any joint faster than its limit.

    Parameters
    ----------
    start, target : ndarray, shape (n,)
        The measured posture and the commanded one (rad).
    vmax : ndarray, shape (n,)
        Positive velocity limits (rad/s), already scaled.
    rate : float
        Setpoints per second (``command_rate``), > 0.

    Returns
    -------
    ndarray, shape (k, n)
        Setpoint i (1-based) = start + (target - start) i / k.
    """
    k = max(1, math.ceil(move_duration(start, target, vmax) * rate - 1e-9))
    frac = np.arange(1, k + 1, dtype=float)[:, None] / k
    out = start[None, :] + (target - start)[None, :] * frac
    out[-1] = target
    return out


def probe_setpoint(measured: np.ndarray, toward: np.ndarray, probe_step: float, lower: np.ndarray,
                   upper: np.ndarray) -> np.ndarray:
    """One small setpoint that tells whether a stopped arm follows again: ``probe_step`` rad (in
    the joint that moves most; the direction kept) from the measured posture toward ``toward`` (the
    stopped move's start, where the arm came from; or its target when it stopped at the start),
    within the joint limits: on the move's checked segment when the arm stopped on it, and away
    from whatever stopped it.

    Parameters
    ----------
    measured, toward : ndarray, shape (n,)
        The measured posture; where the probe heads (rad).
    probe_step : float
        Largest joint motion of the probe (rad), > 0.
    lower, upper : ndarray, shape (n,)
        Joint limits.

    Returns
    -------
    ndarray, shape (n,)
        The probe setpoint. When the target is closer than ``probe_step`` it is the target; when
        the arm is on it, ``probe_step`` along the joint with the most room, away from its nearer limit.
    """
    step = toward - measured
    big = float(np.abs(step).max()) if step.size else 0.0
    if big < 1e-6:
        room = np.minimum(measured - lower, upper - measured)
        j = int(np.argmax(room))
        step = np.zeros_like(measured)
        step[j] = probe_step if upper[j] - measured[j] >= measured[j] - lower[j] else -probe_step
    elif big > probe_step:
        step = step * (probe_step / big)
    return np.minimum(np.maximum(measured + step, lower), upper)


class FollowWatch:
    """Whether the measured posture follows the setpoints of a move.

    Progress is either a measured motion of at least ``tolerance`` (any joint) since the last
    progress, or the posture within ``tolerance`` of the current setpoint. With no progress for
    ``timeout`` s while the arm is farther than ``tolerance`` from its setpoint, the arm does not
    follow (:meth:`update` says so): a protective stop, an e-stop, a driver that ignores commands.

    Parameters
    ----------
    tolerance : float
        ``settle_tolerance`` (rad).
    timeout : float
        ``follow_timeout`` (s).
    """

    def __init__(self, tolerance: float, timeout: float):
        self.tolerance, self.timeout = float(tolerance), float(timeout)
        self.ref: np.ndarray | None = None
        self.t_ref = 0.0

    def start(self, measured: np.ndarray, now: float) -> None:
        """A move (or a probe) begins at ``measured``."""
        self.ref, self.t_ref = np.array(measured, dtype=float), now

    def update(self, measured: np.ndarray, setpoint: np.ndarray, now: float) -> bool:
        """A new measured posture while ``setpoint`` is the newest one sent; True when the arm has
        not followed for ``timeout`` s."""
        if self.ref is None:
            self.start(measured, now)
            return False
        tol = self.tolerance
        if float(np.abs(measured - self.ref).max()) >= tol or float(np.abs(setpoint - measured).max()) <= tol:
            self.ref, self.t_ref = np.array(measured, dtype=float), now
            return False
        return now - self.t_ref > self.timeout

    def lag(self, measured: np.ndarray, setpoint: np.ndarray) -> tuple[int, float]:
        """(joint index, rad): the joint farthest from ``setpoint`` and how far."""
        d = np.abs(setpoint - measured)
        j = int(np.argmax(d))
        return j, float(d[j])


# what MoveStream.tick asks of its caller
SEND, WAIT, SETTLE, STOPPED, RESUMED = "send", "wait", "settle", "stopped", "resumed"


class MoveStream:
    """One move at a time, from the measured posture to a target, as a real arm gets it.

    ==========  =======================================================  ==============================
    phase       what happens at each :meth:`tick` (``command_rate`` Hz)  next
    ==========  =======================================================  ==============================
    streaming   the next setpoint (:func:`streamed_setpoints`), once it  settling after the last one;
                lies within ``max_step`` of the measured posture; with   stopped when the arm does not
                a trajectory: the expected point of the line at this     follow (:class:`FollowWatch`)
                time
    settling    nothing: the caller waits for a settled observation     (the caller answers the move)
    stopped     nothing for ``follow_retry`` s, then one probe           probing
                (:func:`probe_setpoint`) back toward the move's start
    probing     watch the probe for ``follow_timeout`` s                 the move ends where the arm
                                                                         is (the arm followed: the
                                                                         caller answers it), else
                                                                         stopped
    ==========  =======================================================  ==============================

    Parameters
    ----------
    vmax : ndarray, shape (n,)
        Scaled velocity limits (rad/s).
    rate : float
        ``command_rate`` (Hz).
    trajectory : bool
        ``command_interface`` 'trajectory': the whole line goes out at once (:meth:`begin` returns
        its duration), the ticks only watch.
    max_step : float
        ``max_joint_step``: no setpoint further than this from the measured posture.
    tolerance, follow_timeout, follow_retry, probe_step : float
        The parameters of the same names.
    lower, upper : ndarray, shape (n,)
        Joint limits.
    """

    STREAMING, SETTLING, STOPPED, PROBING = "streaming", "settling", "stopped", "probing"

    def __init__(self, vmax: np.ndarray, rate: float, trajectory: bool, max_step: float, tolerance: float,
                 follow_timeout: float, follow_retry: float, probe_step: float, lower: np.ndarray,
                 upper: np.ndarray):
        self.vmax, self.rate, self.trajectory = np.asarray(vmax, dtype=float), float(rate), bool(trajectory)
        self.max_step, self.retry, self.probe_step = float(max_step), float(follow_retry), float(probe_step)
        self.lower, self.upper = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
        self.watch = FollowWatch(tolerance, follow_timeout)
        self.phase: str | None = None
        self.start = self.target = self.setpoints = self.sent = self.probe_from = None
        self.index = 0
        self.t0 = self.duration = self.t_phase = 0.0
        self.stops = 0      # the times the arm was found not following
        self.probes = 0     # probe setpoints sent

    @property
    def busy(self) -> bool:
        """A move is streaming, stopped or probing (not yet settling or done)."""
        return self.phase in (self.STREAMING, self.STOPPED, self.PROBING)

    def begin(self, measured: np.ndarray, target: np.ndarray, now: float) -> float:
        """A new move from ``measured`` to ``target``; returns its duration at the limits (s)."""
        start = np.array(measured, dtype=float)
        self.target = np.array(target, dtype=float)
        self.duration = move_duration(start, self.target, self.vmax)
        self.setpoints = None if self.trajectory else streamed_setpoints(start, self.target, self.vmax, self.rate)
        self.start, self.index, self.t0, self.sent = start, 0, now, start
        self.phase = self.STREAMING
        self.watch.start(start, now)
        return self.duration

    def tick(self, measured: np.ndarray, now: float) -> tuple[str, np.ndarray | None]:
        """One step of the table above for the newest ``measured`` posture at time ``now``.

        Returns
        -------
        (str, ndarray or None)
            ``(SEND, setpoint)``: publish it; ``(SETTLE, None)``: the last setpoint is out, wait for
            a settled observation (said once); ``(STOPPED, None)``: the arm was just found not
            following (said once); ``(RESUMED, None)``: a probe moved the arm: it follows again,
            and the move ends where the arm is (the caller answers it: the same move again would
            meet what stopped it); ``(WAIT, None)``: nothing to do now.
        """
        phase = self.phase
        if phase == self.STREAMING:
            return self._stream(measured, now)
        if phase == self.SETTLING:
            if self.watch.update(measured, self.sent, now):
                return self._stop(now)
            return WAIT, None
        if phase == self.STOPPED:
            if now - self.t_phase < self.retry:
                return WAIT, None
            # back toward where the move started (the arm was there: the way the safety
            # controller let it come), or toward the target when it stopped at the start
            back = float(np.abs(self.start - measured).max()) >= 0.5 * self.probe_step
            probe = probe_setpoint(measured, self.start if back else self.target, self.probe_step, self.lower,
                                   self.upper)
            self.probe_from, self.sent = np.array(measured, dtype=float), probe
            self.phase, self.t_phase = self.PROBING, now
            self.probes += 1
            return SEND, probe
        if phase == self.PROBING:
            wanted = float(np.abs(self.sent - self.probe_from).max())
            if float(np.abs(measured - self.probe_from).max()) >= 0.5 * wanted:
                return RESUMED, None
            if now - self.t_phase > self.watch.timeout:
                self.phase, self.t_phase = self.STOPPED, now
            return WAIT, None
        return WAIT, None

    def _stream(self, measured: np.ndarray, now: float) -> tuple[str, np.ndarray | None]:
        if self.watch.update(measured, self.sent, now):
            return self._stop(now)
        if self.trajectory:
            self.sent = self._expected(now)
            if now - self.t0 >= self.duration:
                self.phase = self.SETTLING
                return SETTLE, None
            return WAIT, None
        nxt = self.setpoints[self.index]
        if float(np.abs(nxt - measured).max()) > self.max_step:
            return WAIT, None  # (the arm lags: the next setpoint waits until it is within a step)
        self.index += 1
        self.sent = nxt
        if self.index == len(self.setpoints):
            self.phase = self.SETTLING
        return SEND, nxt

    def _expected(self, now: float) -> np.ndarray:
        """Where a trajectory's line is at ``now``."""
        frac = 1.0 if self.duration <= 0 else min(1.0, (now - self.t0) / self.duration)
        return self.start + (self.target - self.start) * frac

    def _stop(self, now: float) -> tuple[str, None]:
        self.phase, self.t_phase = self.STOPPED, now
        self.stops += 1
        return STOPPED, None

    def done(self) -> None:
        """The move was answered (or abandoned): no move in flight."""
        self.phase = None
