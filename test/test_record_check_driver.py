"""`sagg record` (the recorder alone, for graphs not started by `sagg run`) and `sagg check-driver`,
both against test/fake_driver.py (a numpy arm at 250 Hz, not MuJoCo, joints named axis_* in
reversed order)."""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import yaml

import rclpy.executors
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sagg_msgs.msg import CompetenceReport, LearnerStatus
from std_srvs.srv import SetBool

import test_nodes_graph
from test_nodes_graph import STARTUP_TIMEOUT, logs, start
from test_run_graph import read_bag
from installed import SAGG

ros_env = test_nodes_graph.ros_env  # the fixture: a private ROS domain per test

HERE = Path(__file__).resolve().parent
LENGTHS, REST = [20.0, 15.0, 10.0], [0.3, 0.3, 0.3]
RATE, LATENCY = 250.0, 0.008


def arm_config(path: Path, joints=("axis_0", "axis_1", "axis_2"), steps: int = 0) -> Path:
    lim = float(np.pi / 2)
    path.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"seed": 3, "task_space": {"lower": [-20.0, -50.0], "upper": [50.0, 50.0]}}},
        "sagg_goal_generator": {"ros__parameters": {"g_max": 20}},
        "sagg_learner": {"ros__parameters": {
            "joints": list(joints), "joint_limits": {"lower": [-lim] * 3, "upper": [lim] * 3}, "rest_posture": REST,
            "observation_delay": LATENCY + 2.0 / RATE, "max_micro_actions": steps, "q": 10}}}))
    return path


def start_driver(ros_env, tmp_path: Path, noise: float = 1e-4) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, str(HERE / "fake_driver.py"), "--dof", "3", "--lengths", *map(str, LENGTHS),
                          "--rest", *map(str, REST), "--rate", str(RATE), "--latency", str(LATENCY),
                          "--noise", str(noise), "--seed", "1"],
                         env=ros_env["env"], stdout=open(tmp_path / "fake_driver.log", "w"), stderr=subprocess.STDOUT)
    ros_env["procs"].append(p)
    return p


def test_sagg_record_alone_records_a_late_joined_graph_and_stops_cleanly(ros_env, tmp_path):
    steps = 120
    params = arm_config(tmp_path / "arm.yaml", steps=steps)
    procs = [start_driver(ros_env, tmp_path)] + [start(ros_env, s, params, tmp_path)
                                                 for s in ("goal_generator", "learner")]
    node = Node("sagg_test_watch", context=ros_env["ctx"])
    status: list[LearnerStatus] = []
    reports: list[CompetenceReport] = []
    node.create_subscription(LearnerStatus, "/sagg/status", status.append, 10)
    node.create_subscription(CompetenceReport, "/sagg/competence", reports.append, QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=10000, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    ex = rclpy.executors.SingleThreadedExecutor(context=ros_env["ctx"])
    ex.add_node(node)

    def spin_until(cond, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not cond():
            for p in procs:
                assert p.poll() is None, logs(tmp_path)
            ex.spin_once(timeout_sec=0.05)
        return cond()

    # the recorder joins late: learning has started
    assert spin_until(lambda: status and status[-1].micro_actions >= 20, STARTUP_TIMEOUT), logs(tmp_path)
    # learning is paused while the recorder starts (on a loaded machine the learner could otherwise
    # finish its budget first): then the recorder has joined late, and samples still come after it
    pause = node.create_client(SetBool, "/sagg/pause")

    def set_pause(on: bool) -> None:
        assert pause.wait_for_service(timeout_sec=30.0)
        fut = pause.call_async(SetBool.Request(data=on))
        assert spin_until(fut.done, 30.0) and fut.result().success

    set_pause(True)
    bag = tmp_path / "bag"
    rec = subprocess.Popen([SAGG, "record", "--out", str(bag), "--params", str(params)], env=ros_env["env"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ros_env["procs"].append(rec)
    assert spin_until(lambda: node.count_subscribers("/sagg/sample") >= 1, 60.0), "the recorder never subscribed"
    set_pause(False)
    assert spin_until(lambda: status and status[-1].micro_actions >= steps
                              and "max_micro_actions" in status[-1].pause_reason,
                      120), logs(tmp_path)
    spin_until(lambda: False, 2.0)  # the recorder takes the last messages
    rec.send_signal(signal.SIGINT)
    out, err = rec.communicate(timeout=30)
    assert rec.returncode == 0, err[-2000:]
    assert "bag closed" in err
    types, msgs = read_bag(bag)
    # the same topic set as `sagg run`, subscribed as their publishers appeared
    assert types["/joint_states"] == "sensor_msgs/msg/JointState"
    assert types["/forward_position_controller/commands"] == "std_msgs/msg/Float64MultiArray"
    assert {"/sagg/competence", "/sagg/regions", "/sagg/sample", "/sagg/status", "/tip_position",
            "/sagg/markers"} <= set(types)
    # transient_local publishers: the reports from before the recorder joined are in the bag too
    assert len(msgs["/sagg/competence"]) == len(reports) and msgs["/sagg/competence"][0].seq == 1
    assert len(msgs["/sagg/regions"]) >= 1 and len(msgs["/sagg/markers"]) >= 1
    assert 0 < len(msgs["/sagg/sample"]) < steps  # volatile: only what came after it joined
    assert [s.index for s in msgs["/sagg/sample"]] == list(range(msgs["/sagg/sample"][0].index, steps))
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    qos = {t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
           for t in meta["topics_with_message_count"]}
    assert qos["/sagg/regions"][0]["durability"] == "transient_local"  # the publisher's
    assert qos["/sagg/competence"][0]["durability"] == "transient_local"
    # the publishers' offered QoS as `ros2 bag record` writes them (a reader learns no history or
    # depth: unknown / 0), not the recorder's own subscription (keep_last, its depth)
    assert (qos["/sagg/competence"][0]["history"], qos["/sagg/competence"][0]["depth"]) == ("unknown", 0)
    assert (qos["/joint_states"][0]["durability"], qos["/joint_states"][0]["reliability"]) == ("volatile", "reliable")
    ex.shutdown()
    node.destroy_node()


def check(ros_env, config: Path, *extra) -> subprocess.CompletedProcess:
    return subprocess.run([SAGG, "check-driver", str(config), "--seconds", "1", *extra], env=ros_env["env"],
                          capture_output=True, text=True, timeout=90)


def test_check_driver_reports_rates_delays_mapping_and_noise(ros_env, tmp_path):
    start_driver(ros_env, tmp_path, noise=1e-3)
    res = check(ros_env, arm_config(tmp_path / "arm.yaml"))
    assert res.returncode == 0, res.stdout + res.stderr
    out = res.stdout
    assert "contract met" in out and "OK: the driver meets the contract" in out
    # 250 Hz with 8 ms latency; names in reversed order on the wire
    rate = float(out.split("joint states ")[1].split("/s")[0])
    assert 150 < rate < 300, out
    assert "axis_0 -> 2, axis_1 -> 1, axis_2 -> 0" in out
    delay_ms = float(out.split("(same clock): joint states ")[1].split(" ms")[0])
    assert 5 < delay_ms < 100, out
    assert "noise at rest" in out and "moved axis_2 by +0.050 rad" in out
    assert "suggested: observation_delay" in out


def test_check_driver_names_a_wrong_joint_order_and_a_missing_driver(ros_env, tmp_path):
    # no driver yet: the contract items are named
    res = check(ros_env, arm_config(tmp_path / "arm.yaml"), "--timeout", "2")
    assert res.returncode == 1 and "/joint_states (sensor_msgs/msg/JointState): no publisher" in res.stdout
    start_driver(ros_env, tmp_path)
    # 'joints' in the wrong order: command slot 0 moves the driver's axis_0, not axis_1
    res = check(ros_env, arm_config(tmp_path / "bad.yaml", joints=("axis_1", "axis_0", "axis_2")), "--joint", "axis_1")
    assert res.returncode == 1, res.stdout + res.stderr
    assert "commanding axis_1 also moved axis_0" in res.stdout


def test_sagg_record_beside_hand_started_nodes_keeps_every_message_at_ctrl_c(ros_env, tmp_path):
    """The three executables on a run's params.yaml with `sagg record --params`
    beside them, under load; SIGINT to every process at the same moment (as a terminal's Ctrl-C or
    ros2 launch does). The recorder acknowledges (the learner waits while it lags), then takes what
    the nodes still publish before it closes: every sample and report the learner published is in
    the bag, or the recorder's exit code (3) and its metadata name what is not."""
    import json
    import re
    from test_params_everywhere import run_params_file
    params = run_params_file(tmp_path, 0)
    hogs = [subprocess.Popen(["nice", "-n", "19", sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        bag = tmp_path / "bag"
        rec = subprocess.Popen([SAGG, "record", "--out", str(bag), "--params", str(params)], env=ros_env["env"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        ros_env["procs"].append(rec)
        node = Node("sagg_test_watch", context=ros_env["ctx"])
        status: list[LearnerStatus] = []
        node.create_subscription(LearnerStatus, "/sagg/status", status.append, 10)
        ex = rclpy.executors.SingleThreadedExecutor(context=ros_env["ctx"])
        ex.add_node(node)
        end = time.monotonic() + 60
        while time.monotonic() < end and "sagg_record" not in node.get_node_names():  # the recorder is up
            ex.spin_once(timeout_sec=0.05)
        # the nodes wait for the recorder's subscriptions, as with record:=true (a learner publishes
        # no sample while nobody subscribes: a recorder that subscribes later misses the first ones)
        waits = {"learner": ("-p", "min_sample_subscribers:=1"), "goal_generator": ("-p", "min_goal_subscribers:=1")}
        procs = [start(ros_env, s, params, tmp_path, waits.get(s, ()))
                 for s in ("mujoco_bridge", "goal_generator", "learner")]
        end = time.monotonic() + STARTUP_TIMEOUT + 60
        while time.monotonic() < end and not (status and status[-1].micro_actions >= 600):
            for p in procs + [rec]:
                assert p.poll() is None, logs(tmp_path)
            ex.spin_once(timeout_sec=0.05)
        assert status and status[-1].micro_actions >= 600, logs(tmp_path)
        for p in procs + [rec]:
            p.send_signal(signal.SIGINT)
        for p in procs:
            assert p.wait(30) == 0, logs(tmp_path)
        out, err = rec.communicate(timeout=60)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    published = json.loads(re.search(r"\[sagg_learner\]: published counts: (\{.*\})",
                                     (tmp_path / "learner.log").read_text()).group(1))
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
    custom = meta["custom_data"]
    lost, before = json.loads(custom["sagg.lost"]), json.loads(custom["sagg.published_before_subscribed"])
    assert custom["sagg.recorder"] == "sagg record" and "ended" in json.loads(custom["sagg.drain"])
    assert not before.get("/sagg/sample") and not before.get("/sagg/competence")
    assert json.loads(custom["sagg.first_sample_index"]) == 0  # the learner's first sample on
    for topic in ("/sagg/sample", "/sagg/competence"):
        # every message accounted for: in the bag, published before the recorder subscribed, or lost
        assert counts[topic] + before.get(topic, 0) + lost.get(topic, 0) == published[topic] > 0, (topic, err[-3000:])
    assert rec.returncode == (3 if lost else 0), err[-3000:]
    if lost:
        assert "LOST" in err
    assert "bag closed" in err
    ex.shutdown()
    node.destroy_node()
