"""Bags of `sagg run`: relearning offline gives the run's final memory and region tree; replay
republishes the exact recorded CDR (counts and bytes), and stops cleanly on SIGINT."""
from __future__ import annotations

import json
import contextlib
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from sagg_bringup.bags.bag_reader import bag_messages
from sagg_bringup.bags.bags import relearn
from sagg_bringup.graph.processes import pick_domain_id
from sagg_low_level.memory import SampleMemory

from sagg_low_level.checkpoint import checkpoint_memory
from installed import SAGG

ROOT = Path(__file__).resolve().parents[1]
STEPS = 600


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A small `sagg run` (7-DOF kinematic arm, mostly reachable Y)."""
    out = tmp_path_factory.mktemp("run") / "r"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    p = subprocess.run([SAGG, "run", str(ROOT / "config/arm15_y50.yaml"), "--set", "arm.dof=7",
                        "--set", "arm.mode=kinematic", "--micro-actions", str(STEPS), "--eval-every", "300",
                        "--out", str(out), "--quiet", "--no-report"],
                       env=env, capture_output=True, text=True, timeout=400)
    assert p.returncode == 0, p.stdout + p.stderr
    return out


def test_relearn_gives_the_runs_memory_and_tree(run_dir, tmp_path):
    summary = json.loads((run_dir / "summary.json").read_text())
    s = relearn([run_dir / "bag"], tmp_path / "re", out=lambda _: None)
    # the memory rebuilt offline is the run's final memory (recorded samples, and the learner's own
    # final checkpoint, written at shutdown)
    ck = json.loads((run_dir / "checkpoint" / "learner.json").read_text())
    assert s["memory"]["samples"] == STEPS == ck["memory_samples"]
    assert s["memory"]["digest"] == summary["memory"]["digest"] == ck["memory_digest"]
    mem = SampleMemory.load(tmp_path / "re" / "memory.npz")
    assert mem.digest() == ck["memory_digest"] == checkpoint_memory(run_dir / "checkpoint").digest()
    # the region tree: the core generator, fed the recorded reports and choosing the goals as the
    # node did, chose every recorded goal and equals every recorded /sagg/regions snapshot,
    # the last one included
    assert s["goals_match"] and s["goals"] == len(summary["goals"]) >= 2
    assert s["regions_match"] and s["regions_snapshots_checked"] >= 2 and s["splits"] >= 1
    assert s["last_regions_snapshot_reports"] == s["reports"] == summary["reports"]
    regions = json.loads((tmp_path / "re" / "regions.json").read_text())
    assert [(r["id"], r["lower"], r["upper"], r["count"]) for r in regions["regions"]] == \
           [(r["id"], r["lower"], r["upper"], r["count"]) for r in summary["regions"]]
    # same evaluation code and test goals as the run: the same final test error
    assert s["test_goals"] == summary["test_goals"]
    assert s["final_mean_error"] == summary["final_mean_error"]
    # and the evaluation's other metrics (eval_metrics), as the run reports them
    assert s["curve"][-1]["median_error"] == summary["curve"][-1]["median_error"]
    assert s["final_within_share"] == summary["curve"][-1]["within_share"]
    assert s["band_mean_errors"] == summary["curve"][-1]["band_mean_errors"]
    assert s["eval_metrics"]["band_counts"] and sum(s["eval_metrics"]["band_counts"]) == len(s["test_goals"])


def test_relearn_detects_a_tampered_recording(run_dir, tmp_path):
    """A sample missing from the recording is an error naming it, not a silently different memory."""
    from sagg_bringup.bags.recorder import BagWriter, TopicSpec
    msgs = list(bag_messages([run_dir / "bag"]))
    types = {t: ty for t, ty, _, _ in msgs}
    bag = BagWriter(tmp_path / "bag", [TopicSpec(t, ty) for t, ty in types.items()])
    dropped = False
    for topic, _, ts, raw in msgs:
        if topic == "/sagg/sample" and not dropped and ts > msgs[len(msgs) // 2][2]:
            dropped = True
            continue
        bag.write(topic, ts, raw)
    bag.close()
    from sagg_common.params import ConfigError
    with pytest.raises(ConfigError, match="samples are missing"):
        relearn([tmp_path / "bag"], tmp_path / "re", params_file=run_dir / "params.yaml", out=lambda _: None)


def test_relearn_drops_hostile_messages_and_rebuilds_the_real_memory(run_dir, tmp_path):
    """A NaN sample, a well-formed sample far ahead, a NaN report, a report with seq
    10^12, a NaN goal and undecodable bytes in a bag: relearn never crashes, counts what it drops,
    and rebuilds exactly the run's memory, goals and tree (no forged message took a real index)."""
    from sagg_bringup.bags.recorder import BagWriter, TopicSpec
    from sagg_common.msg_codecs import encode_report, encode_sample
    from rclpy.serialization import serialize_message
    from sagg_msgs.msg import Goal
    summary = json.loads((run_dir / "summary.json").read_text())
    msgs = list(bag_messages([run_dir / "bag"]))
    types = {t: ty for t, ty, _, _ in msgs}
    bag = BagWriter(tmp_path / "bag", [TopicSpec(t, ty) for t, ty in types.items()])
    injected = False
    samples = 0
    for topic, _, ts, raw in msgs:
        if topic == "/sagg/sample":
            if samples == STEPS // 2 and not injected:
                injected = True
                z = np.zeros(7)
                bag.write(topic, ts, encode_sample(ts, samples, z + np.nan, z, np.zeros(2)))   # NaN, next index
                bag.write(topic, ts, encode_sample(ts, samples + 1000, z, z, np.zeros(2)))     # far ahead
                bag.write(topic, ts, encode_sample(ts, samples, z + 9.0, z, np.zeros(2)))      # α outside limits
                bag.write(topic, ts, b"\x00\x01\x00\x00garbage")
                bag.write("/sagg/competence", ts, encode_report(ts, 10**12, 0, 3, (), (1.0, 1.0), (0.0, 0.0), 0.0, 1))
                bag.write("/sagg/competence", ts, encode_report(ts, 1, 0, 3, (), (np.nan, 1.0), (0.0, 0.0), 0.0, 1))
                g = Goal()
                g.seq, g.position = 2, [float("nan"), 0.0]
                bag.write("/sagg/goal", ts, serialize_message(g))
            samples += 1
        bag.write(topic, ts, raw)
    bag.close()
    s = relearn([tmp_path / "bag"], tmp_path / "re", params_file=run_dir / "params.yaml", out=lambda _: None)
    assert s["memory"]["digest"] == summary["memory"]["digest"] and s["memory"]["samples"] == STEPS
    assert s["goals_match"] and s["regions_match"] and s["reports"] == summary["reports"]
    assert s["rejected"] == {"sample": 3, "sample undecodable": 1, "report": 2, "goal": 1}


def _subscriber(domain: int, topics: dict[str, str]):
    """A test-side node receiving the raw bytes of ``topics`` (name -> type)."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sagg_bringup.bags.recorder import msg_class
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = rclpy.create_node("sagg_test_replay_sub", context=ctx)
    got: dict[str, list[bytes]] = {t: [] for t in topics}
    for t, ty in topics.items():
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=(DurabilityPolicy.TRANSIENT_LOCAL if t == "/sagg/regions" else
                                     DurabilityPolicy.VOLATILE))
        node.create_subscription(msg_class(ty), t, lambda data, t=t: got[t].append(bytes(data)), qos, raw=True)
    ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    return ctx, ex, got


@contextlib.contextmanager
def _replay(bag, topics: dict[str, str], *args: str):
    """`sagg replay BAG --topics ... ARGS --wait-subscribers 1` in a subprocess on a private domain,
    with a test-side subscriber of ``topics`` there: yields (executor, received bytes, process);
    afterwards the process is killed if still running and the subscriber's context shut down."""
    domain = pick_domain_id()
    ctx, ex, got = _subscriber(domain, topics)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.Popen([SAGG, "replay", str(bag), *args, "--topics", *topics,
                             "--wait-subscribers", "1"], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        yield ex, got, proc
    finally:
        if proc.poll() is None:
            proc.kill()
        ctx.try_shutdown()


def test_replay_republishes_the_exact_bytes(run_dir):
    bag = run_dir / "bag"
    recorded: dict[str, list[bytes]] = {}
    types = {}
    for topic, ty, _, raw in bag_messages([bag]):
        recorded.setdefault(topic, []).append(bytes(raw))
        types[topic] = ty
    topics = {t: types[t] for t in ("/sagg/sample", "/sagg/goal", "/sagg/competence", "/sagg/regions",
                                    "/joint_states")}
    with _replay(bag, topics, "--rate", "0") as (ex, got, proc):
        end = time.monotonic() + 120
        while time.monotonic() < end and (proc.poll() is None or
                                          any(len(got[t]) < len(recorded[t]) for t in topics)):
            ex.spin_once(timeout_sec=0.05)
            if proc.poll() is not None and proc.returncode != 0:
                break
        text = proc.communicate(timeout=30)[0]
    assert proc.returncode == 0, text
    for t in topics:
        assert len(got[t]) == len(recorded[t]) > 0, t
        assert got[t] == recorded[t], t  # same bytes, same order
    assert f"replayed {sum(len(recorded[t]) for t in topics):,} messages" in text


def test_replay_stops_cleanly_on_sigint(run_dir):
    with _replay(run_dir / "bag", {"/sagg/sample": "sagg_msgs/msg/Sample"}, "--rate", "1", "--loop") as (ex, got, proc):
        end = time.monotonic() + 60
        while time.monotonic() < end and len(got["/sagg/sample"]) < 5:
            ex.spin_once(timeout_sec=0.05)
        assert len(got["/sagg/sample"]) >= 5
        proc.send_signal(signal.SIGINT)
        text = proc.communicate(timeout=30)[0]
    assert proc.returncode == 130, text
    assert "(interrupted)" in text and "Traceback" not in text
    # what arrived is the recording's start, in order (rate 1: the bag's own pace)
    recorded = [bytes(raw) for _, _, _, raw in bag_messages([run_dir / "bag"], {"/sagg/sample"})]
    n = len(got["/sagg/sample"])
    assert got["/sagg/sample"] == (recorded * (n // len(recorded) + 1))[:n]
    assert np.all(np.isfinite([len(b) for b in got["/sagg/sample"]]))


def test_run_resume_continues_the_run(run_dir, tmp_path):
    """`sagg run --resume DIR` on a finished run with a larger budget: the nodes resume from the
    checkpoints, the new segment goes to bag2, and the summary, the relearned memory and the
    learner's own final checkpoint agree on the whole run (the first segment's samples unchanged)."""
    import shutil
    run = tmp_path / "r"
    shutil.copytree(run_dir, run)
    first = json.loads((run / "summary.json").read_text())
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    p = subprocess.run([SAGG, "run", "--resume", str(run), "--micro-actions", str(STEPS + 300),
                        "--quiet", "--no-report"], env=env, capture_output=True, text=True, timeout=400)
    assert p.returncode == 0, p.stdout + p.stderr
    s = json.loads((run / "summary.json").read_text())
    assert s["micro_actions"] == s["memory"]["samples"] == STEPS + 300
    assert s["bag"]["paths"] == [str(run / "bag"), str(run / "bag2")] and s["resumed_segments"] == 1
    assert [c["micro_actions"] for c in s["curve"]] == [0, 300, 600, 900]
    assert s["curve"][:3] == first["curve"]  # the first segment's evaluations are kept, not redone
    assert all(v == 0 for v in s["bag"]["sequence_gaps"].values())
    assert "resumed from" in (run / "logs" / "learner.2.log").read_text()
    ck = json.loads((run / "checkpoint" / "learner.json").read_text())
    r = relearn([run / "bag", run / "bag2"], tmp_path / "re", out=lambda _: None)
    assert r["memory"]["digest"] == s["memory"]["digest"] == ck["memory_digest"]
    # every report the learner counts is in the bags (a run used to end before a slow tail came)
    assert s["learner_status"]["reports"] == s["reports"] and not s["bag"]["dropped"], s["bag"]
    assert r["goals_match"] and r["regions_match"] and r["reports"] == s["reports"], {
        k: r.get(k) for k in ("goals_match", "goal_mismatches", "regions_match", "regions_snapshots_checked",
                              "regions_snapshots_differing", "last_regions_snapshot_reports", "reports", "goals",
                              "rejected", "duplicates_dropped")}
    old = checkpoint_memory(run_dir / "checkpoint")
    new = SampleMemory.load(tmp_path / "re" / "memory.npz")
    assert new.alpha[:STEPS].tobytes() == old.alpha.tobytes() and new.delta_y[:STEPS].tobytes() == old.delta_y.tobytes()


# ------------------------------------------------------------------ replay leaves command topics out
CMD = "/forward_position_controller/commands"
CMD_TYPES = {CMD: "std_msgs/msg/Float64MultiArray", "/joint_states": "sensor_msgs/msg/JointState"}


def _command_bag(path: Path, n: int = 20) -> Path:
    """A bag of ``n`` position commands and ``n`` joint states (as a `sagg run` records them)."""
    from sagg_bringup.bags.recorder import BagWriter, TopicSpec
    from sagg_common.cdr import encode_f64_array, encode_joint_state
    bag = BagWriter(path, [TopicSpec(t, ty) for t, ty in CMD_TYPES.items()])
    for i in range(n):
        bag.write(CMD, 1_000_000 * (2 * i + 1), encode_f64_array(np.array([0.01 * i, -0.01 * i])))
        bag.write("/joint_states", 1_000_000 * (2 * i + 2),
                  encode_joint_state(i, "", ["joint_0", "joint_1"], [0.01 * i, -0.01 * i]))
    bag.close()
    return path


def _replay_with(bag: Path, node_name: str, *args: str):
    """`sagg replay BAG ARGS` on a private domain, a test node ``node_name`` subscribed to the
    command topic and /joint_states there; returns (exit code, output, received bytes)."""
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sagg_bringup.bags.recorder import msg_class
    domain = pick_domain_id()
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        node = rclpy.create_node(node_name, context=ctx)
        got: dict[str, list[bytes]] = {t: [] for t in CMD_TYPES}
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        for t, ty in CMD_TYPES.items():
            node.create_subscription(msg_class(ty), t, lambda data, t=t: got[t].append(bytes(data)), qos, raw=True)
        ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
        proc = subprocess.Popen([SAGG, "replay", str(bag), "--rate", "0", "--wait-subscribers", "1",
                                 *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            end = time.monotonic() + 60
            while time.monotonic() < end and proc.poll() is None:
                ex.spin_once(timeout_sec=0.05)
            settle = time.monotonic() + 1.0  # whatever is still in flight
            while time.monotonic() < settle:
                ex.spin_once(timeout_sec=0.05)
            text = proc.communicate(timeout=30)[0]
        finally:
            if proc.poll() is None:
                proc.kill()
        return proc.returncode, text, got
    finally:
        ctx.try_shutdown()


def test_replay_publishes_no_command_by_default_and_never_to_a_driver(tmp_path):
    bag = _command_bag(tmp_path / "bag")
    # default: every other topic, no command (a driver listening here would move its robot)
    code, text, got = _replay_with(bag, "my_arm_driver")
    assert code == 0, text
    assert len(got["/joint_states"]) == 20 and got[CMD] == [], text
    assert f"command topic(s) left out: {CMD}" in text
    # naming it in --topics is not enough either
    code, text, got = _replay_with(bag, "my_arm_driver", "--topics", CMD)
    assert code == 2 and "--include-commands" in text and got[CMD] == [], text
    # --include-commands while a node other than sagg's simulator subscribes: refused, naming both
    code, text, got = _replay_with(bag, "my_arm_driver", "--include-commands")
    assert code == 2 and got[CMD] == [], text
    line = next(s for s in text.splitlines() if s.startswith("sagg: error:"))
    assert CMD in line and "my_arm_driver" in line and "sagg_sim_bridge" in line
    # ... and published when only sagg's simulator listens
    code, text, got = _replay_with(bag, "sagg_sim_bridge", "--include-commands")
    assert code == 0 and len(got[CMD]) == 20 and len(got["/joint_states"]) == 20, text
