"""``sagg bench compare``: resuming after a kill, the settings fingerprint, the statistics on known
inputs, and the Ray path on a local Ray instance.

Runs are tiny (7-DOF kinematic arm, a few hundred micro-actions, 10 test goals). The command runs
in subprocesses in their own session, so a SIGKILL of the group stops the driver and its workers.
"""
from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from sagg_bringup.experiments.compare import curve_stats, pairwise_tests, summary_json
from sagg_bringup.experiments.sweep import (RunSpec, check_fingerprint, make_fingerprint, run_dir,
                                validate_result, expected_config)
from sagg_common.params import ConfigError
from installed import SAGG

ROOT = Path(__file__).resolve().parents[1]
CONFIG = str(ROOT / "config" / "arm15.yaml")
TINY = ["--set", "arm.dof=7", "--set", "eval.goals=10"]
STRATS = ["sagg-riac", "actuator-random"]
SEEDS = 3
MA, EVERY = 300, 150


def compare_cmd(out: Path, *extra: str, micro_actions: int = MA) -> list[str]:
    return [str(SAGG), "bench", "compare", "--config", CONFIG, "--strategies", *STRATS,
            "--seeds", str(SEEDS), "--micro-actions", str(micro_actions), "--eval-every", str(EVERY),
            "--out", str(out), "--workers", "1", *TINY, *extra]


def kill_group(p: subprocess.Popen) -> None:
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    p.wait(30)


def result_files(out: Path) -> list[Path]:
    return sorted((out / "runs").rglob("result.json"))


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """Start a comparison, SIGKILL it (driver and workers) once the first result exists, corrupt
    one unfinished run's result, restart it to the end."""
    out = tmp_path_factory.mktemp("cmp") / "out"
    p = subprocess.Popen(compare_cmd(out), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         start_new_session=True, text=True)
    try:
        end = time.monotonic() + 120
        while not result_files(out):
            assert p.poll() is None, f"compare exited early: {p.stdout.read()}"
            assert time.monotonic() < end, "no result within 120 s"
            time.sleep(0.05)
    finally:
        kill_group(p)
    first = {f: (f.stat().st_mtime_ns, f.read_bytes()) for f in result_files(out)}
    # an unfinished run whose result.json is half-written (e.g. copied in by hand, or a disk
    # full): it must be validated and rerun
    done_names = {f.parent for f in first}
    broken = next(run_dir(out, RunSpec(st, s)) for st in STRATS for s in range(SEEDS)
                  if run_dir(out, RunSpec(st, s)) not in done_names)
    broken.mkdir(parents=True, exist_ok=True)
    (broken / "result.json").write_text('{"format": "sagg.result/1", "strategy"')
    time.sleep(0.01)
    r = subprocess.run(compare_cmd(out), capture_output=True, text=True, timeout=300)
    return {"out": out, "first": first, "broken": broken, "restart": r}


def test_restart_keeps_finished_runs_and_completes_the_rest(resumed):
    out, first, r = resumed["out"], resumed["first"], resumed["restart"]
    assert r.returncode == 0, r.stdout + r.stderr
    assert 1 <= len(first) < len(STRATS) * SEEDS
    assert f"{len(first)} finished run(s) kept and skipped" in r.stdout
    # finished results untouched, byte for byte and by modification time
    for f, (mtime, data) in first.items():
        assert f.stat().st_mtime_ns == mtime
        assert f.read_bytes() == data
    # the restart ran exactly the missing runs: progress lines count from the kept ones
    progress = [line for line in r.stdout.splitlines() if line.startswith("[")]
    assert len(progress) == len(STRATS) * SEEDS - len(first)
    assert progress[-1].startswith(f"[{len(STRATS) * SEEDS}/{len(STRATS) * SEEDS}]")
    assert "ETA" in progress[-1]
    # the corrupted result was detected and rerun
    rel = f"{resumed['broken'].parent.name}/{resumed['broken'].name}"
    assert f"rerun {rel}: existing result.json unreadable" in r.stdout
    # every run finished, valid, and of its own strategy and seed
    for st in STRATS:
        for s in range(SEEDS):
            spec = RunSpec(st, s)
            f = run_dir(out, spec) / "result.json"
            assert validate_result(f, spec, MA, EVERY, expected_config(CONFIG, spec, {
                "arm.dof": 7, "eval.goals": 10})) is None
    summ = json.loads((out / "summary.json").read_text())
    assert set(summ["strategies"]) == set(STRATS)
    for st in STRATS:
        assert summ["strategies"][st]["seeds"] == list(range(SEEDS))
        assert summ["strategies"][st]["curve"]["micro_actions"] == [0, 150, 300]
    assert len(summ["tests"]) == 1 and summ["failed_runs"] == {}
    md = (out / "summary.md").read_text()
    assert "Mann-Whitney U" in md and "Welch t" in md and "seed i = 0 + i" in md
    assert (out / "curves.png").stat().st_size > 1000


def test_a_third_start_runs_nothing(resumed):
    out = resumed["out"]
    before = {f: f.stat().st_mtime_ns for f in result_files(out)}
    r = subprocess.run(compare_cmd(out), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert f"{len(STRATS) * SEEDS} finished run(s) kept and skipped, 0 to run" in r.stdout
    assert {f: f.stat().st_mtime_ns for f in result_files(out)} == before


def test_more_seeds_extend_a_finished_comparison(resumed, tmp_path):
    """`--seeds` raised on a finished comparison (as `sagg reproduce` does when the registry asks
    more seeds): the finished runs are kept, only the new seed runs, the summary has every seed."""
    out = tmp_path / "out"
    shutil.copytree(resumed["out"], out)
    before = {f.relative_to(out): f.read_bytes() for f in result_files(out)}
    cmd = compare_cmd(out)
    cmd[cmd.index("--seeds") + 1] = str(SEEDS + 1)
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"{len(STRATS) * SEEDS} finished run(s) kept and skipped, {len(STRATS)} to run" in r.stdout
    assert {f.relative_to(out): f.read_bytes() for f in result_files(out) if f.relative_to(out) in before} == before
    summ = json.loads((out / "summary.json").read_text())
    assert all(summ["strategies"][st]["seeds"] == list(range(SEEDS + 1)) for st in STRATS)
    assert json.loads((out / "compare.json").read_text())["seeds"] == list(range(SEEDS + 1))


def test_resuming_with_other_settings_is_refused(resumed):
    out = resumed["out"]
    r = subprocess.run(compare_cmd(out, micro_actions=MA + 1), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert "micro_actions: 300 -> 301" in r.stderr
    r = subprocess.run(compare_cmd(out, "--set", "v=3.0"), capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    assert "parameters.sagg_learner.v: 2.0 -> 3.0" in r.stderr
    assert "overrides" in r.stderr


def test_fingerprint_names_config_file_changes(tmp_path):
    cfg = tmp_path / "a.yaml"
    cfg.write_text(Path(CONFIG).read_text())
    fp = make_fingerprint(cfg, ["sagg-riac"], [0, 1], 100, 50, {})
    assert check_fingerprint(tmp_path / "out", fp) is False
    assert check_fingerprint(tmp_path / "out", fp) is True
    cfg.write_text(Path(CONFIG).read_text().replace("q: 20", "q: 25"))
    fp2 = make_fingerprint(cfg, ["sagg-riac"], [0, 1], 100, 50, {})
    with pytest.raises(ConfigError, match=r"parameters\.sagg_learner\.q: 20 -> 25"):
        check_fingerprint(tmp_path / "out", fp2)
    fp3 = make_fingerprint(CONFIG, ["sagg-riac"], [0, 1, 2], 100, 50, {})
    assert check_fingerprint(tmp_path / "out", fp3) is True  # the same settings, one seed more


def test_more_seeds_and_strategies_extend_a_comparison(tmp_path):
    """The run set may grow on a restart (each run is validated on its own); the stored
    fingerprint follows it, and any other setting still refuses."""
    out = tmp_path / "out"
    fp = make_fingerprint(CONFIG, ["sagg-riac"], [0, 1], 100, 50, {})
    assert check_fingerprint(out, fp) is False
    fp2 = make_fingerprint(CONFIG, ["sagg-riac", "sagg-random"], [0, 1, 2, 3], 100, 50, {})
    assert check_fingerprint(out, fp2) is True
    stored = json.loads((out / "compare.json").read_text())
    assert stored["seeds"] == [0, 1, 2, 3] and stored["strategies"] == ["sagg-riac", "sagg-random"]
    fp3 = make_fingerprint(CONFIG, ["sagg-riac"], [0, 1, 2, 3, 4], 200, 50, {})
    with pytest.raises(ConfigError, match=r"micro_actions: 100 -> 200"):
        check_fingerprint(out, fp3)
    assert json.loads((out / "compare.json").read_text())["seeds"] == [0, 1, 2, 3]


def test_bad_arguments_name_the_field(tmp_path):
    from sagg_bringup.experiments.sweep import run_compare
    with pytest.raises(ConfigError, match="--strategies"):
        run_compare(CONFIG, ["nope"], 1, 10, 10, tmp_path / "o")
    with pytest.raises(ConfigError, match="--set seed"):
        run_compare(CONFIG, ["sagg-riac"], 1, 10, 10, tmp_path / "o", overrides={"seed": 3})
    assert not (tmp_path / "o").exists()


def test_pairwise_statistics_on_known_inputs():
    a, b = [1.0, 2.0, 3.0], [4.0, 5.0, 6.0, 7.5]
    t = pairwise_tests(a, b)
    # U of a: every a is below every b -> 0; the exact null distribution of U for sizes 3 and 4
    # has C(7,3) = 35 equally likely rank sets, one with U = 0 (and one with U = 12)
    assert t["mannwhitney_u"] == 0.0
    assert t["mannwhitney_p_less"] == pytest.approx(1 / 35)
    assert t["mannwhitney_p"] == pytest.approx(2 / 35)
    # Welch by hand
    ma, mb = np.mean(a), np.mean(b)
    va, vb = np.var(a, ddof=1) / 3, np.var(b, ddof=1) / 4
    tt = (ma - mb) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va ** 2 / 2 + vb ** 2 / 3)
    assert t["welch_t"] == pytest.approx(tt)
    assert t["welch_p"] == pytest.approx(2 * stats.t.sf(abs(tt), df))
    # swapped: U is n_a n_b - U, the two-sided p is symmetric, the one-sided is not significant
    s = pairwise_tests(b, a)
    assert s["mannwhitney_u"] == 12.0 and s["mannwhitney_p"] == pytest.approx(t["mannwhitney_p"])
    assert s["mannwhitney_p_less"] == pytest.approx(1.0)
    assert math.isnan(pairwise_tests([1.0], [2.0, 3.0])["welch_p"])


def _fake(strategy, seed, ys, share=0.5):
    return {"strategy": strategy, "seed": seed, "final_mean_error": ys[-1],
            "curve": [{"micro_actions": 100 * i, "mean_error": y} for i, y in enumerate(ys)],
            "goal_stats": {"goal_share_reachable_second_half": share, "reachable_share_of_Y": 0.1}}


def test_curve_statistics_and_summary_on_known_inputs():
    rs = [_fake("x", 1, [10.0, 4.0, 2.0]), _fake("x", 0, [10.0, 2.0, 1.0]),
          _fake("y", 0, [10.0, 6.0, 5.0]), _fake("y", 1, [10.0, 8.0, 7.0])]
    c = curve_stats([r for r in rs if r["strategy"] == "x"])
    assert c["micro_actions"] == [0, 100, 200] and c["n"] == 2
    assert c["mean"] == pytest.approx([10.0, 3.0, 1.5])
    assert c["std"] == pytest.approx([0.0, math.sqrt(2.0), math.sqrt(0.5)])
    s = summary_json(rs, ["y", "x"])
    assert list(s["strategies"]) == ["y", "x"]
    assert s["strategies"]["x"]["seeds"] == [0, 1]
    assert s["strategies"]["x"]["final_mean_error"] == [1.0, 2.0]
    assert s["strategies"]["y"]["final_mean"] == pytest.approx(6.0)
    assert s["strategies"]["y"]["final_std"] == pytest.approx(math.sqrt(2.0))
    assert [(t["a"], t["b"]) for t in s["tests"]] == [("y", "x")]
    assert s["tests"][0]["mannwhitney_u"] == 4.0


def test_ray_local_instance_gives_the_process_pool_results(resumed, tmp_path):
    import ray  # installed by `make test` (requirements-ray.txt); a missing Ray fails, no skip
    assert ray.__version__ == "2.60.0"
    out = tmp_path / "ray"
    cmd = [str(SAGG), "bench", "compare", "--config", CONFIG, "--strategies", "sagg-riac",
           "--seeds", "1", "--micro-actions", str(MA), "--eval-every", str(EVERY), "--out", str(out),
           "--workers", "1", "--ray", "local", *TINY]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300,
                       env=dict(os.environ, RAY_AUTH_MODE="disabled"))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "to run on Ray (local)" in r.stdout
    assert "[1/1] sagg-riac/seed-0" in r.stdout
    for s in range(1):
        spec = RunSpec("sagg-riac", s)
        ray_res = json.loads((run_dir(out, spec) / "result.json").read_text())
        pool_res = json.loads((run_dir(resumed["out"], spec) / "result.json").read_text())
        # same seed and settings -> the same run, whichever executor ran it
        assert ray_res["curve"] == pool_res["curve"]
        assert ray_res["memory"]["digest"] == pool_res["memory"]["digest"]
    assert (out / "summary.md").exists()


def test_bench_speed_rows_and_bytes_per_sample():
    from sagg_lab.bench import babbling_samples, bench_speed
    from sagg_bringup.inprocess.experiment import InProcessRun
    from sagg_bringup.graph.setups import load_experiment_config
    run = InProcessRun(load_experiment_config(CONFIG, {"arm.dof": 7}))
    a, da, dy = babbling_samples(run, 450, period=200)
    assert a.shape == da.shape == (450, 7) and dy.shape == (450, 2)
    # walks start at rest every 200 samples, and Δy is the simulator's tip displacement
    assert np.array_equal(a[200], run.sim.rest) and np.array_equal(a[400], run.sim.rest)
    tips = run.sim.tip_positions(np.vstack([a[:5], a[4] + da[4]]))
    assert np.allclose(dy[:5], np.diff(tips, axis=0))
    lines = []
    res = bench_speed(CONFIG, dofs=(7,), sizes=(600, 300), measure=40,
                      strategies=("sagg-riac", "actuator-random"), graph=False, out=lines.append)
    rows = res["rows"]
    assert [(r["strategy"], r["stored"]) for r in rows] == [
        ("sagg-riac", 300), ("sagg-riac", 600), ("actuator-random", 300), ("actuator-random", 600)]
    for r in rows:
        assert r["data_bytes_per_sample"] == (7 + 7 + 2) * 8
        assert r["bytes_per_sample"] > r["data_bytes_per_sample"]
        assert r["rate"] > 0
    assert rows[0]["cost_ratio"] == 1.0 and rows[2]["cost_ratio"] == 1.0
    assert res["worst_cost_ratio"] == max(r["cost_ratio"] for r in rows)
    assert any("criterion <= 2" in line for line in lines)


def test_competence_over_time_figure(tmp_path):
    from sagg_lab.competence_figure import plot_competence_over_time
    cfg = {"sagg_learner": {"task_space.lower": [0.0, -150.0], "task_space.upper": [150.0, 150.0]},
           "sagg_sim_bridge": {"arm.total_length": 50.0}}
    goals = [{"position": [10.0 * i, 5.0], "competence": -i / 10, "micro_actions": 100 * i}
             for i in range(10)]
    res = {"strategy": "sagg-riac", "seed": 0, "micro_actions": 1000, "config": cfg, "goals": goals}
    plot_competence_over_time(res, tmp_path / "c.png", windows=4)
    assert (tmp_path / "c.png").stat().st_size > 1000
    with pytest.raises(ValueError, match="no goals"):
        plot_competence_over_time(dict(res, goals=[]), tmp_path / "d.png")
