"""Fixed-context learner (paper Sec. 4.4, Alg. 4) on analytic maps θ → y."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_common.competence import gamma, is_reached
from sagg_common.params import ConfigError, resolve
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED
from sagg_goal_generator.core import SCHEMA as GEN_SCHEMA, GoalGenerator
from sagg_low_level.fixed_context import (SCHEMA, SYNERGY_SCHEMA, Driver, Execute, FixedContextLearner,
                                          ThetaSpace, evaluate_fixed, exploration_theta, least_spread_set,
                                          local_inverse, set_spread, set_spreads, spread_goals,
                                          synergy_from_params)

A = np.array([[0.8, -0.3, 0.5, 0.2, -0.6, 0.1],
              [0.1, 0.7, -0.4, 0.5, 0.3, -0.2]])


def smooth_map(theta):
    """A smooth, redundant, nonlinear map [0,1]^6 → R^2 (reachable set ≈ [-1.1, 1.1]²)."""
    t = np.asarray(theta, dtype=float) - 0.5
    return A @ t + 0.3 * np.sin(2.0 * t[:2])


def make(strategy="sagg-riac", seed=0, **over):
    common = {"strategy": strategy, "seed": seed, "task_space.lower": [-3.0, -3.0],
              "task_space.upper": [3.0, 3.0]}
    lp = resolve(SCHEMA, {**common, **over})
    gen = GoalGenerator(resolve(GEN_SCHEMA, {**common, "g_max": 30}))
    learner = FixedContextLearner(lp, ThetaSpace(np.zeros(6), np.ones(6)))
    learner.on_report = lambda r: gen.report(r.kind, r.target, r.competence)

    def next_goal():
        g = gen.next_goal()
        return g.seq, g.position

    driver = Driver(learner, lambda th, kind: smooth_map(th), next_goal, smooth_map(np.full(6, 0.5)))
    return learner, driver


def make_goals():
    rng = np.random.default_rng(123)
    return np.array([smooth_map(rng.uniform(0, 1, 6)) for _ in range(60)])


def test_local_inverse_is_exact_on_a_linear_map():
    rng = np.random.default_rng(0)
    jac = rng.normal(size=(3, 8))
    theta = rng.uniform(0, 1, (12, 8))
    y = theta @ jac.T + 0.7
    goal = np.array([0.3, -0.2, 1.1])
    th = local_inverse(theta, y, goal, 1e-12, 1e-12)
    np.testing.assert_allclose(jac @ th + 0.7, goal, atol=1e-9)


def test_least_spread_set_picks_the_compact_neighbourhood():
    rng = np.random.default_rng(1)
    theta = np.concatenate([rng.uniform(0, 1, (10, 4)), 0.5 + 0.01 * rng.normal(size=(10, 4))])
    wide, tight = np.arange(10), np.arange(10, 20)
    assert set_spread(theta[tight]) < 0.05 < set_spread(theta[wide])
    assert least_spread_set([wide, tight, wide], theta) == 1


def test_exploration_noise_scales_with_distance():
    rng = np.random.default_rng(2)
    centre = np.full(24, 0.5)
    draws = np.array([exploration_theta(centre, 0.2, 0.5, rng) for _ in range(2000)])
    assert np.all(np.abs(draws - centre) <= 0.5 * 0.2 + 1e-12)
    assert np.abs(draws - centre).max() > 0.09          # fills [-λD, λD]
    np.testing.assert_array_equal(exploration_theta(centre, 0.0, 0.5, rng), centre)


def test_optimiser_converges_on_an_analytic_map():
    goals = make_goals()
    learner, driver = make("sagg-riac")
    start = evaluate_fixed(learner, smooth_map, goals).mean()
    errors = []
    for n in (200, 600, 1200):
        driver.step_until(n)
        errors.append(evaluate_fixed(learner, smooth_map, goals).mean())
    assert start > 0.4
    # measured: 0.57 -> 0.053 / 0.044 at 600 / 1200 experiments
    assert errors[-1] < 0.12 * start, (start, errors)
    assert errors[-1] < 0.08
    assert learner.exploration_phases > 0 and learner.goals_done > 20


def test_repeated_attempts_at_one_goal_get_closer():
    common = {"strategy": "sagg-random", "seed": 3, "task_space.lower": [-3.0, -3.0],
              "task_space.upper": [3.0, 3.0], "min_samples": 1000}  # no inverse: exploration only
    learner = FixedContextLearner(resolve(SCHEMA, common), ThetaSpace(np.zeros(6), np.ones(6)))
    goal = smooth_map(np.array([0.9, 0.1, 0.8, 0.7, 0.2, 0.5]))
    driver = Driver(learner, lambda th, kind: smooth_map(th), lambda: (1, goal), smooth_map(np.full(6, 0.5)))
    first = None
    for n in (11, 110, 440):
        driver.step_until(n)
        d = float(np.linalg.norm(learner.outcomes[learner.closest(goal)] - goal))
        first = d if first is None else first
    assert d < 0.25 * first and d < 0.05, (first, d)


@pytest.mark.parametrize("strategy", ["sagg-random", "actuator-random", "actuator-riac"])
def test_every_strategy_learns(strategy):
    goals = make_goals()
    learner, driver = make(strategy)
    start = evaluate_fixed(learner, smooth_map, goals).mean()
    driver.step_until(400)
    end = evaluate_fixed(learner, smooth_map, goals).mean()
    assert end < 0.3 * start, (strategy, start, end)
    if strategy == "actuator-riac":
        assert len(learner.riac_tree.leaves()) > 1


def test_same_seed_same_samples_other_seed_differs():
    a, da = make("sagg-riac", seed=5)
    b, db = make("sagg-riac", seed=5)
    c, dc = make("sagg-riac", seed=6)
    for d in (da, db, dc):
        d.step_until(150)
    assert a.by_theta.digest() == b.by_theta.digest()
    assert a.by_theta.digest() != c.by_theta.digest()


def test_trials_without_outcome_are_discarded_and_counted():
    common = {"strategy": "actuator-random", "task_space.lower": [-3.0, -3.0], "task_space.upper": [3.0, 3.0]}
    learner = FixedContextLearner(resolve(SCHEMA, common), ThetaSpace(np.zeros(6), np.ones(6)))
    # no outcome when θ_0 > 0.5 (like a cast that misses the water)
    driver = Driver(learner, lambda th, kind: None if th[0] > 0.5 else smooth_map(th), None, np.zeros(2))
    driver.step_until(100)
    assert learner.experiments == len(learner) == 100
    assert learner.discarded == learner.trials - 100 > 20
    assert np.all(learner.thetas[:, 0] <= 0.5)


def test_coroutine_protocol_first_requests():
    lp = resolve(SCHEMA, {"strategy": "sagg-riac", "task_space.lower": [-1.0, -1.0],
                          "task_space.upper": [1.0, 1.0]})
    learner = FixedContextLearner(lp, ThetaSpace(np.zeros(3), np.ones(3)))
    coro = learner.run()
    next(coro)
    goal_req = coro.send(np.zeros(2))
    assert goal_req.after_report == 0
    ex = coro.send((1, np.array([0.5, 0.5])))
    assert isinstance(ex, Execute) and ex.kind == "reach" and ex.theta.shape == (3,)
    assert np.all((ex.theta >= 0) & (ex.theta <= 1))


def test_bad_input_names_the_field():
    with pytest.raises(ValueError, match="theta bounds"):
        ThetaSpace([0.0, 1.0], [1.0, 1.0])
    p = resolve(SYNERGY_SCHEMA, {"synergy.amplitude_max": [0.1] * 3})
    with pytest.raises(ConfigError, match="synergy.amplitude_max"):
        synergy_from_params(p)
    with pytest.raises(ConfigError, match="lambda"):
        resolve(SCHEMA, {"lambda": 0.0})


def test_spread_goals_cover_rare_areas():
    rng = np.random.default_rng(0)
    # 990 outcomes in one corner, 10 in the other: uniform sampling would almost never pick the rare ones
    pts = np.concatenate([rng.uniform(0, 0.1, (990, 2)), rng.uniform(0.9, 1.0, (10, 2))])
    goals = spread_goals(pts, 20, np.random.default_rng(1), [-1, -1], [2, 2])
    assert goals.shape == (20, 2)
    assert (goals[:, 0] > 0.5).sum() >= 5
    assert all(any(np.array_equal(g, p) for p in pts) for g in goals)
    with pytest.raises(ValueError, match="eval.pool"):
        spread_goals(pts + 10, 5, rng, [-1, -1], [2, 2])


def _recorded(over, n=600, seed=0):
    """A SAGG-RANDOM run on smooth_map with every report recorded: (learner, reports)."""
    reports = []
    learner, driver = make("sagg-random", seed=seed, **over)
    forward = learner.on_report

    def keep(r):
        reports.append(r)
        forward(r)

    learner.on_report = keep
    driver.step_until(n)
    return learner, reports


def _per_goal(reports):
    """Reports grouped by goal, in order, the goal's own report last."""
    out: dict[int, list] = {}
    for r in reports:
        out.setdefault(r.goal_seq, []).append(r)
    return [rs for rs in out.values() if rs[-1].kind == KIND_GOAL]


def test_outcome_competence_goal_is_the_outcomes_competence_toward_the_goal():
    """'goal' (Alg. 4: Γ_{y_i}): each reach / exploration outcome is reported at y_i with
    Γ(C(y_g, y_i)); 'maximal' (Sec. 2.5): with 0."""
    for mode in ("goal", "maximal"):
        learner, reports = _recorded({"outcome_competence": mode}, n=300)
        seen_negative = False
        for rs in _per_goal(reports):
            goal = rs[-1].target
            for r in rs[:-1]:
                assert r.kind in (KIND_REACHED, KIND_EXPLORATION)
                np.testing.assert_array_equal(r.target, r.reached)  # recorded where it landed
                want = gamma(learner.competence_of(goal, r.reached), learner.p["eps_sim"])
                assert r.competence == (want if mode == "goal" else 0.0)
                seen_negative |= r.competence < 0
        assert seen_negative == (mode == "goal")


def test_stop_when_reached_ends_the_exploration_at_the_first_reaching_experiment():
    """True (Sec. 2.4.1): no experiment of a goal follows one that reached it; False (default, Alg. 4
    literally): the q experiments run on after a reaching one, and the goals cost more. No inverse
    model (min_samples), so the reaches are random and the explorations do the reaching."""
    costs = {}
    for stop in (True, False):
        learner, reports = _recorded({"stop_when_reached": stop, "eps_sim": -0.2, "min_samples": 10_000})
        after_reached = 0
        for rs in _per_goal(reports):
            goal = rs[-1].target
            hit = [is_reached(learner.competence_of(goal, r.reached), -0.2) for r in rs[:-1]]
            after_reached += sum(1 for i, h in enumerate(hit) if any(hit[:i]))
        assert (after_reached == 0) == stop, (stop, after_reached)
        costs[stop] = learner.experiments / learner.goals_done
        assert learner.goals_reached > 0
    assert costs[True] < costs[False]


def test_blocking_w_stops_after_w_experiments_without_progress():
    """blocking_w = w (Sec. 3.7.6 in Alg. 4): an exploration phase ends after w consecutive
    experiments that do not beat the best so far, and the goal counts as blocked; 0: q experiments."""
    for w in (0, 2):
        learner, reports = _recorded({"blocking_w": w, "q": 12, "stop_when_reached": False,
                                      "min_samples": 50})
        lengths = []
        for rs in _per_goal(reports):
            explore = [r for r in rs if r.kind == KIND_EXPLORATION]
            if not explore:
                continue
            goal = rs[-1].target
            lengths.append(len(explore))
            # the phase starts from the closest outcome known before it: the best so far
            best = min(learner.distance(goal, r.reached) for r in rs if r.kind == KIND_REACHED)
            prior = learner.outcomes[: explore[0].micro_actions - 1]
            best = min(best, *(learner.distance(goal, y) for y in prior)) if len(prior) else best
            idle = 0
            for r in explore:
                d = learner.distance(goal, r.reached)
                idle = 0 if d < best else idle + 1
                best = min(best, d)
                if w:
                    assert idle <= w
            if w and len(explore) < 12:
                assert idle == w  # stopped by the blocking test, nothing else
        if w:
            assert learner.goals_blocked > 0 and min(lengths) == w
        else:
            assert learner.goals_blocked == 0 and set(lengths) == {12}


def test_explore_length_measures_the_exploration_distance_whatever_the_box():
    """explore_length L > 0: the exploration noise's D is the task-unit distance / L, the same for
    any box Y; 0: the competence's units, which scale with the box (rescaled)."""
    goal, y = np.array([0.3, -0.4]), np.array([0.0, 0.0])
    for box in (3.0, 6.0):
        over = {"task_space.lower": [-box, -box], "task_space.upper": [box, box]}
        fixed = FixedContextLearner(resolve(SCHEMA, {**over, "explore_length": 2.0}),
                                    ThetaSpace(np.zeros(6), np.ones(6)))
        assert fixed.explore_distance(goal, y) == pytest.approx(0.25)
        rescaled = FixedContextLearner(resolve(SCHEMA, over), ThetaSpace(np.zeros(6), np.ones(6)))
        assert rescaled.explore_distance(goal, y) == pytest.approx(0.5 / (2 * box))
    # in a run: an exploratory θ's distance (max-norm, normalised θ) to the nearest stored θ (its
    # θ_k among them) is at most λ·D/L; measured mean 0.079 with L = 4, 0.30 with L = 0.25 (clipped)
    mean_step = {}
    for length in (4.0, 0.25):
        learner, driver = make("sagg-random", seed=2, explore_length=length, min_samples=20, blocking_w=0)
        steps = []
        base_execute = driver.execute

        def execute(th, kind, steps=steps, learner=learner):
            if kind == "explore":
                stored = learner.norm_theta(learner.thetas)
                steps.append(np.abs(stored - learner.norm_theta(th)).max(axis=1).min())
            return base_execute(th, kind)

        driver.execute = execute
        driver.step_until(300)
        mean_step[length] = float(np.mean(steps))
        assert max(steps) <= 0.5 * 6.0 / length + 1e-12  # D < 6, the diagonal of the reachable set
    assert mean_step[4.0] < 0.12 and mean_step[0.25] > 2.5 * mean_step[4.0], mean_step


def test_least_spread_set_in_one_call_equals_per_set_spreads():
    rng = np.random.default_rng(4)
    theta = rng.uniform(0, 1, (200, 7))
    for _ in range(50):
        sets = [rng.choice(200, 16, replace=False) for _ in range(10)]
        want = int(np.argmin([set_spread(theta[s]) for s in sets]))
        assert least_spread_set(sets, theta) == want
        assert least_spread_set(np.array(sets), theta) == want  # the sets as rows of one array
    # ties go to the first set, as argmin over the list did
    s = rng.choice(200, 16, replace=False)
    assert least_spread_set([s, s.copy(), s[::-1].copy()], theta) == 0


def test_set_spreads_equal_numpy_var_and_mean_bit_for_bit():
    rng = np.random.default_rng(5)
    for shape in [(10, 16, 7), (1, 2, 1), (3, 9, 24), (10, 33, 4)]:
        stacked = rng.uniform(0, 1, shape) ** 3
        want = np.sqrt(np.mean(np.var(stacked, axis=1), axis=1))
        np.testing.assert_array_equal(set_spreads(stacked), want)


def test_competence_toward_a_goal_equals_competence():
    from sagg_common.competence import competence, competence_toward
    rng = np.random.default_rng(6)
    for scale in (None, np.array([2.0, 0.5])):
        for _ in range(200):
            goal, start = rng.normal(size=2), rng.normal(size=2) * rng.choice([1.0, 1e-3])
            of = competence_toward(goal, start, 0.01, scale)
            for y in rng.normal(size=(5, 2)):
                assert of(y) == competence(goal, y, start, 0.01, scale)


def test_the_learners_searches_are_the_memory_search_while_it_learns():
    """Every query of the learner's two TreeKnn indexes (θ sets, the goal's outcome neighbours,
    ACTUATOR-RIAC's predictor) during learning = SampleMemory's exact search over the same samples."""
    from sagg_low_level.memory import SampleMemory
    from sagg_low_level.tree_knn import TreeKnn

    for strategy in ("sagg-riac", "actuator-riac"):
        learner, driver = make(strategy, seed=2)
        refs = {id(learner.theta_index): SampleMemory(6, 1, 1), id(learner.y_index): SampleMemory(2, 1, 1)}
        asked = []
        query = TreeKnn.query

        def checked(index, queries, k, query=query, refs=refs, asked=asked):
            got = query(index, queries, k)
            ref, table = refs[id(index)], index.memory
            for a in table.alpha[len(ref):]:
                ref.add(a, [0.0], [0.0])
            want = np.array([ref.neighbours(q, k) for q in queries]).reshape(got.shape)
            np.testing.assert_array_equal(got, want)
            asked.append(len(queries))
            return got

        for index in (learner.theta_index, learner.y_index):
            index.query = checked.__get__(index)
        driver.step_until(700)
        assert sum(asked) > 600  # many queries checked, on a memory that outgrew several tree builds
