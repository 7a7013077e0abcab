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
