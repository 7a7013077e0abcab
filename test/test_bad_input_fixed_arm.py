"""The synergy learner node driving the arm in the fixed context (synergy.kind 'posture'): its
PositionLink answers a request only with fresh, settled joint states and tips (a rest command, then
θ), and rejects bad joint states and tips (counted on /diagnostics) without changing its state."""
from __future__ import annotations

import math

import numpy as np
import pytest
import rclpy

from sagg_bringup.graph.params_files import write_params_file
from sagg_bringup.graph.processes import pick_domain_id
from sagg_bringup.graph.setups import SETUPS
from sagg_common.cdr import JointStateEncoder, PointStampedEncoder, decode_f64_array
from sagg_low_level.position_link import PositionLink
from sagg_low_level.fixed_node import SynergyLearnerNode

from sagg_common.cdr import encode_joint_state


@pytest.fixture(scope="module")
def node(tmp_path_factory):
    cfg = SETUPS["arm-fixed"].graph_config("config/arm8.yaml", {"context": "fixed"})
    path = tmp_path_factory.mktemp("fixed_arm") / "params.yaml"
    write_params_file(path, {"sagg_learner": cfg["sagg_learner"]})
    rclpy.init(args=["--ros-args", "--params-file", str(path)], domain_id=pick_domain_id())
    try:
        n = SynergyLearnerNode()
        yield n
        n.destroy_node()
    finally:
        rclpy.try_shutdown()


class Sent:
    """Captures what the link publishes (raw CDR bytes) instead of sending it."""

    def __init__(self):
        self.data = []

    def publish(self, data):
        self.data.append(decode_f64_array(data))


def _link(node):
    answers, fails = [], []
    link = PositionLink(node, node.synergy, answers.append, fails.append)
    link.pub = Sent()
    return link, answers, fails


def test_the_node_uses_the_position_contract(node):
    assert node.link is not None and node.link.topic == "/forward_position_controller/commands"
    assert node.synergy.joint_names == [f"joint_{i}" for i in range(8)]


def test_an_experiment_is_rest_then_theta_answered_by_fresh_settled_states(node):
    link, answers, _ = _link(node)
    js = JointStateEncoder(node.synergy.joint_names, "world")
    tip = PointStampedEncoder("world")
    rest = node.synergy.rest
    link.on_joint_state(js.encode(10, rest, np.zeros(8)))
    link.on_task_point(tip.encode(10, 1.0, 2.0))
    assert link.ready()
    theta = np.clip(rest + 0.3, node.synergy.lower, node.synergy.upper)
    link.execute(theta)
    np.testing.assert_array_equal(link.pub.data[0], rest)
    # a re-publication of the old state (same stamp) and an unsettled one answer nothing
    link.on_joint_state(js.encode(10, rest, np.zeros(8)))
    link.on_task_point(tip.encode(10, 1.0, 2.0))
    link.on_joint_state(js.encode(20, rest, np.full(8, 1.0)))
    link.on_task_point(tip.encode(20, 1.5, 2.5))
    assert len(link.pub.data) == 1 and not answers
    link.on_joint_state(js.encode(21, rest, np.zeros(8)))  # settled: rest reached, θ goes out
    np.testing.assert_array_equal(link.pub.data[1], theta)
    link.on_joint_state(js.encode(30, theta, np.zeros(8)))
    assert not answers  # the tip of θ is still missing
    link.on_task_point(tip.encode(30, 3.0, 4.0))
    assert len(answers) == 1 and answers[0].tolist() == [3.0, 4.0]


@pytest.mark.parametrize("kind, data", [
    ("joint_states.undecodable", b"\x00\x01\x00\x00garbage"),
    ("joint_states.non_finite", encode_joint_state(50, "w", [f"joint_{i}" for i in range(8)],
                                                   [0.0] * 7 + [math.nan], [0.0] * 8)),
    ("joint_states.names", encode_joint_state(50, "w", [f"joint_{i}" for i in range(7)], [0.0] * 7, [0.0] * 7)),
    ("joint_states.out_of_order", encode_joint_state(5, "w", [f"joint_{i}" for i in range(8)], [0.0] * 8, [0.0] * 8)),
    ("joint_states.length", encode_joint_state(50, "w", [f"joint_{i}" for i in range(8)], [0.0] * 7, [])),
])
def test_bad_joint_states_are_rejected_and_change_nothing(node, kind, data):
    link, answers, _ = _link(node)
    js = JointStateEncoder(node.synergy.joint_names, "world")
    link.on_joint_state(js.encode(10, node.synergy.rest, np.zeros(8)))
    link.execute(node.synergy.rest)
    before = (link.alpha.copy(), link.js_stamp, link.js_fresh, node.guard.counts.get(kind, 0), node.guard.total)
    link.on_joint_state(data)
    assert np.array_equal(link.alpha, before[0]) and (link.js_stamp, link.js_fresh) == before[1:3]
    assert node.guard.counts[kind] == before[3] + 1 and node.guard.total == before[4] + 1
    assert not answers


@pytest.mark.parametrize("kind, x, stamp", [("task_point.non_finite", math.nan, 50),
                                            ("task_point.non_finite", math.inf, 50),
                                            ("task_point.out_of_order", 1.0, 5)])
def test_bad_tips_are_rejected_and_change_nothing(node, kind, x, stamp):
    link, answers, _ = _link(node)
    tip = PointStampedEncoder("world")
    link.on_task_point(tip.encode(10, 1.0, 2.0))
    before = (link.tip.copy(), link.tip_stamp, node.guard.counts.get(kind, 0))
    link.on_task_point(tip.encode(stamp, x, 0.0))
    assert np.array_equal(link.tip, before[0]) and link.tip_stamp == before[1]
    assert node.guard.counts[kind] == before[2] + 1
    link.on_task_point(b"\x00\x01")  # undecodable
    assert node.guard.counts["task_point.undecodable"] >= 1 and link.tip_stamp == before[1]
