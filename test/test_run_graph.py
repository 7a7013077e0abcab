"""`sagg run` end to end: the three nodes as separate processes learn, everything is recorded in an
mcap bag, the summary and the report are complete; Ctrl-C stops cleanly; bad parameters exit 2."""
import json
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml

from sagg_bringup.graph.setups import run_experiment
from sagg_bringup.bags.recorder import make_typestore
from installed import SAGG

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config/arm8.yaml"  # the `make run` default: 8-DOF dynamic arm, 20% motor noise
N, EVERY = 600, 300
# Stated learning factor: after N micro-actions the mean test error is below this share of the
# initial one (the in-process run of the same config reaches ~0.1 of it by 500 micro-actions).
LEARNING_FACTOR = 0.5
SUMMARY_KEYS = {"format", "strategy", "seed", "config", "node_params", "params_file", "timing", "domain_id",
                "micro_actions", "micro_actions_requested", "micro_actions_per_second", "learn_seconds",
                "startup_seconds", "eval_seconds", "wall_seconds", "curve", "final_mean_error",
                "final_median_error", "memory", "learner_status", "reports", "goals", "goal_stats", "regions",
                "splits", "bag", "rates", "nodes", "interrupted", "error"}
TOPICS = {"/sagg/goal": "sagg_msgs/msg/Goal", "/sagg/competence": "sagg_msgs/msg/CompetenceReport",
          "/sagg/regions": "sagg_msgs/msg/RegionTree", "/sagg/sample": "sagg_msgs/msg/Sample",
          "/sagg/status": "sagg_msgs/msg/LearnerStatus", "/sagg/evaluation": "sagg_msgs/msg/Evaluation",
          "/sagg/markers": "visualization_msgs/msg/MarkerArray",
          "/joint_states": "sensor_msgs/msg/JointState",
          "/forward_position_controller/commands": "std_msgs/msg/Float64MultiArray",
          "/tip_position": "geometry_msgs/msg/PointStamped"}


def read_bag(path):
    from rosbags.highlevel import AnyReader
    msgs, types = {}, {}
    with AnyReader([Path(path)], default_typestore=make_typestore()) as reader:
        for c in reader.connections:
            types[c.topic] = c.msgtype
        for conn, _, raw in reader.messages():
            msgs.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return types, msgs


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("graph") / "run"
    proc = subprocess.run([SAGG, "run", str(CONFIG), "--micro-actions", str(N), "--eval-every", str(EVERY),
                           "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, json.loads((out / "summary.json").read_text()), proc.stdout


def test_summary_is_complete(run):
    out, s, stdout = run
    assert SUMMARY_KEYS <= set(s)
    assert s["micro_actions"] == N and s["interrupted"] is False and s["error"] is None
    assert [c["micro_actions"] for c in s["curve"]] == [0, 300, 600]
    assert s["final_mean_error"] == s["curve"][-1]["mean_error"]
    assert s["micro_actions_per_second"] > 0 and s["wall_seconds"] > s["learn_seconds"] > 0
    assert s["learner_status"]["paused"] and "max_micro_actions" in s["learner_status"]["pause_reason"]
    assert len(s["goals"]) >= 3 and all(g["competence"] is not None for g in s["goals"][:-1])
    assert len(s["regions"]) >= 2 and len(s["splits"]) == len(s["regions"]) - 1
    assert all(info["exit_code"] is not None for info in s["nodes"].values())
    assert "final mean test error" in stdout
    # params.yaml is a configuration: the budget and checkpoint directory are the run's, on the
    # nodes' command lines (the summary's node_params has them)
    learner = yaml.safe_load((out / "params.yaml").read_text())["sagg_learner"]["ros__parameters"]
    assert "max_micro_actions" not in learner and "checkpoint_dir" not in learner
    assert s["node_params"]["sagg_learner"]["max_micro_actions"] == N
    for log in ("goal_generator", "learner", "mujoco_bridge"):
        assert (out / "logs" / f"{log}.log").is_file()


def test_three_processes_learn(run):
    _, s, _ = run
    first, last = s["curve"][0]["mean_error"], s["curve"][-1]["mean_error"]
    assert last < LEARNING_FACTOR * first, (first, last)


def test_bag_holds_every_topic_and_sample(run):
    out, s, _ = run
    types, msgs = read_bag(out / "bag")
    assert types == TOPICS
    assert {t: len(v) for t, v in msgs.items()} == {t: v["count"] for t, v in s["bag"]["topics"].items()}
    # every topic the run produced is there, with messages
    assert all(len(msgs.get(t, [])) > 0 for t in TOPICS)
    # the samples: exactly the learner's memory, in order
    samples = msgs["/sagg/sample"]
    assert len(samples) == s["memory"]["samples"] == s["learner_status"]["samples"] == N
    assert [m.index for m in samples] == list(range(N))
    assert s["bag"]["sequence_gaps"] == {"/sagg/sample": 0, "/sagg/competence": 0, "/sagg/goal": 0}
    # one command per micro-action + one per reset (one reset per goal in this config)
    assert len(msgs["/forward_position_controller/commands"]) == N + len(s["goals"])
    assert [m.seq for m in msgs["/sagg/goal"]] == [g["seq"] for g in s["goals"]]
    assert [m.seq for m in msgs["/sagg/competence"]] == list(range(1, s["reports"] + 1))
    evals = msgs["/sagg/evaluation"]
    assert [e.micro_actions for e in evals] == [0, 300, 600]
    assert [e.mean_error for e in evals] == [c["mean_error"] for c in s["curve"]]
    assert all(len(e.errors) == s["config"]["sagg_learner"]["eval.goals"] for e in evals)


def test_graph_run_equals_in_process_run(run):
    """Lockstep: the recorded samples, goals, evaluation curve and region tree are those of the
    in-process run of the same config (the graph is a faithful transport)."""
    _, s, _ = run
    r = run_experiment(CONFIG, None, None, N, EVERY, None, progress=False)
    assert s["memory"]["digest"] == r["memory"]["digest"]
    assert s["curve"] == r["curve"]
    assert [g["position"] for g in s["goals"]] == [g["position"] for g in r["goals"]]
    assert [g["micro_actions"] for g in s["goals"]] == [g["micro_actions"] for g in r["goals"]]
    def leaves(regions):  # (an empty region's mean competence is NaN in the message, 0 in-process)
        return [{k: v for k, v in g.items() if g["count"] or k != "mean_competence"} for g in regions]
    assert leaves(s["regions"]) == leaves(r["regions"])
    # the split history is the generator's own (its last checkpoint), whatever the load
    assert s["splits"] == json.loads(json.dumps(r["splits"]))
    assert s["eval_metrics"] == r["eval_metrics"]


def test_report_exists_and_references_its_figures(run):
    out, s, _ = run
    text = (out / "report.md").read_text()
    within = re.search(r"final share of test goals within ([^ |]+)", text)
    assert within and within.group(1) != "nan" and float(within.group(1)) == pytest.approx(s["eval_metrics"]["within"],
                                                                                         rel=1e-2)
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert len(images) == 4
    for name in images:
        assert (out / name).read_bytes()[:4] == b"\x89PNG"
    assert "## Recording" in text and "/sagg/sample" in text
    assert f"{s['final_mean_error']:.4g}" in text


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_ctrl_c_stops_everything_and_closes_the_bag(tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen([SAGG, "run", str(CONFIG), "--micro-actions", "1000000", "--out", str(out), "--quiet"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        log = out / "logs" / "learner.log"
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120:
            if log.is_file() and "graph ready" in log.read_text():
                break
            assert proc.poll() is None, proc.communicate()[1]
            time.sleep(0.2)
        # learning for a while: from the first sample the learner journals (it journals each before
        # publishing it). A fixed 2 s from "graph ready" was a guess about the machine: CI once
        # interrupted a run that had no sample yet (its logs were not kept; they now are, below).
        journals = out / "checkpoint"
        while time.monotonic() - t0 < 120 and not any(j.stat().st_size for j in journals.glob("learner_journal_*.bin")):
            assert proc.poll() is None, proc.communicate()[1]
            time.sleep(0.2)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert "interrupted" in err
    s = json.loads((out / "summary.json").read_text())
    assert s["interrupted"] is True and 0 < s["memory"]["samples"] < 1_000_000, (
        s.get("learner_status"), (out / "logs" / "learner.log").read_text()[-3000:])
    for info in s["nodes"].values():
        assert info["exit_code"] is not None and not _alive(info["pid"])
    types, msgs = read_bag(out / "bag")  # closed properly: readable, metadata written
    assert len(msgs["/sagg/sample"]) == s["memory"]["samples"]
    assert [m.index for m in msgs["/sagg/sample"]] == list(range(s["memory"]["samples"]))


def test_bad_parameter_exits_2_naming_it(tmp_path):
    proc = subprocess.run([SAGG, "run", str(CONFIG), "--micro-actions", "10", "--out", str(tmp_path / "o"),
                           "--set", "v=-1", "--quiet"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert "'v'" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "o").exists()  # nothing was started
