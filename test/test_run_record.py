"""Recording (sagg run's recorder) against a fake publisher, and the ROS-free parts of the run:
the generated parameter file and the split history rebuilt from /sagg/regions snapshots."""
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from sagg_bringup.inprocess.experiment import InProcessRun
from sagg_bringup.graph.setups import load_experiment_config
from sagg_bringup.inprocess.arm_params import graph_params, load_graph_config
from sagg_bringup.graph.params_files import run_only_params, run_values, write_params_file
from sagg_bringup.graph.processes import pick_domain_id
from sagg_bringup.graph.split_tracker import SplitTracker
from sagg_bringup.bags.topics import graph_topics
from sagg_bringup.bags.recorder import BagWriter, TopicRecorder, TopicSpec, make_typestore
from sagg_bringup.report.report import leaves_after
from sagg_common.params import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SMALL = {"arm.dof": 7, "task_space.lower": [0.0, -60.0], "task_space.upper": [60.0, 60.0]}


def _read_bag(path):
    from rosbags.highlevel import AnyReader
    out = {}
    with AnyReader([Path(path)], default_typestore=make_typestore()) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return types, out


def test_recorder_writes_exact_cdr_of_every_message(tmp_path):
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sagg_msgs.msg import Region, RegionTree, Sample
    from sensor_msgs.msg import JointState

    topics = [TopicSpec("/sagg/sample", "sagg_msgs/msg/Sample"),
              TopicSpec("/sagg/regions", "sagg_msgs/msg/RegionTree", depth=100, transient_local=True),
              TopicSpec("/joint_states", "sensor_msgs/msg/JointState"),
              TopicSpec("/sagg/goal", "sagg_msgs/msg/Goal")]  # never published: an empty connection
    ctx = Context()
    rclpy.init(context=ctx, domain_id=pick_domain_id())
    try:
        pub_node = rclpy.create_node("fake_learner", context=ctx)
        rec_node = rclpy.create_node("recorder", context=ctx)
        bag = BagWriter(tmp_path / "bag", topics)
        seen = []
        rec = TopicRecorder(rec_node, bag, topics, {"/sagg/sample": lambda m: seen.append(m.index)})
        ps = pub_node.create_publisher(Sample, "/sagg/sample", 10000)
        pr = pub_node.create_publisher(RegionTree, "/sagg/regions",
                                       QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL))
        pj = pub_node.create_publisher(JointState, "/joint_states", 10)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(rec_node)
        ex.add_node(pub_node)
        t0 = time.monotonic()
        while ps.get_subscription_count() == 0 and time.monotonic() - t0 < 10:
            ex.spin_once(timeout_sec=0.01)
        rng = np.random.default_rng(0)
        sent = []
        special = [5e-324, -0.0, 1e300, math.pi, -1.0 / 3.0]  # subnormal, signed zero, extremes
        for i in range(300):
            a = rng.normal(size=3)
            a[i % 3] = special[i % len(special)]
            sent.append((a, -a, a[:2] * 7.0))
            ps.publish(Sample(index=i, alpha=a.tolist(), delta_alpha=(-a).tolist(), delta_y=(a[:2] * 7.0).tolist()))
        pr.publish(RegionTree(goals=3, splits=1, regions=[Region(id=1, lower=[0.0, 0.0], upper=[1.0, 2.0]),
                                                          Region(id=2, lower=[1.0, 0.0], upper=[3.0, 2.0])]))
        pj.publish(JointState(name=["joint_0", "joint_1"], position=[0.5, -0.25], velocity=[0.0, 0.0]))
        t0 = time.monotonic()
        while (len(seen) < 300 or bag.counts["/joint_states"] < 1 or bag.counts["/sagg/regions"] < 1) \
                and time.monotonic() - t0 < 20:
            ex.spin_once(timeout_sec=0.01)
        rec.destroy()
        bag.close()
        ex.shutdown()
    finally:
        rclpy.shutdown(context=ctx)
    assert seen == list(range(300))  # the handler got every message, in order
    types, msgs = _read_bag(tmp_path / "bag")
    assert types == {t.name: t.msgtype for t in topics}
    assert bag.topics()["/sagg/sample"] == {"type": "sagg_msgs/msg/Sample", "count": 300}
    assert "/sagg/goal" not in msgs and bag.counts["/sagg/goal"] == 0
    for m, (a, da, dy) in zip(msgs["/sagg/sample"], sent):
        assert m.alpha.tobytes() == a.tobytes() and m.delta_alpha.tobytes() == da.tobytes()
        assert m.delta_y.tobytes() == dy.tobytes()
    assert [m.index for m in msgs["/sagg/sample"]] == list(range(300))
    (tree,) = msgs["/sagg/regions"]
    assert [r.id for r in tree.regions] == [1, 2] and tree.regions[1].upper.tolist() == [3.0, 2.0]
    assert list(msgs["/joint_states"][0].name) == ["joint_0", "joint_1"]
    # metadata.yaml says mcap, version 9
    meta = yaml.safe_load((tmp_path / "bag" / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["version"] == 9 and meta["storage_identifier"] == "mcap"
    assert meta["message_count"] == 302


def test_bag_writer_refuses_an_existing_path(tmp_path):
    (tmp_path / "bag").mkdir()
    with pytest.raises(FileExistsError, match="bag"):
        BagWriter(tmp_path / "bag", [TopicSpec("/sagg/sample", "sagg_msgs/msg/Sample")])


def test_params_file_gives_every_node_its_parameters(tmp_path):
    full = load_graph_config(ROOT / "config/arm8.yaml", {"seed": 4, "timing": "realtime"})
    params = graph_params(full, 1234, "lockstep")
    write_params_file(tmp_path / "params.yaml", params)
    doc = yaml.safe_load((tmp_path / "params.yaml").read_text())
    assert set(doc) == {"sagg_goal_generator", "sagg_learner", "sagg_sim_bridge"}
    lp = doc["sagg_learner"]["ros__parameters"]
    assert lp["seed"] == 4
    # the budget is the run's, not the configuration's: on the nodes' command lines
    assert "max_micro_actions" not in lp and run_values(params)["sagg_learner"]["max_micro_actions"] == 1234
    assert lp["joints"] == [f"joint_{i}" for i in range(8)]
    assert len(lp["joint_limits"]["lower"]) == 8 and len(lp["rest_posture"]) == 8
    assert lp["task_space"] == {"lower": [0.0, -60.0], "upper": [100.0, 60.0]}
    # the waits for `sagg run`'s recorder are not in the file (it must work without sagg run) ...
    assert lp["min_sample_subscribers"] == 0
    assert doc["sagg_goal_generator"]["ros__parameters"]["min_goal_subscribers"] == 0
    # ... they are given on the nodes' command lines: the recorder must see every sample and goal
    assert run_only_params(params) == {"sagg_learner": {"min_sample_subscribers": 1,
                                                        **run_values(params)["sagg_learner"]},
                                       "sagg_goal_generator": {"min_goal_subscribers": 1,
                                                               **run_values(params)["sagg_goal_generator"]}}
    bp = doc["sagg_sim_bridge"]["ros__parameters"]
    assert bp["timing"] == "lockstep" and bp["arm"]["dof"] == 8 and bp["arm"]["motor_noise"] == 0.2
    # the learner's joints are the bridge arm's, so the rest posture is the arm's
    from sagg_sim_bridge.params import arm_spec_from_params
    assert lp["rest_posture"] == arm_spec_from_params(full["sagg_sim_bridge"]).rest_posture().tolist()
    names = [t.name for t in graph_topics(params["sagg_learner"])]
    assert "/forward_position_controller/commands" in names and "/tip_position" in names
    assert lp["observation_delay"] == 0.0 and "/clock" not in names
    # real-time bridge: the learner waits two publish periods for a post-command state; /clock recorded
    rt = graph_params(full, 10, "realtime")
    assert rt["sagg_sim_bridge"]["timing"] == "realtime"
    assert rt["sagg_learner"]["observation_delay"] == 2.0 / rt["sagg_sim_bridge"]["publish_rate"]
    assert "/clock" in [t.name for t in graph_topics(rt["sagg_learner"], "realtime")]


def test_graph_config_errors_name_the_parameter():
    with pytest.raises(ConfigError, match="'v'"):
        load_graph_config(ROOT / "config/arm8.yaml", {"v": -1.0})
    with pytest.raises(ConfigError, match="no_such_param"):
        load_graph_config(ROOT / "config/arm8.yaml", {"no_such_param": 1})
    with pytest.raises(ConfigError, match="timing"):
        load_graph_config(ROOT / "config/arm8.yaml", {"timing": "sometimes"})


@pytest.mark.parametrize("every", [1, 3, 1000])
def test_split_history_rebuilt_from_region_snapshots(every):
    """Snapshots after every report give the exact split list; coalesced ones (every 3rd report,
    or only the final tree) still give the exact leaves at every snapshot."""
    cfg = load_experiment_config(ROOT / "config/arm15.yaml", SMALL)
    run = InProcessRun(cfg)
    gen = run.generator
    tracker = SplitTracker(gen.lower, gen.upper)
    observed = []
    original = gen.report

    def report(kind, target, competence):
        original(kind, target, competence)
        if gen.reports % every == 0:
            snap = gen.region_snapshot()
            tracker.update([(r["id"], r["lower"], r["upper"]) for r in snap], len(gen.goals))
            observed.append((len(gen.goals), sorted((tuple(r["lower"]), tuple(r["upper"])) for r in snap)))

    gen.report = report
    run.step_until(1000)
    snap = gen.region_snapshot()
    tracker.update([(r["id"], r["lower"], r["upper"]) for r in snap], len(gen.goals))
    observed.append((len(gen.goals), sorted((tuple(r["lower"]), tuple(r["upper"])) for r in snap)))
    assert len(snap) > 5 and tracker.inconsistent == 0
    if every == 1:
        keys = ("region", "dim", "value", "left", "right", "stamp")
        assert [{k: s[k] for k in keys} for s in tracker.splits] == \
               [{k: s[k] for k in keys} for s in gen.tree.splits]
    else:
        assert len(tracker.splits) == len(gen.tree.splits)
    for i, (stamp, boxes) in enumerate(observed):
        later_same_stamp = any(s == stamp for s, _ in observed[i + 1:])
        if later_same_stamp:
            continue  # leaves_after(stamp) shows the last snapshot with that stamp
        rebuilt = leaves_after(tracker.splits, gen.lower, gen.upper, stamp)
        assert sorted((tuple(lo), tuple(hi)) for lo, hi in rebuilt) == boxes


def test_graph_session_closed_before_run_leaves_a_readable_bag_and_no_context(tmp_path):
    # what run_graph does when its set-up fails or is interrupted before session.run (e.g. a
    # corrupt earlier bag on --resume): the new bag segment must be closed, or the next --resume
    # could not read it
    from rosbags.highlevel import AnyReader

    from sagg_bringup.graph.session import GraphSession

    params = graph_params(load_graph_config(ROOT / "config/arm8.yaml"), 100, "lockstep")
    session = GraphSession([], None, graph_topics(params["sagg_learner"], "lockstep"), tmp_path / "bag",
                           tmp_path, drain=10)
    assert session.ctx.ok()
    session.close()
    session.close()  # once only
    assert not session.ctx.ok()
    with AnyReader([tmp_path / "bag"], default_typestore=make_typestore()) as reader:
        assert reader.message_count == 0


def test_final_drain_takes_the_stopped_nodes_backlog_and_not_a_live_drivers_stream(tmp_path):
    # after the nodes stop, sagg run drains the recorder until the nodes' topics fall silent; an
    # external driver's joint states and task point never do (nor a gripper driver's joint states
    # beside the simulated arm), and must not hold the run to the drain's limit (it did: every
    # `--driver external` run ended with a 60 s wait; with a gripper publishing, every run): a topic
    # another node still publishes on is not waited on
    import rclpy
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import JointState

    from sagg_bringup.graph.session import GraphSession

    params = graph_params(load_graph_config(ROOT / "config/arm8.yaml"), 100, "lockstep")
    session = GraphSession([], None, graph_topics(params["sagg_learner"], "lockstep"), tmp_path / "bag",
                           tmp_path, drain=10)
    driver = rclpy.create_node("some_driver", context=session.ctx)  # (its publishers outlive our nodes)
    driver.create_publisher(JointState, "/joint_states", 10)
    driver.create_publisher(PointStamped, "/tip_position", 10)
    spins = []

    class Stream:
        """A driver publishing for ever; the stopped learner's backlog: 30 more samples."""
        def spin_once(self, timeout_sec):  # noqa: ARG002
            spins.append(1)
            time.sleep(0.01)
            session.bag.counts["/joint_states"] += 1
            session.bag.counts["/tip_position"] += 1
            if len(spins) <= 30:
                session.bag.counts["/sagg/sample"] += 1

    real = session.executor
    session.executor, session.recorder = Stream(), object()
    try:
        session.drain_recorder(quiet=0.2, limit=60.0)
    finally:
        session.executor, session.recorder = real, None
        driver.destroy_node()
        session.close()
    assert session.bag.counts["/sagg/sample"] == 30  # the whole backlog was taken
    assert 31 <= len(spins) < 1000  # then it stopped, ~0.2 s later (at the limit: ~6,000 spins)
