"""Run reports (report.md + figures) from an in-process result, and the split-history replay."""
import json
import re
from pathlib import Path

import numpy as np
import pytest

from sagg_bringup.inprocess.experiment import InProcessRun
from sagg_bringup.graph.setups import load_experiment_config, run_experiment
from sagg_bringup.graph.setups import write_report as write_setup_report
from sagg_bringup.report.report import leaves_after, write_report

ROOT = Path(__file__).resolve().parents[1]
SMALL = {"arm.dof": 7, "task_space.lower": [0.0, -60.0], "task_space.upper": [60.0, 60.0]}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp")
    run_experiment(ROOT / "config/arm15.yaml", "sagg-riac", 3, 1500, 500, out, progress=False, overrides=SMALL)
    return out


def test_report_references_existing_figures(result, tmp_path):
    path = write_report(result / "result.json", tmp_path)  # a path to result.json works too
    text = path.read_text()
    data = json.loads((result / "result.json").read_text())
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert set(images) == {"learning_curve.png", "goals_over_time.png", "regions_over_time.png",
                           "competence_map.png"}
    for name in images:
        blob = (tmp_path / name).read_bytes()
        assert blob[:8] == PNG_MAGIC and len(blob) > 10_000
    # the numbers of the run are in the report
    assert f"{data['final_mean_error']:.4g}" in text
    assert data["memory"]["digest"] in text
    for c in data["curve"]:
        assert f"| {c['micro_actions']:,} | {c['mean_error']:.3f} |" in text
    assert "## Recording" not in text  # in-process: no bag


def test_report_rejects_incomplete_result(tmp_path):
    with pytest.raises(ValueError, match="curve"):
        write_report({"strategy": "sagg-riac", "seed": 0, "config": {}, "micro_actions": 0}, tmp_path)


def test_report_without_goals_skips_goal_figures(result, tmp_path):
    data = json.loads((result / "result.json").read_text())
    data["goals"] = []
    text = write_report(data, tmp_path).read_text()
    assert "learning_curve.png" in text and "goals_over_time.png" not in text
    assert not (tmp_path / "goals_over_time.png").exists()


def test_split_replay_gives_the_generators_leaves_at_every_goal():
    cfg = load_experiment_config(ROOT / "config/arm15.yaml", SMALL)
    run = InProcessRun(cfg)
    gen = run.generator
    lower, upper = gen.lower, gen.upper
    seen = []  # (goals issued so far, leaf boxes) just before each new goal
    original = gen.next_goal

    def next_goal():
        seen.append((len(gen.goals), sorted((tuple(r["lower"]), tuple(r["upper"])) for r in gen.region_snapshot())))
        return original()

    gen.next_goal = next_goal
    run.step_until(1200)
    assert len(seen) > 5 and len(seen[-1][1]) > 5  # several goals, and the tree did split
    for stamp, boxes in seen:
        rebuilt = sorted((tuple(lo), tuple(hi)) for lo, hi in leaves_after(gen.tree.splits, lower, upper, stamp))
        assert rebuilt == boxes
    final = sorted((tuple(r["lower"]), tuple(r["upper"])) for r in gen.region_snapshot())
    assert sorted((tuple(lo), tuple(hi)) for lo, hi in leaves_after(gen.tree.splits, lower, upper, np.inf)) == final


def test_report_describes_the_simulated_robot(result, tmp_path):
    data = json.loads((result / "result.json").read_text())
    text = write_setup_report(data, tmp_path / "arm").read_text()
    assert "| arm | 7 DOF, equal links" in text
    # a synergy run's bridge has a set-up, no arm.* parameters: named, never "None DOF"
    data["config"]["sagg_sim_bridge"] = {"seed": 3, "setup": "quadruped", "controller": "joint_trajectory_controller",
                                         "task_topic": "/body_pose"}
    text = write_setup_report(data, tmp_path / "quadruped").read_text()
    assert "| set-up | quadruped (synergies, fixed context; trajectories on joint_trajectory_controller, " \
           "outcome on /body_pose) |" in text
    assert "DOF" not in text


def test_report_names_what_the_recorder_missed_and_did_not_use(result, tmp_path):
    """A recorder that fell behind is never silent: the summary's bag.dropped (gaps in the
    publishers' sequence numbers), dropped_not_estimated and rejected appear in report.md."""
    data = json.loads((result / "result.json").read_text())
    data["bag"] = {"path": "bag", "topics": {"/joint_states": {"type": "sensor_msgs/msg/JointState", "count": 90}},
                   "dropped": {"/joint_states": 1234, "/tip_position": 7}, "dropped_not_estimated": ["/sagg/goal"],
                   "rejected": {"/sagg/sample publishers": 300}}
    text = write_report(data, tmp_path / "r").read_text()
    assert "Messages missed by the recorder" in text
    assert "`/joint_states` 1,234" in text and "`/tip_position` 7" in text
    assert "Not estimated (the topic had several publishers): `/sagg/goal`" in text
    assert "`/sagg/sample publishers` 300" in text
    data["bag"]["dropped"], data["bag"]["dropped_not_estimated"] = {}, []
    assert "Messages missed by the recorder (gaps in the publishers' sequence numbers): none." in \
        write_report(data, tmp_path / "r2").read_text()
