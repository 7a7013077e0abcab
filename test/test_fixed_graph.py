"""The synergy graph (goal_generator + fixed_learner + synergy_bridge as processes, private
ROS_DOMAIN_ID, SIGKILL fallback in stop_processes) equals the in-process run, and its bag holds the
trajectories and outcomes."""
from __future__ import annotations

import numpy as np

from sagg_bringup.graph.setups import load_experiment_config, run_experiment, run_graph
from sagg_bringup.bags.recorder import make_typestore
from sagg_bringup.graph.run_file import read_run_file
from sagg_low_level.fixed_context import synergy_from_params

OVERRIDES = {"eval.pool": 20, "eval.goals": 5, "synergy.duration": 1.0}


def test_quadruped_graph_equals_in_process_and_records_trajectories(tmp_path):
    n = 16
    graph = run_graph("config/quadruped.yaml", n, tmp_path / "graph", eval_every=8, overrides=OVERRIDES,
                              progress=False, stall_timeout=120.0, report=False)
    inproc = run_experiment("config/quadruped.yaml", None, None, n, 8, tmp_path / "inproc", progress=False,
                            overrides=OVERRIDES)
    # bit-identical samples (θ and outcomes), goals and test errors
    assert graph["memory"]["samples"] == inproc["memory"]["samples"] == n
    assert graph["memory"]["digest"] == inproc["memory"]["digest"]
    assert graph["curve"] == inproc["curve"]
    assert [g["position"] for g in graph["goals"]] == [g["position"] for g in inproc["goals"]]
    # the run's own settings, written before its nodes started (what a resume would read)
    settings = read_run_file(tmp_path / "graph")
    assert (settings["setup"], settings["driver"], settings["micro_actions"], settings["eval_every"]) == \
        ("quadruped", "sim", n, 8)
    assert settings["domain_id"] == graph["domain_id"] and settings["overrides"] == OVERRIDES

    topics = graph["bag"]["topics"]
    traj_topic = "/joint_trajectory_controller/joint_trajectory"
    assert topics[traj_topic]["type"] == "trajectory_msgs/msg/JointTrajectory"
    assert topics["/body_pose"]["type"] == "geometry_msgs/msg/PoseStamped"
    assert topics["/sagg/sample"]["count"] == n

    # the first recorded synergy is the trajectory of the first stored θ
    from rosbags.highlevel import AnyReader
    store = make_typestore()
    cfg = load_experiment_config("config/quadruped.yaml", OVERRIDES)
    syn = synergy_from_params(cfg["sagg_learner"])
    with AnyReader([tmp_path / "graph" / "bag"], default_typestore=store) as reader:
        conns = {c.topic: c for c in reader.connections}
        trajs = [reader.deserialize(raw, c.msgtype)
                 for c, _, raw in reader.messages(connections=[conns[traj_topic]])]
        samples = [reader.deserialize(raw, c.msgtype)
                   for c, _, raw in reader.messages(connections=[conns["/sagg/sample"]])]
        outcomes = [reader.deserialize(raw, c.msgtype)
                    for c, _, raw in reader.messages(connections=[conns["/body_pose"]])]

    def stamp(m) -> int:
        return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec

    # every trajectory (the n synergies + the empty rest-outcome query, which the learner may send
    # again while unanswered) and its outcome, matched by the echoed stamp
    assert len({stamp(t) for t in trajs}) == n + 1
    assert {stamp(o) for o in outcomes} == {stamp(t) for t in trajs}
    assert len(trajs[0].points) == 0
    first = next(t for t in trajs if len(t.points))
    expected = syn.trajectory(np.array(samples[0].alpha))
    got = np.array([p.positions for p in first.points])
    np.testing.assert_array_equal(got, expected.positions)
    assert list(first.joint_names) == syn.joint_names


def test_fixed_context_arm_graph_equals_in_process_and_speaks_the_position_contract(tmp_path):
    """The arm with context: fixed through the graph (goal_generator + fixed_learner + mujoco_bridge
    in lockstep; config/arm8.yaml: dynamic, 20 % motor noise) equals the in-process run bit for bit,
    and the bag holds one rest command then θ per experiment on the position controller's topic."""
    n = 20
    ov = {"context": "fixed", "eval.goals": 5}
    graph = run_graph("config/arm8.yaml", n, tmp_path / "graph", eval_every=10, overrides=ov,
                              progress=False, stall_timeout=120.0, report=False)
    inproc = run_experiment("config/arm8.yaml", None, None, n, 10, tmp_path / "inproc", progress=False,
                            overrides=ov)
    assert graph["memory"]["samples"] == inproc["memory"]["samples"] == n
    assert graph["memory"]["digest"] == inproc["memory"]["digest"]
    assert graph["curve"] == inproc["curve"]
    assert graph["test_goals"] == inproc["test_goals"]
    assert [g["position"] for g in graph["goals"]] == [g["position"] for g in inproc["goals"]]
    assert graph["synergy"]["setup"] == inproc["synergy"]["setup"] == "arm-fixed"

    topics = graph["bag"]["topics"]
    cmd_topic = "/forward_position_controller/commands"
    assert topics[cmd_topic]["type"] == "std_msgs/msg/Float64MultiArray"
    assert topics["/tip_position"]["type"] == "geometry_msgs/msg/PointStamped"
    assert "/joint_trajectory_controller/joint_trajectory" not in topics

    from rosbags.highlevel import AnyReader
    cfg = load_experiment_config("config/arm8.yaml", ov)
    rest = np.array(cfg["sagg_learner"]["rest_posture"])
    with AnyReader([tmp_path / "graph" / "bag"], default_typestore=make_typestore()) as reader:
        conns = {c.topic: c for c in reader.connections}
        cmds = [np.array(reader.deserialize(raw, c.msgtype).data)
                for c, _, raw in reader.messages(connections=[conns[cmd_topic]])]
        samples = [reader.deserialize(raw, c.msgtype)
                   for c, _, raw in reader.messages(connections=[conns["/sagg/sample"]])]
    # the rest-outcome query (a rest command), then per experiment: rest, θ
    assert len(cmds) == 1 + 2 * n
    for c in [cmds[0]] + cmds[1::2]:
        np.testing.assert_array_equal(c, rest)
    for c, s in zip(cmds[2::2], samples):
        np.testing.assert_array_equal(c, np.array(s.alpha))
