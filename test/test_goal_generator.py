"""High level of SAGG-RIAC: competence, interest, splits, goal modes (paper Sec. 2.4, 3.5)."""
import numpy as np
import pytest

from sagg_common.competence import competence, gamma, is_reached
from sagg_common.params import resolve
from sagg_common.regions import RegionTree, choose_split, interest, interest_probabilities, split_quality
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED
from sagg_goal_generator.core import (MODE_GLOBAL, MODE_INITIAL, MODE_LOW_COMPETENCE, MODE_RANDOM, MODE_REGION,
                                      SCHEMA, GoalGenerator)


def params(**kw):
    return resolve(SCHEMA, kw)


# ------------------------------------------------------------------------------ competence
def test_competence_normal_case_is_minus_ratio_of_distances():
    # start (0,0), goal (4,0), final (4,1): D(g,f)=1, D(s,g)=4 -> -0.25
    assert competence([4, 0], [4, 1], [0, 0], eps_c=0.1) == pytest.approx(-0.25)


def test_competence_goal_too_close_to_start_is_zero():
    assert competence([0.05, 0], [3, 3], [0, 0], eps_c=0.1) == 0.0


def test_competence_moved_away_is_minus_one():
    # D(g,f) = 5 > D(s,g) = 4
    assert competence([4, 0], [-1, 0], [0, 0], eps_c=0.1) == -1.0


def test_competence_rescaled_variant_weighs_dimensions_by_extent():
    # Sec. 4.3: dims rescaled to [0,1]. Y extents (90, 4pi): an error of 9 in u equals 0.1,
    # start distance of 45 in u equals 0.5 -> C = -0.2; unscaled it would also include phi.
    scale = [90.0, 4 * np.pi]
    c = competence([45, 0], [36, 0], [0, 0], eps_c=1e-6, scale=scale)
    assert c == pytest.approx(-0.2)
    c2 = competence([45, 0], [45, 4 * np.pi * 0.1], [0, 0], eps_c=1e-6, scale=scale)
    assert c2 == pytest.approx(-0.2)


def test_gamma_is_zero_when_reached_and_competence_otherwise():
    assert gamma(-0.01, eps_sim=-0.05) == 0.0 and is_reached(-0.01, -0.05)
    assert gamma(-0.3, eps_sim=-0.05) == -0.3 and not is_reached(-0.3, -0.05)


# ------------------------------------------------------------------------------- interest
def test_interest_on_known_sequence():
    # window 8: older half sums to -4, recent half to 0 -> |−4 − 0| / 8
    vals = np.array([-1, -1, -1, -1, 0, 0, 0, 0], float)
    assert interest(vals, 8) == pytest.approx(0.5)
    # window 4 sees only the last four zeros
    assert interest(vals, 4) == 0.0
    # window 6: older = [-1,-1,0]? no: last 6 = [-1,-1,0,0,0,0] -> older [-1,-1,0] = -2, recent 0
    assert interest(vals, 6) == pytest.approx(2 / 6)


def test_interest_with_fewer_values_than_window_and_odd_window():
    assert interest(np.array([-0.2]), 20) == 0.0
    # 5 values, window 20 -> h = 2: older [-0.4,-0.3], recent [-0.2,-0.1]: |-0.7+0.3|/4
    assert interest(np.array([-0.5, -0.4, -0.3, -0.2, -0.1]), 20) == pytest.approx(0.1)


def test_split_quality_formula():
    left = np.array([-1, -1, 0, 0], float)   # interest |-2 - 0| / 4 = 0.5
    right = np.array([-1, -1, -1], float)    # interest 0
    assert split_quality(left, right, 4) == pytest.approx(4 * 3 * 0.5)


def test_split_chosen_on_constructed_set_separates_interest():
    rng = np.random.default_rng(1)
    # left half x in [0, 1): constant competence (no progress);
    # right half x in [1.2, 2]: competence rising from -1 to 0 (progress); interleaved in time.
    pts, vals = [], []
    for t in range(40):
        pts.append([rng.uniform(0, 1), rng.uniform(0, 1)])
        vals.append(-0.5)
        pts.append([rng.uniform(1.2, 2), rng.uniform(0, 1)])
        vals.append(-1.0 if t < 20 else 0.0)
    pts, vals = np.array(pts), np.array(vals)
    choice = choose_split(pts, vals, n_candidates=300, zeta=80,
                          rng=np.random.default_rng(2))
    assert choice.dim == 0
    assert pts[pts[:, 0] < 1.0, 0].max() < choice.value <= 1.2
    assert (choice.left_count, choice.right_count) == (40, 40)


def test_split_ties_prefer_balanced_split():
    # all values equal: every quality is 0, so the most balanced candidate wins
    pts = np.column_stack([np.arange(100.0), np.zeros(100)])
    choice = choose_split(pts, np.zeros(100), 50, 20,
                          np.random.default_rng(0))
    assert choice.dim == 0 and abs(choice.left_count - 50) <= 5


def test_region_tree_splits_above_g_max_and_keeps_points():
    tree = RegionTree([0, 0], [1, 1], g_max=10, zeta=4, n_candidates=5, rng=np.random.default_rng(0))
    rng = np.random.default_rng(3)
    for i in range(11):
        tree.add(rng.uniform(0, 1, 2), -0.1 * i)
    assert len(tree.leaves()) == 2
    assert sum(r.count for r in tree.leaves()) == 11
    for r in tree.leaves():  # every point lies in its leaf, time order kept
        assert all(r.contains(p) for p in r.filled_points)
        assert np.all(np.diff(r.filled_values) < 0)
    assert tree.add([2.0, 0.5], 0.0) is None  # outside Y is ignored


# ------------------------------------------------------------------------------ generator
def _two_region_generator(**kw):
    gen = GoalGenerator(params(**{"task_space.lower": [0.0, 0.0], "task_space.upper": [10.0, 10.0],
                                  "g_max": 10, **kw}))
    rng = np.random.default_rng(5)
    for i in range(11):
        gen.report(KIND_GOAL, rng.uniform(0, 10, 2), -rng.uniform())
    assert len(gen.tree.leaves()) >= 2
    return gen


def test_initial_phase_is_uniform_until_two_regions():
    gen = GoalGenerator(params(**{"task_space.lower": [0.0, 0.0], "task_space.upper": [10.0, 10.0]}))
    g = [gen.next_goal() for _ in range(200)]
    assert all(x.mode == MODE_INITIAL for x in g)
    pos = np.array([x.position for x in g])
    assert pos.min() >= 0 and pos.max() <= 10 and abs(pos.mean() - 5) < 0.6


def test_mode_frequencies_match_p1_p2_p3():
    gen = _two_region_generator()
    n = 20000
    modes = np.array([gen.next_goal().mode for _ in range(n)])
    tol = 4 * np.sqrt(0.25 / n)
    assert abs((modes == MODE_REGION).mean() - 0.7) < tol
    assert abs((modes == MODE_GLOBAL).mean() - 0.2) < tol
    assert abs((modes == MODE_LOW_COMPETENCE).mean() - 0.1) < tol


def test_region_probability_is_interest_minus_min():
    gen = _two_region_generator()
    for r, it in zip(gen.tree.leaves(), [0.1, 0.3, 0.5] + [0.1] * 10):
        r.interest = it
    k = len(gen.tree.leaves())
    w = np.array(([0.1, 0.3, 0.5] + [0.1] * 10)[:k]) - 0.1
    expected = w / w.sum() if w.sum() > 0 else np.full(k, 1 / k)
    assert np.allclose(gen.region_probabilities(), expected)
    for r in gen.tree.leaves():
        r.interest = 0.2
    assert np.allclose(gen.region_probabilities(), 1 / k)


def test_interest_probabilities_formula():
    """Sec. 2.4.4 mode 1 on known numbers (also ACTUATOR-RIAC's region choice)."""
    assert interest_probabilities(np.array([0.1, 0.3, 0.2])).tolist() == pytest.approx([0.0, 2 / 3, 1 / 3])
    assert interest_probabilities(np.array([0.4, 0.4])).tolist() == [0.5, 0.5]
    assert interest_probabilities(np.array([0.7])).tolist() == [1.0]


def test_mode1_goals_fall_in_the_only_interesting_region():
    gen = _two_region_generator(p1=1.0, p2=0.0, p3=0.0)
    leaves = gen.tree.leaves()
    for r in leaves:
        r.interest = 0.0
    leaves[0].interest = 1.0
    for _ in range(200):
        g = gen.next_goal()
        assert g.mode == MODE_REGION and leaves[0].contains(g.position)


def test_mode3_goals_are_near_the_lowest_competence_point():
    gen = _two_region_generator(p1=0.0, p2=0.0, p3=1.0, mode3_sigma=0.01)
    leaves = gen.tree.leaves()
    for r in leaves:
        r.interest = 0.0
    leaves[-1].interest = 1.0
    worst = leaves[-1].filled_points[np.argmin(leaves[-1].filled_values)]
    extent = leaves[-1].upper - leaves[-1].lower
    for _ in range(100):
        g = gen.next_goal()
        assert g.mode == MODE_LOW_COMPETENCE
        assert np.all(np.abs(g.position - worst) <= 5 * 0.01 * extent + 1e-12)


def test_sagg_random_draws_uniform_goals_in_y():
    gen = _two_region_generator(strategy="sagg-random")
    pos = np.array([gen.next_goal().position for _ in range(4000)])
    assert np.all(pos >= 0) and np.all(pos <= 10)
    hist, _ = np.histogram(pos[:, 0], bins=4, range=(0, 10))
    assert hist.min() > 850 and all(g.mode == MODE_RANDOM for g in gen.goals[-10:])


def test_reached_points_count_only_when_switched_on():
    on = GoalGenerator(params(**{"task_space.lower": [0.0, 0.0], "task_space.upper": [1.0, 1.0]}))
    off = GoalGenerator(params(**{"task_space.lower": [0.0, 0.0], "task_space.upper": [1.0, 1.0],
                                  "count_reached": False}))
    for gen in (on, off):
        gen.report(KIND_REACHED, [0.5, 0.5], 0.0)
        gen.report(KIND_EXPLORATION, [0.4, 0.5], 0.0)
        gen.report(KIND_GOAL, [0.2, 0.5], -0.5)
    assert on.tree.n_added == 3 and off.tree.n_added == 1
    assert on.reports == off.reports == 3


def test_same_seed_same_goals_different_seed_different_goals():
    def goals(seed):
        gen = _two_region_generator(seed=seed)
        return np.array([gen.next_goal().position for _ in range(50)])
    assert np.array_equal(goals(1), goals(1))
    assert not np.array_equal(goals(1), goals(2))


def test_bad_probabilities_are_rejected_with_field_name():
    with pytest.raises(ValueError, match="p1 \\+ p2 \\+ p3"):
        GoalGenerator(params(p1=0.5, p2=0.2, p3=0.1))
    with pytest.raises(ValueError, match="g_max"):
        params(g_max=1)
