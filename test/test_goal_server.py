"""The goal generator's ``/sagg/next_goal`` answers a request only once the reports it names are in
(deterministic lockstep), with public rclpy API only (GoalServer: the request waits in a thread of
its own). The generator runs as a real process; the test process sends the reports and requests."""
from __future__ import annotations

import signal
import time

import numpy as np
import yaml

from rclpy.node import Node

from sagg_common.ros_params import reliable
from sagg_goal_generator.core import SCHEMA as CORE_SCHEMA, GoalGenerator
from sagg_msgs.msg import CompetenceReport
from sagg_msgs.srv import NextGoal
from test_nodes_graph import ros_env, start  # noqa: F401 - ros_env is a fixture

GEN = {"seed": 4, "strategy": "sagg-riac", "g_max": 2, "task_space.lower": [-10.0, -10.0],
       "task_space.upper": [10.0, 10.0]}
REPORTS = [(0, [1.0, 2.0], -0.5), (2, [-3.0, 4.0], 0.0), (0, [5.0, -6.0], -0.9)]  # (kind, target, competence)


def spin_until(ex, done, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while not done() and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    return done()


def test_goal_request_waits_for_its_reports(ros_env, tmp_path):  # noqa: F811
    import rclpy.executors

    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {
        "seed": GEN["seed"], "strategy": GEN["strategy"],
        "task_space": {"lower": GEN["task_space.lower"], "upper": GEN["task_space.upper"]}}},
        "sagg_goal_generator": {"ros__parameters": {"g_max": GEN["g_max"]}}}))
    proc = start(ros_env, "goal_generator", params, tmp_path)
    # named as the learner it stands in for: the generator takes reports from the learner only
    node = Node("sagg_learner", context=ros_env["ctx"])
    ex = rclpy.executors.SingleThreadedExecutor(context=ros_env["ctx"])
    ex.add_node(node)
    client = node.create_client(NextGoal, "/sagg/next_goal")
    reports = node.create_publisher(CompetenceReport, "/sagg/competence", reliable(10000, transient_local=True))
    assert spin_until(ex, lambda: client.service_is_ready() and reports.get_subscription_count() >= 1, 90.0), \
        (tmp_path / "goal_generator.log").read_text()

    ask = client.call_async(NextGoal.Request(after_report=len(REPORTS)))
    assert not spin_until(ex, ask.done, 1.5)  # reports 1..3 not sent yet: no answer
    for seq, (kind, target, comp) in enumerate(REPORTS, 1):
        reports.publish(CompetenceReport(seq=seq, kind=kind, target=target, reached=target, start=[0.0, 0.0],
                                         competence=comp))
    assert spin_until(ex, ask.done, 30.0)
    goal = ask.result().goal

    core = {p.name: p.default for p in CORE_SCHEMA} | GEN
    gen = GoalGenerator(core)  # the same reports in-process, then the same draw
    for kind, target, comp in REPORTS:
        gen.report(kind, np.array(target), comp)
    want = gen.next_goal()
    assert len(gen.tree.leaves()) >= 2  # the goal depends on the reports (g_max 2: the tree split)
    assert (goal.seq, goal.after_report, goal.mode) == (want.seq, len(REPORTS), want.mode)
    assert np.array(goal.position).tobytes() == want.position.tobytes()

    again = client.call_async(NextGoal.Request(after_report=len(REPORTS)))  # a repeated request
    assert spin_until(ex, again.done, 30.0)
    assert again.result().goal.seq == goal.seq
    assert np.array(again.result().goal.position).tobytes() == want.position.tobytes()

    client.call_async(NextGoal.Request(after_report=len(REPORTS) + 5))  # waits for reports never sent
    spin_until(ex, lambda: False, 0.5)
    proc.send_signal(signal.SIGINT)  # the waiting request does not keep the node alive
    assert proc.wait(15) == 0, (tmp_path / "goal_generator.log").read_text()
    node.destroy_node()
