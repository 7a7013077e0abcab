"""Smoke test of ``sagg bench quality`` at a tiny scale."""
import json

import pytest

from sagg_bringup.cli.cli import main
from sagg_lab.quality import bench_quality, check_context
from sagg_common.params import ConfigError
from sagg_low_level.learner import SCHEMA

CONFIG = "config/arm7_ratio15.yaml"


def test_bench_quality_smoke(tmp_path, capsys, monkeypatch):
    assert main(["bench", "quality", "--config", CONFIG, "--strategies", "sagg-riac", "sagg-random",
                 "--seeds", "2", "--points", "50", "100", "--contexts", "evolving", "--set", "eval.goals=20",
                 # the clamp-vs-clip comparison below was measured with the old evaluation budget
                 # 2·D/v; with the default 5·D/v (docs/notes/evaluation.md) clip misses no more of these
                 # 20 goals than clamp (3 each), only its mean error stays higher
                 "--set", "eval.timeout_factor=2.0", "--out", str(tmp_path)]) == 0
    text = capsys.readouterr().out
    res = json.loads((tmp_path / "quality.json").read_text())
    assert set(res["cells"]) == {f"evolving/{y}/{s}" for y in ("config", "wide")
                                 for s in ("sagg-riac", "sagg-random")}
    cell = res["cells"]["evolving/wide/sagg-riac"]
    assert cell["seeds"] == [0, 1] and set(cell["error"]) == {"50", "100"}
    assert cell["queries_per_second"]["mean"] > 0 and len(cell["error"]["100"]["per_seed"]) == 2
    assert res["task_spaces"]["wide"] == [[-2.0, -2.0], [2.0, 2.0]]
    # SAGG-RIAC vs SAGG-RANDOM, per context, task space and point, with compare's statistics
    assert len(res["tests"]) == 4 and all(0 <= t["mannwhitney_p_less"] <= 1 for t in res["tests"])
    # the analytic-Jacobian reach check: clamping misses fewer goals than the clipped steps
    ana = res["analytic_reach"]
    assert ana["clamp"]["mean"] < ana["clip"]["mean"] and ana["clamp"]["missed"] < ana["clip"]["missed"]
    assert "Y = wide" in text and "queries/s" in text and "Mann-Whitney" in text
    assert 0 <= cell["goals_in_reachable_area"] <= 1 and "goals in the reachable area" in text
    # coverage: the worst test goal is at least as far from the reached tips as the mean one
    assert all(v["coverage_mean"]["mean"] <= v["coverage_max"]["mean"] for v in res["cells"].values())
    assert "nearest reached tip, mean over goals" in text and "nearest reached tip, max over goals" in text
    # SAGG-RANDOM's goals are uniform in Y: in [-2,2]² far fewer of them fall in the reachable area
    assert res["cells"]["evolving/wide/sagg-random"]["goals_in_reachable_area"] < \
        res["cells"]["evolving/config/sagg-random"]["goals_in_reachable_area"]
    # every run's result.json is kept, with where its micro-actions went
    r = json.loads((tmp_path / "evolving/config/sagg-riac/seed-1/result.json").read_text())
    assert r["phases"]["reach"] + r["phases"]["explore"] == 100
    # rerun into the same directory: every finished run is reused, nothing is recomputed
    import sagg_lab.quality as quality

    def no_run(*a, **k):
        raise AssertionError("a finished run was recomputed")
    monkeypatch.setattr(quality, "run_experiment", no_run)
    again = bench_quality(CONFIG, ["sagg-riac", "sagg-random"], 2, [50, 100], contexts=["evolving"],
                          overrides={"eval.goals": 20, "eval.timeout_factor": 2.0}, out_dir=tmp_path,
                          analytic=False, out=lambda *_: None)
    assert again["cells"] == res["cells"]


def test_bench_quality_fixed_context_column():
    """The fixed column goes through the same override as --set context=fixed: a build without
    the learner parameter says so instead of running the evolving context under its name."""
    if any(p.name == "context" for p in SCHEMA):
        check_context(CONFIG, "fixed", None)  # accepted once the parameter exists
    else:
        with pytest.raises(ConfigError, match="context=fixed"):
            bench_quality(CONFIG, ["sagg-riac"], 1, [100], contexts=["evolving", "fixed"], analytic=False,
                          out=lambda *_: None)
