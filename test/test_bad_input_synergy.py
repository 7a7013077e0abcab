"""Fuzz tests of the synergy nodes' subscription callbacks (fishing-rod setup): the bridge's
trajectory callback and the learner's outcome callback never raise; malformed trajectories are
rejected, counted (/diagnostics) and answered with the "no outcome" value, running nothing."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import rclpy
import yaml
from builtin_interfaces.msg import Duration
from hypothesis import HealthCheck, given, settings, strategies as st

from geometry_msgs.msg import PointStamped
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from sagg_bringup.graph.processes import pick_domain_id
from sagg_low_level.fixed_node import SynergyLearnerNode
from sagg_sim_bridge.synergy_node import SynergyBridgeNode

ROOT = Path(__file__).resolve().parents[1]
JOINTS = ["base_yaw", "shoulder", "elbow", "wrist"]
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@pytest.fixture(scope="module")
def nodes():
    path = ROOT / "config" / "fishing.yaml"
    assert yaml.safe_load(path.read_text())["/**"]["ros__parameters"]["setup"] == "fishing"
    rclpy.init(args=["--ros-args", "--params-file", str(path)], domain_id=pick_domain_id())
    try:
        built = {"learner": SynergyLearnerNode(), "bridge": SynergyBridgeNode()}
        yield built
        for n in built.values():
            n.destroy_node()
    finally:
        rclpy.try_shutdown()


@FUZZ
@given(names=st.lists(st.sampled_from(JOINTS + ["other"]), max_size=5),
       points=st.lists(st.tuples(st.integers(-2, 3), st.lists(floats, max_size=5), st.lists(floats, max_size=5)),
                       min_size=1, max_size=4))
def test_bad_trajectories_are_rejected_and_counted(nodes, names, points):
    b = nodes["bridge"]
    msg = JointTrajectory()
    msg.joint_names = names
    for sec, pos, vel in points:
        p = JointTrajectoryPoint()
        p.time_from_start = Duration(sec=max(sec, 0), nanosec=0)
        p.positions, p.velocities = pos, vel
        msg.points.append(p)
    secs = [max(s, 0) for s, _, _ in points]
    valid = (sorted(set(names)) == sorted(JOINTS) and len(names) == 4 and secs == sorted(set(secs))
             and all(len(v) == 4 and all(math.isfinite(x) for x in v) for _, _, v in points)
             and all(len(p) in (0, 4) and all(math.isfinite(x) for x in p) for _, p, _ in points))
    if valid:
        return  # a real experiment (seconds of physics): covered by test_synergy_*
    before, total = b.experiments, b.guard.total
    b.on_trajectory(msg)  # must not raise
    assert b.experiments == before and b.guard.total == total + 1


@FUZZ
@given(sec=st.integers(0, 2**31 - 1), nanosec=st.integers(0, 10**9 - 1), x=floats, y=floats)
def test_outcomes_never_crash_the_learner(nodes, sec, nanosec, x, y):
    n = nodes["learner"]
    msg = PointStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.point.x, msg.point.y = x, y
    before = (n.learner.experiments, n.waiting_stamp, n.trial_counter)
    n.on_outcome(msg)  # nothing in flight: ignored
    assert (n.learner.experiments, n.waiting_stamp, n.trial_counter) == before
