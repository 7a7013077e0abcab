"""The teachers beyond the paper through the graph: `sagg run` with alp-gmm and with
discretized-progress learns what the in-process run of the same config learns (lockstep), and
`sagg relearn` of its bag chooses every recorded goal again."""
from __future__ import annotations

import json
import os
import subprocess

import pytest

from sagg_bringup.bags.bags import relearn
from sagg_bringup.graph.setups import run_experiment
from installed import SAGG

N = 400
# a 7-DOF kinematic arm, and alp-gmm fitting every 10 goals so that its mixtures choose goals
SETS = {"arm.dof": 7, "arm.mode": "kinematic", "alp_gmm.fit_every": 10, "alp_gmm.bootstrap": 10,
        "alp_gmm.k_max": 3}


@pytest.fixture(scope="module", params=["alp-gmm", "discretized-progress"])
def graph_run(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("teacher") / "r"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    sets = [a for k, v in SETS.items() for a in ("--set", f"{k}={v}")]
    p = subprocess.run([SAGG, "run", "config/arm15_y50.yaml", "--strategy", request.param, *sets,
                        "--micro-actions", str(N), "--eval-every", str(N), "--out", str(out), "--quiet",
                        "--no-report"], env=env, capture_output=True, text=True, timeout=400)
    assert p.returncode == 0, p.stdout + p.stderr
    return request.param, out, json.loads((out / "summary.json").read_text())


def test_graph_run_of_a_teacher_equals_its_in_process_run(graph_run):
    strategy, _, s = graph_run
    r = run_experiment("config/arm15_y50.yaml", strategy, None, N, N, None, progress=False, overrides=SETS)
    assert s["strategy"] == strategy
    assert s["memory"]["digest"] == r["memory"]["digest"]
    assert [g["position"] for g in s["goals"]] == [g["position"] for g in r["goals"]]
    assert "region" in {g["mode_name"] for g in r["goals"]}  # the teacher's interest chose goals
    # the teacher's own view, read back from the generator node's last checkpoint: the in-process one
    assert s["teacher"]["teacher"] == strategy and s["teacher"] == r["teacher"]


def test_the_report_of_a_teachers_graph_run_draws_the_teacher(graph_run, tmp_path):
    from sagg_bringup.report.report import write_report
    _, _, s = graph_run
    write_report(s, tmp_path)
    assert (tmp_path / "teacher.png").stat().st_size > 10_000
    assert "teacher.png" in (tmp_path / "report.md").read_text()


def test_relearn_of_a_teachers_bag_chooses_its_goals_again(graph_run, tmp_path):
    strategy, out, s = graph_run
    re = relearn([out / "bag"], tmp_path / "re", evaluate=False, report=False, out=lambda _: None)
    assert re["strategy"] == strategy
    assert re["goals_match"] and re["goals"] == len(s["goals"]) > 5
    assert re["memory"]["digest"] == s["memory"]["digest"]


def test_a_fixed_context_graph_run_of_a_teacher_reports_its_view(tmp_path):
    # the other graph path (fixed_graph: the fixed-context learner), with its own short report
    out = tmp_path / "r"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    p = subprocess.run([SAGG, "run", "config/arm7_ratio15.yaml", "--set", "context=fixed", "--strategy",
                        "discretized-progress", "--micro-actions", "300", "--eval-every", "300", "--out", str(out),
                        "--quiet"], env=env, capture_output=True, text=True, timeout=400)
    assert p.returncode == 0, p.stdout + p.stderr
    s = json.loads((out / "summary.json").read_text())
    r = run_experiment("config/arm7_ratio15.yaml", "discretized-progress", None, 300, 300, None, progress=False,
                       overrides={"context": "fixed"})
    assert s["teacher"] == r["teacher"] and any(s["teacher"]["progress"])
    assert (out / "teacher.png").stat().st_size > 10_000 and "teacher.png" in (out / "report.md").read_text()
