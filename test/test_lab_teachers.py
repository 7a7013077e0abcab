"""The issue-27 lab tools: the interest's anatomy (shuffled windows, what the tree took, the
near-rest shares) and the teachers' cost per goal, on tiny budgets."""
import numpy as np
import pytest

from sagg_common.regions import interest
from sagg_lab import interest_anatomy, teacher_cost


def test_shuffled_interest_keeps_the_spread_and_loses_the_trend():
    rng = np.random.default_rng(0)
    ramp = np.linspace(-1.0, 0.0, 20)  # competence rising steadily: progress
    assert interest(ramp, 20) > 2 * interest_anatomy.shuffled_interest(ramp, 20, 200, rng)
    assert interest_anatomy.shuffled_interest(np.full(20, -0.4), 20, 50, rng) == 0.0  # no spread, no interest
    mixed = np.where(np.arange(20) % 2 == 0, 0.0, -1.0)  # a spread without trend: interest 0 in this order
    assert interest(mixed, 20) == 0.0 < interest_anatomy.shuffled_interest(mixed, 20, 200, rng)


def test_variants_parse_strategy_and_overrides():
    assert interest_anatomy.parse_variant("sagg-riac") == ("sagg-riac", {})
    assert interest_anatomy.parse_variant("sagg-riac:count_reached=false,g_max=30") == \
        ("sagg-riac", {"count_reached": False, "g_max": 30})


def test_anatomy_logs_what_the_tree_took_and_shares_add_up():
    on = interest_anatomy.anatomy("config/arm8.yaml", "sagg-riac", {}, 0, 1500, 10.0, 2, 5)
    off = interest_anatomy.anatomy("config/arm8.yaml", "sagg-riac", {"count_reached": False}, 0, 1500, 10.0, 2, 5)
    assert np.allclose(on["rest_tip"], off["rest_tip"]) and on["rows"] and off["rows"]
    for r in on["rows"] + off["rows"]:
        assert 0.0 <= r["mass_near"] <= 1.0 and 0.0 <= r["area_near"] <= 1.0 and r["leaves"] >= 2
    # without count_reached the tree takes no reached point: its windows hold goals and subgoals only
    assert all(r["zeros_far"] == 0.0 or np.isnan(r["zeros_far"]) for r in off["rows"])
    assert max(r["zeros_far"] for r in on["rows"]) > 0.5
    assert len(on["goal_log"]) == on["goals"] > 10


@pytest.mark.parametrize("strategy", ["sagg-random", "discretized-progress"])
def test_teacher_cost_times_the_teacher_apart_from_the_tree(strategy):
    r = teacher_cost.teacher_cost("config/arm8.yaml", strategy, 0, 800, {})
    assert r["goals"] > 0 and r["micro_actions_per_goal"] == pytest.approx(800 / r["goals"])
    assert 0.0 < r["share"] < 1.0 and 0.0 < r["tree_share"] < 1.0 and r["share"] + r["tree_share"] < 1.0
    assert "| " + strategy + " |" in teacher_cost.table([r])


def test_teachers_table_marks_what_beats_the_baseline(tmp_path):
    import json
    from sagg_lab import teachers_table
    finals = {"sagg-random": [1.0, 1.1, 1.2, 1.3, 1.4], "alp-gmm": [0.1, 0.2, 0.3, 0.4, 0.5],
              "discretized-progress": [1.05, 1.15, 1.25, 1.35, 1.45]}
    for strategy, errors in finals.items():
        for seed, e in enumerate(errors):  # (the baseline's runs in a directory of their own)
            d = tmp_path / ("base" if strategy == "sagg-random" else "cmp") / strategy / f"seed-{seed}"
            d.mkdir(parents=True)
            curve = [{"micro_actions": 0, "mean_error": 2.0}, {"micro_actions": 100, "mean_error": e}]
            (d / "result.json").write_text(json.dumps({"strategy": strategy, "seed": seed, "final_mean_error": e,
                                                       "curve": curve}))
    assert teachers_table.main(["--out", str(tmp_path / "t"), f"toy={tmp_path / 'cmp'},{tmp_path / 'base'}"]) == 0
    row = [line for line in (tmp_path / "t" / "teachers.md").read_text().splitlines()
           if line.startswith("| toy | 5")][0]
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[1] == "5 × 100" and cells[2] == "1.2 ± 0.16"  # columns: sagg-random (baseline), alp-gmm, d-p
    assert cells[3].startswith("0.3 ± 0.16") and cells[3].endswith("**better**")  # every alp-gmm seed lower
    assert "**" not in cells[4] and "p 0.69" in cells[4]  # discretized-progress: not different
    assert (tmp_path / "t" / "teachers_curves.png").stat().st_size > 5000


def test_interest_on_reachable_reads_each_teachers_snapshot():
    from sagg_bringup.inprocess.experiment import load_arm_config
    from sagg_lab.teachers_table import interest_on_reachable
    config = load_arm_config("config/arm8.yaml")  # Y = [0,100] x [-60,60]; reachable: the half-disk of radius 50
    grid = {"teacher": "discretized-progress", "shape": [2, 2], "lower": [0.0, -60.0], "upper": [100.0, 60.0],
            "progress": [0.3, -0.1, 0.6, 0.0], "competence": [1.0, 0.8, 0.0, 0.2]}  # cells at x 25 reachable, x 75 not
    r = interest_on_reachable({"config": config, "teacher": grid})
    assert r == pytest.approx({"share": 0.4, "competence_inside": 0.9, "competence_outside": 0.1})
    fits = [{"means": [[80.0, 0.0, 1.0]]},  # (first half: the choice right after the bootstrap, left out)
            {"means": [[25.0, 0.0, 0.3], [80.0, 40.0, 0.1]]}, {"means": [[25.0, 0.0, 0.0], [80.0, 40.0, 0.0]]}]
    r = interest_on_reachable({"config": config, "teacher": {"teacher": "alp-gmm", "fits": fits}})
    assert r["share"] == pytest.approx((0.75 + 0.5) / 2) and r["fits"] == 3  # all-zero ALP: uniform
    assert interest_on_reachable({"config": config, "teacher": None}) is None
