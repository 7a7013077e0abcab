"""Moves within the velocity limits, and a stopped arm told from its measured postures (motion.py).

The arm in these tests is a small model of a position-controlled joint servo: each control period
it moves toward its newest setpoint at most its own velocity limit, with a first-order lag; it can
be stopped (a protective stop: commands ignored) and released."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sagg_common.params import ConfigError
from sagg_low_level.motion import (RESUMED, SEND, SETTLE, STOPPED, WAIT, FollowWatch, MoveStream, move_duration,
                                   probe_setpoint, streamed_setpoints, urdf_velocity_limits, velocity_limits)
from sagg_low_level.schema import LEARNER_SCHEMA

from conftest import ROOT

ARM7 = str(ROOT / "config" / "robots" / "arm7.urdf")
PANDA_JOINTS = [f"arm7_joint{i}" for i in range(1, 8)]


class ServoArm:
    """n joints tracking their setpoint at most ``vmax`` rad/s with lag ``tau`` s; ``stopped``:
    setpoints ignored (the arm holds)."""

    def __init__(self, q0, vmax, tau=0.03):
        self.q = np.array(q0, dtype=float)
        self.setpoint = self.q.copy()
        self.vmax, self.tau = np.asarray(vmax, dtype=float), tau
        self.stopped = False

    def command(self, setpoint):
        if not self.stopped:
            self.setpoint = np.array(setpoint, dtype=float)

    def stop(self, stopped: bool):
        """A protective stop (the arm holds where it is, commands ignored) or its release (it holds
        until the next command)."""
        if stopped != self.stopped:
            self.setpoint = self.q.copy()
        self.stopped = stopped

    def step(self, dt):
        if self.stopped:
            return
        v = (self.setpoint - self.q) / max(self.tau, dt)
        v = np.clip(v, -self.vmax, self.vmax)
        self.q = self.q + v * dt


def test_streamed_setpoints_never_exceed_the_scaled_limit():
    rng = np.random.default_rng(3)
    for _ in range(50):
        start, target = rng.uniform(-2, 2, 7), rng.uniform(-2, 2, 7)
        vmax = rng.uniform(0.2, 2.0, 7)
        sp = streamed_setpoints(start, target, vmax, 50.0)
        steps = np.abs(np.diff(np.vstack([start, sp]), axis=0))
        assert (steps <= vmax / 50.0 + 1e-12).all()
        np.testing.assert_array_equal(sp[-1], target)
        # the whole move takes no longer than the limits need, to one period
        assert len(sp) == max(1, math.ceil(move_duration(start, target, vmax) * 50.0 - 1e-9))
        # on the straight line: every setpoint is start + s (target - start)
        frac = (sp - start) / np.where(target != start, target - start, 1.0)
        assert np.allclose(frac, frac[:, :1])


def test_velocity_limits_from_the_urdf_scaled_and_overridden():
    assert np.allclose(urdf_velocity_limits(ARM7, PANDA_JOINTS), 2.175)
    p = {q.name: q.default for q in LEARNER_SCHEMA}
    vmax, source = velocity_limits(p, PANDA_JOINTS, ARM7)
    assert np.allclose(vmax, 2.175 * 0.5) and "arm7.urdf" in source
    p["joint_velocity_limits"] = [1.0] * 7
    p["velocity_scale"] = 0.25
    assert np.allclose(velocity_limits(p, PANDA_JOINTS, ARM7)[0], 0.25)
    # an MJCF gives none: no limits (single setpoints), said by the source
    vmax, source = velocity_limits({**p, "joint_velocity_limits": []}, ["shoulder_pan_joint"],
                                   str(ROOT / "config" / "robots" / "arm6.xml"))
    assert vmax is None and "none known" in source
    with pytest.raises(ConfigError, match="joint_velocity_limits"):
        velocity_limits({**p, "joint_velocity_limits": [1.0, -1.0]}, ["a", "b"], "")
    with pytest.raises(ConfigError, match="joint_velocity_limits"):
        velocity_limits({**p, "joint_velocity_limits": [0.0, 1.0]}, ["a", "b"], "")
    with pytest.raises(ConfigError, match="joint_velocity_limits"):
        velocity_limits({**p, "joint_velocity_limits": [1.0]}, ["a", "b"], "")


def test_probe_setpoint_is_small_and_toward_the_target():
    lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    m = np.array([0.0, 0.5, -0.2])
    p = probe_setpoint(m, np.array([0.3, 0.5, -0.8]), 0.02, lo, hi)
    assert np.abs(p - m).max() == pytest.approx(0.02)
    assert p[0] > m[0] and p[2] < m[2] and p[1] == m[1]
    # on the target: a step along the joint with the most room
    p = probe_setpoint(np.array([0.9, 0.0, -0.9]), np.array([0.9, 0.0, -0.9]), 0.02, lo, hi)
    assert np.abs(p - [0.9, 0.0, -0.9]).max() == pytest.approx(0.02) and p[1] != 0.0


def test_follow_watch_tells_a_stopped_arm_from_a_slow_one():
    w = FollowWatch(0.01, 1.0)
    w.start(np.zeros(2), 0.0)
    # moving slowly (0.012 rad per 0.5 s) toward a far setpoint: following
    for k in range(1, 10):
        assert not w.update(np.array([0.012 * k, 0.0]), np.array([1.0, 0.0]), 0.5 * k)
    # then stopped 0.9 rad short of it: not following after the timeout
    assert not w.update(np.array([0.108, 0.0]), np.array([1.0, 0.0]), 5.3)
    assert w.update(np.array([0.108, 0.0]), np.array([1.0, 0.0]), 5.6)
    # at its setpoint it follows, however long it stays there
    w.start(np.zeros(2), 0.0)
    assert not w.update(np.array([0.995, 0.0]), np.array([1.0, 0.0]), 30.0)


def run_move(stream, arm, dt, t_end, stop_at=None, release_at=None, sent=None):
    """Drive ``stream`` with ``arm`` (ticks at the stream's rate, the arm at ``dt``); returns the
    events (time, what) and the setpoints sent."""
    events, t, next_tick = [], 0.0, 0.0
    sent = [] if sent is None else sent
    while t < t_end:
        if stop_at is not None and stop_at <= t and release_at is not None and t < release_at:
            arm.stop(True)
        elif release_at is not None and t >= release_at:
            arm.stop(False)
        if t >= next_tick:
            next_tick += 1.0 / stream.rate
            what, sp = stream.tick(arm.q.copy(), t)
            if what == SEND:
                sent.append((t, sp.copy(), arm.q.copy()))
                arm.command(sp)
            elif what == RESUMED:  # (the caller ends the move where the arm is)
                events.append((round(t, 3), what))
                return events, sent
            if what != WAIT:
                events.append((round(t, 3), what))
            if stream.phase == stream.SETTLING and np.abs(arm.q - stream.target).max() < 0.01:
                events.append((round(t, 3), "settled"))
                return events, sent
        arm.step(dt)
        t += dt
    return events, sent


def test_a_streamed_move_reaches_the_target_within_the_limits():
    vmax = np.array([1.0, 0.5, 2.0])
    stream = MoveStream(vmax, 50.0, False, 0.5, 0.01, 1.0, 5.0, 0.02, np.full(3, -3.0), np.full(3, 3.0))
    arm = ServoArm([0.0, 0.0, 0.0], vmax * 2)  # the arm could go twice as fast
    stream.begin(arm.q.copy(), np.array([0.4, -0.3, 0.45]), 0.0)
    events, sent = run_move(stream, arm, 0.002, 5.0)
    assert events[-1][1] == "settled" and STOPPED not in [e[1] for e in events]
    pts = np.array([s for _, s, _ in sent])
    assert (np.abs(np.diff(pts, axis=0)) <= vmax / 50.0 + 1e-12).all()
    # the move took about its time at the limits (0.6 s for joint 1), not a jump
    assert 0.55 < events[-1][0] < 1.2


def test_a_stopped_arm_is_held_then_probed_back_and_the_move_ends_where_it_is():
    vmax = np.array([1.0, 1.0])
    stream = MoveStream(vmax, 50.0, False, 0.5, 0.01, 1.0, 2.0, 0.02, np.full(2, -3.0), np.full(2, 3.0))
    arm = ServoArm([0.0, 0.0], vmax)
    stream.begin(arm.q.copy(), np.array([0.5, 0.5]), 0.0)
    sent = []
    # a protective stop at 0.2 s, released at 6 s
    events, sent = run_move(stream, arm, 0.002, 20.0, stop_at=0.2, release_at=6.0, sent=sent)
    kinds = [e[1] for e in events]
    assert kinds.count(STOPPED) == 1
    t_stop = events[kinds.index(STOPPED)][0]
    assert 1.1 < t_stop < 1.4  # follow_timeout after the arm stopped
    # while stopped: nothing but probes, the first one follow_retry after the stop, each small and
    # back toward where the move began (away from what stopped it)
    probes = [(t, sp, q) for t, sp, q in sent if t >= t_stop]
    assert probes and probes[0][0] >= t_stop + 2.0 - 1e-9
    assert all(np.abs(sp - q).max() == pytest.approx(0.02) and (sp < q).all() for _, sp, q in probes)
    # released: a probe moved the arm, it follows again; the move ends there (the caller answers)
    assert kinds[-1] == RESUMED and events[-1][0] >= 6.0 and stream.probes >= 2


def test_a_trajectory_move_waits_its_time_then_settles():
    vmax = np.array([0.5])
    stream = MoveStream(vmax, 50.0, True, 0.5, 0.01, 1.0, 5.0, 0.02, np.array([-3.0]), np.array([3.0]))
    assert stream.begin(np.array([0.0]), np.array([0.25]), 0.0) == pytest.approx(0.5)
    assert stream.tick(np.array([0.1]), 0.2) == (WAIT, None)
    assert stream.tick(np.array([0.25]), 0.52)[0] == SETTLE
