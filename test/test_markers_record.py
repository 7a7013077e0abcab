"""The live view's content (ROS-free part of sagg_bringup.graph.markers) and `sagg record`'s topic set and QoS
choice, without a graph (the graph tests are test_external_driver.py and test_record_check_driver.py)."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from sagg_bringup.graph.markers import (CUBE, DELETEALL, LINE_STRIP, SPHERE_LIST, competence_colour,
                                  interest_colour, to_msg, view_markers)
from sagg_bringup.graph.record import publishers_qos, recorded_topics
from sagg_bringup.bags.recorder import TopicSpec

ROOT = Path(__file__).resolve().parents[1]


def test_view_markers_colour_regions_by_interest_and_goals_by_competence():
    regions = [{"lower": [0, 0], "upper": [5, 10], "interest": 0.0},
               {"lower": [5, 0], "upper": [10, 10], "interest": 0.4}]
    goals = [{"position": [1.0, 2.0], "competence": -1.0}, {"position": [6.0, 7.0], "competence": 0.0},
             {"position": [3.0, 3.0], "competence": None}]
    m = view_markers(regions, goals, np.array([[1.0, 1.0]]), np.array([[0, 0], [1, 1], [2, 1]]), scale=14.1)
    assert m[0]["action"] == DELETEALL
    boxes = [d for d in m if d["ns"] == "regions"]
    assert [d["type"] for d in boxes] == [CUBE, CUBE]
    assert boxes[0]["position"][:2] == [2.5, 5.0] and boxes[0]["scale"][:2] == [5.0, 10.0]
    # lowest interest -> the ramp's start, highest -> its end
    assert boxes[0]["color"][:3] == interest_colour(0.0) and boxes[1]["color"][:3] == interest_colour(1.0)
    g = next(d for d in m if d["ns"] == "goals")
    assert g["type"] == SPHERE_LIST and len(g["points"]) == 3
    assert [c[:3] for c in g["colors"]] == [competence_colour(-1.0), competence_colour(0.0), competence_colour(None)]
    assert (competence_colour(-1.0)[0] > competence_colour(-1.0)[1]
            and competence_colour(0.0)[1] > competence_colour(0.0)[0])
    assert next(d for d in m if d["ns"] == "tip_path")["type"] == LINE_STRIP
    # the message: one Marker per dict, frame world, DELETEALL first
    from builtin_interfaces.msg import Time
    arr = to_msg(m, Time(sec=1))
    assert len(arr.markers) == len(m) and arr.markers[0].action == DELETEALL
    assert all(x.header.frame_id == "world" for x in arr.markers)
    assert len(arr.markers[-1].points) == 3


def test_recorded_topics_follow_the_parameter_file():
    names = {t.name: t for t in recorded_topics()}
    assert names["/joint_states"].msgtype == "sensor_msgs/msg/JointState"
    assert "/forward_position_controller/commands" in names and "/tip_position" in names
    assert names["/sagg/markers"].transient_local and names["/sagg/regions"].transient_local
    quad = {t.name: t.msgtype for t in recorded_topics(ROOT / "config/quadruped.yaml")}
    assert quad["/joint_trajectory_controller/joint_trajectory"] == "trajectory_msgs/msg/JointTrajectory"
    assert quad["/body_pose"] == "geometry_msgs/msg/PoseStamped"


def test_recorder_takes_the_publishers_qos():
    spec = TopicSpec("/x", "std_msgs/msg/String")

    def info(rel, dur):
        return SimpleNamespace(qos_profile=QoSProfile(depth=1, reliability=rel, durability=dur))

    latched = info(ReliabilityPolicy.RELIABLE, DurabilityPolicy.TRANSIENT_LOCAL)
    volatile_be = info(ReliabilityPolicy.BEST_EFFORT, DurabilityPolicy.VOLATILE)
    assert publishers_qos([latched], spec) == TopicSpec("/x", "std_msgs/msg/String", spec.depth, True, False)
    # one volatile, best-effort publisher: a reliable or transient_local reader would not match it
    assert publishers_qos([latched, volatile_be], spec) == TopicSpec("/x", "std_msgs/msg/String", spec.depth,
                                                                     False, True)


def _sample(index):
    return SimpleNamespace(index=index, alpha=[0.1, 0.2], delta_alpha=[0.0, 0.0], delta_y=[0.5, 0.5])


def _diag(node, **published):
    values = [SimpleNamespace(key=f"published {t}", value=str(v)) for t, v in published.items()]
    return SimpleNamespace(status=[SimpleNamespace(name=f"{node}: inputs and safety", hardware_id=node, values=values)])


def test_record_account_acknowledges_from_where_it_joined_and_follows_a_new_learner():
    from sagg_bringup.graph.record_account import RecordAccount
    acc = RecordAccount({"/sagg/sample"})
    assert acc.acknowledged() is None  # no publisher before the first sample: the learner must not wait
    assert all(acc.on_sample(_sample(i)) for i in (7, 8, 9))
    assert acc.acknowledged() == 10
    assert acc.on_sample(_sample(11)) is None and acc.acknowledged() == 10  # a gap: not acknowledged past it
    assert acc.on_sample(_sample(10)) and acc.acknowledged() == 11
    bad = _sample(11)
    bad.delta_y = [float("nan"), 0.0]
    assert acc.on_sample(bad) is None and acc.acknowledged() == 11  # a forged/implausible one takes no index
    # a fresh learner process (index back to 0): its stream is followed from there
    assert acc.on_sample(_sample(0)) and acc.acknowledged() == 1 and acc.processes == 2


def test_record_account_counts_what_the_nodes_announced_and_the_bag_lacks():
    from sagg_bringup.graph.record_account import RecordAccount
    rejected = []
    acc = RecordAccount({"/sagg/sample", "/cmd"}, on_reject=lambda *a: rejected.append(a))
    acc.on_diagnostics(_diag("sagg_learner", **{"/sagg/sample": 120, "/cmd": 130, "/not_recorded": 5}))
    acc.on_diagnostics(_diag("sagg_learner", **{"/sagg/sample": "12x"}))  # not a count: changes nothing
    assert acc.published() == {"/sagg/sample": 120, "/cmd": 130} and len(rejected) == 1
    received = {"/sagg/sample": 100, "/cmd": 125}
    before = acc.before(received, {"/sagg/sample": 11, "/cmd": 1})
    assert before == {"/sagg/sample": 10}
    # 120 announced = 100 in the bag + 10 before the subscription + 10 lost; gaps count at least
    assert acc.losses(received, before, {"/cmd": 7}) == {"/sagg/sample": 10, "/cmd": 7}
    # a restarted node: its earlier process's count is kept
    acc.on_diagnostics(_diag("sagg_learner", **{"/sagg/sample": 20}))
    assert acc.published()["/sagg/sample"] == 140
    # nothing received at all: all of it was published before the recorder subscribed, not lost
    assert acc.before({}, {}) == {"/sagg/sample": 140, "/cmd": 130} and acc.losses({}, {}, {}) == {}
