"""The live view's content (ROS-free part of sagg_bringup.markers) and `sagg record`'s topic set and QoS
choice, without a graph (the graph tests are test_external_driver.py and test_record_check_driver.py)."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from sagg_bringup.markers import (CUBE, DELETEALL, LINE_STRIP, SPHERE_LIST, competence_colour,
                                  interest_colour, to_msg, view_markers)
from sagg_bringup.record import publishers_qos, recorded_topics
from sagg_bringup.recorder import TopicSpec

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
    assert competence_colour(-1.0)[0] > competence_colour(-1.0)[1] and competence_colour(0.0)[1] > competence_colour(0.0)[0]
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
