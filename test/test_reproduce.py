"""``sagg reproduce``: the claim registry, the verdict rules on known inputs, every claim end to end at
smoke scale (claims.json with every field), and resuming after a lost run.

The smoke run is the whole registry at its tiny scale (2 seeds, a few hundred micro-actions or a few
synergy experiments, 6 test goals): a wiring check, never a result.
"""
from __future__ import annotations

import json
import math
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from sagg_bringup.experiments.reproduce import (CLAIM_FIELDS, VERDICTS, claim_verdict, decide, load_registry,
                                    pair_verdict, resolve_config, select, significance_floor)
from sagg_common.params import ConfigError
from installed import SAGG



def test_registry_has_every_claim_of_the_issue_and_valid_setups():
    reg = load_registry()
    exps = reg["experiments"]
    sections = {exps[c["experiment"]]["section"] for c in reg["claims"]}
    assert {"3.8.1", "3.8.2", "3.8.3", "3.9", "3.10", "4.6", "5.3"} <= sections
    arms = {(exps[c["experiment"]]["set"]["arm.dof"], exps[c["experiment"]]["set"]["arm.link_profile"])
            for c in reg["claims"] if exps[c["experiment"]]["section"] == "3.9"}
    assert arms == {(d, p) for d in (7, 15, 30) for p in ("equal", "golden")}
    sizes = sorted(exps[c["experiment"]]["set"]["task_space.upper"][0]
                   for c in reg["claims"] if exps[c["experiment"]]["section"] == "3.8.3")
    assert sizes == [50.0, 150.0, 500.0, 1000.0, 1500.0]
    dof15 = exps["dof15_golden"]["paper"]
    assert dof15["seeds"] >= 15 and dof15["micro_actions"] >= 200_000
    for e in exps.values():
        assert resolve_config(e["config"]).is_file()
    assert [c["id"] for c in select(reg, ["y50"])] == ["y50-sagg-beats-actuator", "y50-riac-beats-random",
                                                       "y50-actuator-random-beats-riac"]
    with pytest.raises(ConfigError, match="no-such-claim"):
        select(reg, ["no-such-claim"])


def test_registry_errors_name_the_claim(tmp_path):
    reg = (Path(__file__).resolve().parents[1] / "src/sagg_bringup/sagg_bringup/experiments/claims.yaml").read_text()
    bad = tmp_path / "claims.yaml"
    bad.write_text(reg.replace("expect: [[sagg-riac, actuator-random]]\n",
                               "expect: [[sagg-riac, sagg-random]]\n", 1))
    with pytest.raises(ConfigError, match="claim 'size-1x': pair"):
        load_registry(bad)


def test_verdict_rules_on_known_inputs():
    assert significance_floor(2, 2) == pytest.approx(1 / 3)
    assert significance_floor(15, 15) == pytest.approx(2 / math.comb(30, 15))
    assert pair_verdict(1.0, 2.0, 0.01, False, 0.05) == "reproduced"
    assert pair_verdict(2.0, 1.0, 0.01, False, 0.05) == "not reproduced"
    assert pair_verdict(1.0, 2.0, 0.2, False, 0.05) == "inconclusive"
    assert pair_verdict(0.6, 0.3, 0.01, True, 0.05) == "reproduced"  # a share: higher is better
    assert pair_verdict(1.0, 2.0, float("nan"), False, 0.05) == "inconclusive"
    ok = {"p": 0.01, "verdict": "reproduced"}
    assert claim_verdict([ok, {"p": 0.03, "verdict": "reproduced"}]) == ("reproduced", 0.03)
    assert claim_verdict([ok, {"p": 0.4, "verdict": "inconclusive"}]) == ("inconclusive", 0.4)
    assert claim_verdict([ok, {"p": 0.02, "verdict": "not reproduced"}]) == ("not reproduced", 0.02)


def test_decide_reads_the_compare_summary():
    low, high = [0.1, 0.2, 0.3, 0.4, 0.5], [1.1, 1.2, 1.3, 1.4, 1.5]
    summ = {"strategies": {"sagg-riac": {"final_mean_error": low, "goal_share_reachable_second_half": high},
                           "actuator-random": {"final_mean_error": high,
                                               "goal_share_reachable_second_half": low}}}
    claim = {"expect": [["sagg-riac", "actuator-random"]], "metric": "final_mean_error",
             "statistic": "mannwhitney_p"}
    d = decide(claim, summ, 0.05)
    assert d["verdict"] == "reproduced"
    assert d["p_value"] == pytest.approx(2 / math.comb(10, 5))  # every A below every B
    assert d["ours"]["strategies"]["sagg-riac"]["mean"] == pytest.approx(0.3)
    d = decide({**claim, "expect": [["actuator-random", "sagg-riac"]]}, summ, 0.05)
    assert d["verdict"] == "not reproduced"
    d = decide({**claim, "metric": "goal_share_reachable_second_half"}, summ, 0.05)
    assert d["verdict"] == "reproduced"  # sagg-riac's share is the higher one
    d = decide({**claim, "statistic": "welch_p"}, summ, 0.05)
    assert d["statistic"] == "welch_p" and d["p_value"] < 1e-4


def reproduce(out: Path, *what: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([str(SAGG), "reproduce", *what, "--scale", "smoke", "--out", str(out),
                           "--workers", "2"], capture_output=True, text=True, timeout=timeout)


def test_smoke_all_writes_every_claim_with_every_field(tmp_path):
    t0 = time.monotonic()
    r = reproduce(tmp_path / "all", "all")
    wall = time.monotonic() - t0
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    rows = json.loads((tmp_path / "all" / "claims.json").read_text())
    reg = load_registry()
    assert [row["id"] for row in rows] == [c["id"] for c in reg["claims"]]
    for row in rows:
        missing = [f for f in CLAIM_FIELDS if f not in row]
        assert not missing, (row["id"], missing)
        assert row["verdict"] in VERDICTS
        assert row["seeds"] == [0, 1]
        strategies = reg["experiments"][row["setup"]["experiment"]]["strategies"]
        assert sorted(row["ours"]["strategies"]) == sorted(strategies), row["id"]
        for s in strategies:
            assert row["ours"]["strategies"][s]["n"] == 2
            assert np.isfinite(row["ours"]["strategies"][s]["mean"])
        # 2 seeds: the smallest two-sided Mann-Whitney p is 1/3, so nothing can be decided
        # (p is NaN when all values tie, e.g. no goal in the second half of 100 micro-actions)
        assert row["verdict"] == "inconclusive" and not row["p_value"] < 1 / 3 - 1e-12
        # the commit the runs computed at, from their result.json files (one commit here)
        assert row["commit"] and not row["commit"].startswith("mixed")
        assert row["run_commits"] == {row["commit"]: 2 * len(strategies)}
        # the evidence next to the verdict: where each strategy's micro-actions went
        mech = row["mechanisms"]
        assert sorted(mech) == sorted(strategies) and all(m["seeds"] == 2 for m in mech.values())
        assert all(0 <= m["explore_share"] <= 1 for m in mech.values()), mech
    report = (tmp_path / "all" / "report.md").read_text()
    assert "| exploration share of micro-actions |" in report
    for row in rows:
        assert f"| {row['id']} |" in report
    for exp in reg["experiments"]:
        assert (tmp_path / "all" / "figures" / f"{exp}_curves.png").stat().st_size > 0
    assert (tmp_path / "all" / "figures" / "quadruped_goals.png").is_file()
    # every curve point carries the evaluation's metrics (defined once, eval_metrics.py)
    res = json.loads(next((tmp_path / "all" / "experiments" / "fishing").rglob("result.json")).read_text())
    assert {"mean_error", "median_error", "within_share", "band_mean_errors"} <= set(res["curve"][-1])
    assert len(res["eval_metrics"]["band_edges"]) == 5
    print(f"smoke wall {wall:.0f} s")


def test_rerun_after_a_lost_run_redoes_only_that_run(tmp_path):
    out = tmp_path / "r"
    r = reproduce(out, "fishing-riac-beats-random")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    files = sorted((out / "experiments" / "fishing" / "runs").rglob("result.json"))
    assert len(files) == 4  # 2 strategies x 2 seeds
    before = {f: f.stat().st_mtime_ns for f in files}
    lost = files[0]
    lost.unlink()  # as if the driver had been killed before this run finished
    # --no-run: an interim verdict on the runs finished so far, nothing run; a run that does not
    # match the settings is left out (not decided on)
    other = next(f for f in files[1:] if f.parts[-2] == lost.parts[-2] and f.parts[-3] != lost.parts[-3])
    kept_text = other.read_text()
    other.write_text(json.dumps({**json.loads(kept_text), "micro_actions": 1}))
    r = reproduce(out, "fishing-riac-beats-random", "--no-run")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "2 not run (--no-run)" in r.stdout and "left out (--no-run)" in r.stdout and not lost.exists()
    row = json.loads((out / "claims.json").read_text())[0]
    seed = int(lost.parts[-2].split("-")[1])
    assert row["seeds"] == [s for s in (0, 1) if s != seed] and row["seeds_planned"] == 2
    assert row["complete"] is False
    assert all(v["n"] == 1 for v in row["ours"]["strategies"].values())  # the bad run is not in
    assert "**interim**" in (out / "report.md").read_text()
    other.write_text(kept_text)
    before[other] = other.stat().st_mtime_ns
    r = reproduce(out, "fishing-riac-beats-random")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "3 finished run(s) kept and skipped, 1 to run" in r.stdout
    assert lost.is_file()
    assert all(f.stat().st_mtime_ns == t for f, t in before.items() if f != lost)
    rows = json.loads((out / "claims.json").read_text())
    assert [row["id"] for row in rows] == ["fishing-riac-beats-random"]
    assert rows[0]["seeds"] == [0, 1] and rows[0]["complete"] is True
    r = reproduce(out, "fishing-riac-beats-random")
    assert "0 to run" in r.stdout


def test_archive_resumes_in_a_new_directory_and_decides_the_same(tmp_path):
    """A session's runs, archived compactly, let another session (a fresh --out) resume without
    rerunning them and decide and draw exactly as from the full results."""
    arch = tmp_path / "archive"
    r = reproduce(tmp_path / "a", "quadruped-riac-best", "--archive", str(arch))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    full = sorted((tmp_path / "a" / "experiments" / "quadruped" / "runs").rglob("result.json"))
    kept = sorted((arch / "smoke" / "quadruped" / "runs").rglob("result.json"))
    assert len(full) == len(kept) == 8 and (arch / "smoke" / "quadruped" / "compare.json").is_file()
    for f, k in zip(full, kept):
        res, small = json.loads(f.read_text()), json.loads(k.read_text())
        assert not {"goals", "regions", "splits"} & set(small)
        assert {key: v for key, v in res.items() if key not in ("goals", "regions", "splits")} == \
            {key: v for key, v in small.items() if key != "goal_histogram"}
        if res["goals"]:  # the histogram counts every goal inside Y
            assert sum(c[2] for c in small["goal_histogram"]["cells"]) == len(res["goals"])
    # a lost run in the new directory: restored from the archive, not rerun
    r = reproduce(tmp_path / "b", "quadruped-riac-best", "--archive", str(arch))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "restored 8 archived run(s)" in r.stdout and "0 to run" in r.stdout
    a, b = (json.loads((tmp_path / d / "claims.json").read_text()) for d in "ab")
    assert [(x["verdict"], x["p_value"], x["ours"]) for x in a] == [(x["verdict"], x["p_value"], x["ours"]) for x in b]
    assert (tmp_path / "b" / "figures" / "quadruped_goals.png").stat().st_size > 0
    # an interim verdict (--no-run) from the archive decides the same and leaves the archive alone
    stamps = {f: f.stat().st_mtime_ns for f in (arch / "smoke" / "quadruped").rglob("*.json")}
    r = reproduce(tmp_path / "d", "quadruped-riac-best", "--archive", str(arch), "--no-run")
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    d = json.loads((tmp_path / "d" / "claims.json").read_text())
    assert [(x["verdict"], x["p_value"], x["ours"]) for x in d] == [(x["verdict"], x["p_value"], x["ours"]) for x in b]
    assert {f: f.stat().st_mtime_ns for f in stamps} == stamps
    # an archived run that does not match the settings is rerun, not trusted
    first = kept[0]
    bad = json.loads(first.read_text())
    bad["micro_actions"] += 1
    first.write_text(json.dumps(bad))
    r = reproduce(tmp_path / "c", "quadruped-riac-best", "--archive", str(arch))
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    assert "rerun" in r.stdout and "1 to run" in r.stdout
    assert json.loads(first.read_text())["micro_actions"] == bad["micro_actions"] - 1  # re-archived


# ------------------------------------------------------------ the evaluation's pieces, known inputs
def test_error_metrics_on_known_inputs():
    from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame
    goals = np.array([[1.0, 0.0], [0.0, 3.0], [5.0, 0.0], [0.0, 10.0], [8.0, 6.0]])  # |g| 1, 3, 5, 10, 10
    f = metric_frame(goals, [0.0, 0.0])
    assert f["radius"] == 10.0 and f["within"] == pytest.approx(0.2)
    assert f["band_edges"] == [0.0, 2.5, 5.0, 7.5, 10.0]
    assert f["band_of_goal"] == [0, 1, 2, 3, 3] and f["band_counts"] == [1, 1, 1, 2]
    m = error_metrics([0.1, 0.3, 0.2, 4.0, 2.0], f)
    assert m["mean_error"] == pytest.approx(1.32) and m["median_error"] == pytest.approx(0.3)
    assert m["within_share"] == pytest.approx(0.4)  # 0.1 and 0.2 are within 0.2
    assert m["band_mean_errors"] == pytest.approx([0.1, 0.3, 0.2, 3.0])
    assert "band_of_goal" not in frame_summary(f)
    f2 = metric_frame(np.array([[0.5, 0.0], [1.0, 0.0]]), [0.0, 0.0])  # bands 0 and 1 hold no goal
    assert error_metrics([1.0, 2.0], f2)["band_mean_errors"] == [None, None, 1.0, 2.0]
    with pytest.raises(ValueError, match="errors"):
        error_metrics([1.0], f)


def test_synergy_test_goals_do_not_follow_the_random_synergy_density():
    """A synergy whose outcome is the mean of many parameters (like the quadruped's 12 amplitudes):
    uniformly random synergies pile up near the centre and almost never reach the edges of the
    reachable set [-1, 1]^2. The goals spread over the estimated reachable set must not."""
    from sagg_low_level.fixed_context import spread_goals
    from sagg_low_level.outcome_set import reachable_outcomes

    def outcome(theta):
        return np.array([theta[:6].mean(), theta[6:].mean()])

    lo, hi = -np.ones(12), np.ones(12)
    random_outcomes = np.array([outcome(t) for t in np.random.default_rng(3).uniform(lo, hi, (4000, 12))])
    far = lambda p: float((np.abs(p).max(axis=1) > 0.5).mean())  # noqa: E731
    uniform_share = 1.0 - 0.5 ** 2  # of a uniform density over [-1, 1]^2
    for seed in (1, 2):
        pool = reachable_outcomes(outcome, lo, hi, 1000, 8, np.random.default_rng(seed))
        old = reachable_outcomes(outcome, lo, hi, 1000, 0, np.random.default_rng(seed))
        goals = spread_goals(pool, 100, np.random.default_rng(7), [-1.0, -1.0], [1.0, 1.0])
        old_goals = spread_goals(old, 100, np.random.default_rng(7), [-1.0, -1.0], [1.0, 1.0])
        # the random-synergy density puts ~6 % of outcomes beyond 0.5; the goals ~ the uniform 75 %
        assert far(random_outcomes) < 0.1
        assert far(goals) > 0.45 > far(old_goals) and far(goals) > 0.6 * uniform_share
        # and the goals reach further out than the random synergies' 99th percentile
        assert np.abs(goals).max() > np.percentile(np.abs(random_outcomes).max(axis=1), 99) + 0.1
        assert np.all(np.abs(pool) <= 1.0)  # only real outcomes: never outside the reachable set


def test_estimate_table_sums_core_hours():
    from sagg_bringup.experiments.reproduce import estimate_table
    rows = [{"experiment": "a", "section": "3.9", "seeds": 15, "micro_actions": 200_000,
             "strategies": {"sagg-riac": {"rate": 2000.0, "core_hours_per_run": 0.5}},
             "core_hours": 7.5},
            {"experiment": "b", "section": "5.3", "seeds": 10, "micro_actions": 10_000,
             "strategies": {"sagg-riac": {"rate": 10.0, "core_hours_per_run": 0.25}},
             "core_hours": 2.5}]
    table = estimate_table(rows)
    assert "| a | 3.9 | 15 × 200,000 | sagg-riac 2,000 | sagg-riac 0.50 | 7.5 |" in table
    assert table.splitlines()[-1] == "| **total** | | | | | **10.0** |"


def test_compare_summary_carries_the_other_metrics():
    from sagg_bringup.experiments.compare import summary_json, summary_markdown

    def run(seed, med, within, bands):
        return {"strategy": "sagg-riac", "seed": seed, "final_mean_error": 1.0,
                "curve": [{"micro_actions": 0, "mean_error": 2.0},
                          {"micro_actions": 100, "mean_error": 1.0, "median_error": med,
                           "within_share": within, "band_mean_errors": bands}],
                "eval_metrics": {"band_edges": [0.0, 1.0, 2.0], "within": 0.04},
                "goal_stats": {"goal_share_reachable_second_half": 0.5, "reachable_share_of_Y": 0.1}}

    rs = [run(0, 0.2, 0.5, [1.0, None]), run(1, 0.4, 0.7, [3.0, None])]
    s = summary_json(rs)["strategies"]["sagg-riac"]
    assert s["final_median_error"] == [0.2, 0.4] and s["mean_of_median_errors"] == pytest.approx(0.3)
    assert s["mean_within_share"] == pytest.approx(0.6)
    assert s["band_mean_errors"] == [2.0, None]
    row = summary_markdown(rs, tests=False).splitlines()[-1]
    assert row.endswith("| 0.300 | 60% (≤ 0.04) | [0, 1]: 2.000, [1, 2]: — |")


# ------------------------------------------------ sensitivity: the paper's open choices varied
def test_sensitivity_registry_has_every_open_choice_at_the_issue_scale():
    from sagg_bringup.experiments.sensitivity import load_sensitivity, variants
    reg = load_registry()
    sens = load_sensitivity(reg)
    assert {c["name"] for c in sens["choices"]} == {
        "rest posture", "eps_sim", "eps_max", "explore_amplitude", "evaluation budget",
        "blocking scope", "reached points"}
    assert reg["experiments"][sens["experiment"]]["section"] == "3.9"
    assert reg["experiments"][sens["experiment"]]["set"]["arm.dof"] == 15
    assert sens["paper"]["seeds"] >= 8 and sens["paper"]["micro_actions"] >= 50_000
    vs = variants(reg)
    assert vs[0]["choice"] == "default" and vs[0]["experiment"]["set"] == reg["experiments"][sens["experiment"]]["set"]
    assert len({v["name"] for v in vs}) == len(vs)  # one directory each
    for v in vs[1:]:  # each variant = the base experiment with exactly its own change
        assert v["experiment"]["set"] == {**vs[0]["experiment"]["set"], **v["set"]}
    with pytest.raises(ConfigError, match="--choice: unknown"):
        variants(reg, ["no such choice"])


def test_sensitivity_strategies_left_out_of_a_choice_do_not_read_it(tmp_path):
    """A choice that names the strategies reading its parameters lets the default's runs stand for
    the others: each of the others, run with each of the choice's values, must give the default's
    memory and errors bit for bit (and a strategy that does read it must not, or the check is blind)."""
    from sagg_bringup.inprocess.experiment import run_arm_experiment
    from sagg_bringup.experiments.sensitivity import load_sensitivity
    reg = load_registry()
    sens = load_sensitivity(reg)
    base = reg["experiments"][sens["experiment"]]
    config = resolve_config(base["config"])
    small = {**base["set"], "eval.goals": 8}

    def run(strategy, extra, name):
        r = run_arm_experiment(config, strategy, 3, 600, 600, tmp_path / name, progress=False,
                               overrides={**small, **extra})
        return r["memory"]["digest"], r["final_errors"]

    declared = [c for c in sens["choices"] if "strategies" in c]
    assert declared, "no choice declares its strategies"
    defaults = {}
    for c in declared:
        left_out = [s for s in base["strategies"] if s not in c["strategies"]]
        for s in left_out:
            defaults.setdefault(s, run(s, {}, f"default-{s}"))
            for i, v in enumerate(c["values"]):
                assert run(s, v["set"], f"{s}-{c['name']}-{i}") == defaults[s], (c["name"], v["label"], s)
    # the check can fail: a strategy that reads a value (SAGG-RIAC and a larger exploration step)
    assert run("sagg-riac", {"explore_amplitude": 0.1}, "reads") != run("sagg-riac", {}, "reads-default")


def test_sensitivity_flips_on_known_inputs():
    from sagg_bringup.experiments.sensitivity import flips
    default = {"verdict": "reproduced", "pairs": [{"a": "x", "b": "y", "verdict": "reproduced"},
                                                  {"a": "x", "b": "z", "verdict": "reproduced"}]}
    same = {"verdict": "reproduced", "pairs": [dict(p) for p in default["pairs"]]}
    other = {"verdict": "not reproduced", "pairs": [{"a": "x", "b": "y", "verdict": "not reproduced"},
                                                    {"a": "x", "b": "z", "verdict": "reproduced"}]}
    assert flips(default, same) == []
    assert flips(default, other) == ["x>y: reproduced → not reproduced",
                                     "claim: reproduced → not reproduced"]


def test_sensitivity_smoke_one_choice_end_to_end(tmp_path):
    out = tmp_path / "s"
    r = subprocess.run([str(SAGG), "reproduce", "sensitivity", "--choice", "reached points", "--scale",
                        "smoke", "--out", str(out), "--workers", "2"], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    from sagg_bringup.experiments.sensitivity import SENSITIVITY_FIELDS
    rows = json.loads((out / "sensitivity.json").read_text())
    assert [(row["choice"], row["overrides"]) for row in rows] == [
        ("default", {}), ("reached points", {"count_reached": True})]
    for row in rows:
        assert set(SENSITIVITY_FIELDS) <= set(row)
        assert row["verdict"] in VERDICTS and row["seeds"] == [0, 1]
    # the variant's runs really ran with its change, the default's without it
    cfg = {row["choice"]: json.loads(next((out / "experiments" / row["experiment"]).rglob("result.json"))
                                     .read_text())["config"]["sagg_goal_generator"]["count_reached"]
           for row in rows}
    assert cfg == {"default": False, "reached points": True}
    # the default ran 4 strategies x 2 seeds; the variant only the two that read count_reached, the
    # default's ACTUATOR runs stand for the others (and are in its decision)
    assert [row["run_commits"] for row in rows] == [{rows[0]["commit"]: 8}, {rows[1]["commit"]: 4}]
    assert rows[1]["reused"] == ["actuator-random", "actuator-riac"] and rows[0]["reused"] == []
    assert rows[1]["strategies"]["actuator-riac"] == rows[0]["strategies"]["actuator-riac"]
    assert not (out / "experiments" / rows[1]["experiment"] / "runs" / "actuator-riac").exists()
    md = (out / "sensitivity.md").read_text()
    assert "| reached points | on (Sec. 3.7" in md and "| default |" in md and "(default's runs)" in md
    assert all(row["complete"] and row["seeds_planned"] == 2 for row in rows)
    assert (out / "sensitivity.png").stat().st_size > 0 and "](sensitivity.png)" in md
    # --no-run: an interim table on the runs finished so far, nothing rerun; a variant missing a
    # seed of one strategy is decided on the seeds all its strategies (reused ones too) have
    lost = out / "experiments" / rows[1]["experiment"] / "runs" / "sagg-random" / "seed-1"
    for f in lost.iterdir():
        f.unlink()
    lost.rmdir()
    r = subprocess.run([str(SAGG), "reproduce", "sensitivity", "--choice", "reached points", "--scale",
                        "smoke", "--out", str(out), "--no-run"], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    interim = json.loads((out / "sensitivity.json").read_text())
    assert [(row["seeds"], row["complete"]) for row in interim] == [([0, 1], True), ([0], False)]
    assert not lost.exists()  # nothing was run
    assert "(interim: 1 of 2 seeds)" in (out / "sensitivity.md").read_text()


def test_run_commits_says_when_an_experiment_spans_several_commits(tmp_path):
    from sagg_bringup.inprocess.results import run_commits
    assert run_commits(tmp_path, "abc") == {"commit": "abc", "run_commits": {}}
    for i, c in enumerate(["c1", "c1", "c2"]):
        (tmp_path / f"r{i}").mkdir()
        (tmp_path / f"r{i}" / "result.json").write_text(json.dumps({"commit": c}))
    assert run_commits(tmp_path, "abc") == {"commit": "mixed: c1, c2", "run_commits": {"c1": 2, "c2": 1}}


def test_mechanisms_average_over_seeds_and_skip_what_a_strategy_lacks():
    from sagg_bringup.experiments.mechanisms import mechanism_table, strategy_mechanisms

    def run(err, share, goals):
        r = {"final_mean_error": err, "curve": [{"median_error": err / 2, "within_share": 0.5}],
             "phases": {"explore_share": share, "reachable_goals": {"share_of_micro_actions": 0.1,
                                                                    "micro_actions_per_goal": 10},
                        "unreachable_goals": {"share_of_micro_actions": 0.9, "micro_actions_per_goal": 90}},
             "coverage": {"median": 0.1, "max": 1.0}}
        if goals is not None:
            r["goal_stats"] = {"goals": goals, "goal_share_reachable": 0.25,
                               "goal_share_reachable_second_half": 0.5}
        return r
    m = strategy_mechanisms({"sagg-riac": [run(1.0, 0.8, 10), run(3.0, 0.6, 20)],
                             "actuator-random": [run(2.0, 0.0, None)]})
    assert m["sagg-riac"]["final_mean_error"] == 2.0 and m["sagg-riac"]["goals"] == 15
    assert m["sagg-riac"]["explore_share"] == pytest.approx(0.7) and m["sagg-riac"]["seeds"] == 2
    assert math.isnan(m["actuator-random"]["goals"])
    table = mechanism_table(m)
    assert "| self-generated goals | 15 | — |" in table
