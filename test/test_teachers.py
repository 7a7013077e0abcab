"""Goal strategies as teachers of the goal generator: the registry, alp-gmm (Portelas et
al. 2019) and discretized-progress (explauto) against hand-made competence histories, resume =
uninterrupted run for every teacher, sagg-riac / sagg-random unchanged, bad parameters refused."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sagg_bringup.graph.setups import run_experiment
from sagg_common.params import (ACTUATOR_STRATEGIES, GOAL_STRATEGIES, PAPER_STRATEGIES, STRATEGIES, ConfigError,
                                resolve)
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED
from sagg_goal_generator.alp_gmm import absolute_learning_progress, component_probabilities, fit_mixture
from sagg_goal_generator.checkpoint import GeneratorCheckpointer, teacher_snapshot
from sagg_goal_generator.core import (MODE_GLOBAL, MODE_INITIAL, MODE_LOW_COMPETENCE, MODE_RANDOM, MODE_REGION,
                                      SCHEMA, TEACHERS, GoalGenerator, GoalRecord)
from sagg_goal_generator.discretized_progress import cell_probabilities, cell_progress, grid_shape

Y = {"task_space.lower": [0.0, -1.0], "task_space.upper": [4.0, 1.0]}
FAST_ALP = {"alp_gmm.fit_every": 20, "alp_gmm.bootstrap": 20, "alp_gmm.k_max": 4}


def generator(strategy, **kw):
    return GoalGenerator(resolve(SCHEMA, {"strategy": strategy, **Y, **kw}))


# ------------------------------------------------------------------------------ registry
def test_one_registry_of_strategy_names():
    assert tuple(TEACHERS) == GOAL_STRATEGIES
    assert set(STRATEGIES) == set(GOAL_STRATEGIES) | set(ACTUATOR_STRATEGIES)
    assert not set(GOAL_STRATEGIES) & set(ACTUATOR_STRATEGIES)
    assert STRATEGIES[:4] == PAPER_STRATEGIES  # the benchmarks' default: the paper's four
    with pytest.raises(ConfigError, match="strategy"):
        resolve(SCHEMA, {"strategy": "alp_gmm"})


# ------------------------------------------------------------------------------- alp-gmm
def test_alp_is_the_competence_change_against_the_nearest_earlier_goal():
    past = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [3.0, 3.0], [2.0, 0.0], [0.0, 2.0]])
    comp = np.array([-0.9, -0.8, -0.1, -0.5, -0.3, -0.2])
    # nearest to (1.1, 0.2) is (1, 0), competence -0.8
    assert absolute_learning_progress([1.1, 0.2], -0.3, past, comp, 6) == pytest.approx(0.5)
    # nearest to (2.9, 2.5) is (3, 3): |-0.9 - (-0.5)|
    assert absolute_learning_progress([2.9, 2.5], -0.9, past, comp, 6) == pytest.approx(0.4)
    # fewer earlier goals than min_history: 0
    assert absolute_learning_progress([1.1, 0.2], -0.3, past, comp, 7) == 0.0


def test_teacher_records_each_goals_alp_as_the_formula_says():
    gen = generator("alp-gmm", **{**FAST_ALP, "alp_gmm.min_history": 3})
    rng = np.random.default_rng(3)
    goals, comps = rng.uniform([0, -1], [4, 1], (15, 2)), -rng.uniform(size=15)
    for i, (g, c) in enumerate(zip(goals, comps)):
        gen.report(KIND_REACHED, g + 0.1, 0.0)  # reached points do not enter the history
        gen.report(KIND_GOAL, g, c)
    t = gen.teacher
    assert t.n == 15
    for i in range(15):
        if i < 3:
            want = 0.0
        else:
            j = int(np.argmin(np.linalg.norm(goals[:i] - goals[i], axis=1)))
            want = abs(comps[i] - comps[j])
        assert t.fit_data[i, -1] == pytest.approx(want)
        assert np.array_equal(t.fit_data[i, :2], goals[i])


def test_component_probabilities_are_proportional_to_mean_alp():
    assert np.allclose(component_probabilities([0.3, 0.1, 0.0]), [0.75, 0.25, 0.0])
    assert np.allclose(component_probabilities([0.0, 0.0]), [0.5, 0.5])


def _set_two_components(gen, alp_a, alp_b):
    """Mixture of two tight Gaussians at (1, 0) and (3, 0) with mean ALPs alp_a, alp_b."""
    t = gen.teacher
    t.n = t.p["bootstrap"]
    cov = np.diag([1e-4, 1e-4, 1e-6])
    t.fits = [{"goals": t.n, "weights": np.array([0.5, 0.5]),
               "means": np.array([[1.0, 0.0, alp_a], [3.0, 0.0, alp_b]]), "covariances": np.stack([cov, cov])}]


def test_goal_component_follows_mean_alp_and_the_uniform_share():
    gen = generator("alp-gmm", **{"alp_gmm.random_share": 0.0})
    _set_two_components(gen, 0.3, 0.1)
    n = 4000
    recs = [gen.next_goal() for _ in range(n)]
    assert all(r.mode == MODE_REGION for r in recs)
    near_a = np.mean([abs(r.position[0] - 1.0) < 0.1 for r in recs])
    assert abs(near_a - 0.75) < 4 * math.sqrt(0.75 * 0.25 / n)
    assert all(abs(r.position[0] - 1.0) < 0.1 or abs(r.position[0] - 3.0) < 0.1 for r in recs)
    # the uniform share: random_share of the goals are uniform in Y (mode global)
    gen = generator("alp-gmm", **{"alp_gmm.random_share": 0.2})
    _set_two_components(gen, 0.3, 0.1)
    modes = np.array([gen.next_goal().mode for _ in range(n)])
    assert abs((modes == MODE_GLOBAL).mean() - 0.2) < 4 * math.sqrt(0.2 * 0.8 / n)


def test_bootstrap_goals_are_uniform_then_fits_come_every_fit_every_goals():
    gen = generator("alp-gmm", **FAST_ALP)
    for i in range(19):
        rec = gen.next_goal()
        assert rec.mode == MODE_INITIAL
        gen.report(KIND_GOAL, rec.position, -0.5)
    assert gen.teacher.mixture is None
    for i in range(41):
        gen.report(KIND_GOAL, gen.next_goal().position, -0.5)
    assert [f["goals"] for f in gen.teacher.fits] == [20, 40, 60]
    assert {gen.next_goal().mode for _ in range(200)} == {MODE_REGION, MODE_GLOBAL}


def test_the_mixture_puts_its_highest_alp_component_where_competence_changes():
    rng = np.random.default_rng(0)
    # left cluster: ALP about 0.6; right cluster: ALP about 0.02
    left = np.column_stack([rng.normal(0.5, 0.1, 100), rng.normal(0, 0.1, 100), rng.normal(0.6, 0.02, 100)])
    right = np.column_stack([rng.normal(3.5, 0.1, 100), rng.normal(0, 0.1, 100), rng.normal(0.02, 0.01, 100)])
    w, means, covs = fit_mixture(np.vstack([left, right]), 2, 5, "aic", "full", 1, 7)
    top = int(np.argmax(means[:, -1]))
    assert abs(means[top, 0] - 0.5) < 0.2 and means[top, -1] > 0.5
    assert covs.shape == (len(w), 3, 3) and w.sum() == pytest.approx(1.0)
    w2, _, covs2 = fit_mixture(np.vstack([left, right]), 2, 5, "bic", "diag", 1, 7)
    assert covs2.shape == (len(w2), 3, 3) and np.count_nonzero(covs2[0] - np.diag(np.diag(covs2[0]))) == 0


@pytest.mark.parametrize("bad, match", [
    ({"alp_gmm.bootstrap": 10, "alp_gmm.fit_every": 20}, "alp_gmm.bootstrap"),
    ({"alp_gmm.k_min": 5, "alp_gmm.k_max": 3}, "alp_gmm.k_min"),
    ({"alp_gmm.k_max": 30, "alp_gmm.fit_every": 20, "alp_gmm.bootstrap": 20}, "alp_gmm.k_max"),
])
def test_inconsistent_alp_gmm_parameters_are_refused_by_name(bad, match):
    with pytest.raises(ConfigError, match=match):
        generator("alp-gmm", **bad)
    generator("sagg-riac", **bad)  # read only by alp-gmm


def test_a_grid_too_large_for_memory_is_refused_by_name():
    big = {"discretized_progress.cells": 1_000_000, "discretized_progress.window": 20}
    with pytest.raises(ConfigError, match=r"discretized_progress\.cells x discretized_progress\.window"):
        generator("discretized-progress", **big)
    generator("sagg-riac", **big)  # read only by discretized-progress


@pytest.mark.parametrize("name, value", [
    ("alp_gmm.random_share", 1.5), ("alp_gmm.fit_every", 1), ("alp_gmm.criterion", "aicc"),
    ("alp_gmm.covariance", "tied"), ("alp_gmm.history", 0), ("discretized_progress.random_share", -0.1),
    ("discretized_progress.window", 1), ("discretized_progress.cells", 0), ("discretized_progress.novelty_bonus", 1),
])
def test_out_of_range_teacher_parameters_are_refused_by_name(name, value):
    with pytest.raises(ConfigError, match=name.replace(".", r"\.")):
        resolve(SCHEMA, {name: value})


# ------------------------------------------------------------------- discretized-progress
def test_grid_shape_is_the_floor_of_the_root_of_the_cells():
    assert grid_shape(400, 2) == (20, 20)
    assert grid_shape(400, 3) == (7, 7, 7)
    assert grid_shape(1000, 3) == (10, 10, 10)
    assert grid_shape(3, 2) == (1, 1)


def test_cell_progress_is_older_half_mean_minus_newer_half_mean():
    assert cell_progress(np.array([0, 0, 0, 0, 0, 1, 1, 1, 1, 1.0])) == pytest.approx(-1.0)
    assert cell_progress(np.array([0.2, 0.4, 0.5, 0.9])) == pytest.approx(0.3 - 0.7)
    assert cell_progress(np.array([0.3, 0.6, 0.9])) == pytest.approx(0.3 - 0.75)  # odd: newer half larger
    assert np.allclose(cell_probabilities([-0.2, 0.0, 0.6]), [0.25, 0.0, 0.75])
    assert np.allclose(cell_probabilities([0.0, 0.0]), [0.5, 0.5])


def test_a_cells_window_and_progress_follow_its_goal_reports():
    gen = generator("discretized-progress", **{"discretized_progress.cells": 4, "discretized_progress.window": 4})
    t = gen.teacher
    assert t.shape == (2, 2) and t.cell_of([0.5, -0.5]) == 0 and t.cell_of([3.5, 0.5]) == 3
    assert t.cell_of([4.0, 1.0]) == 3 and t.cell_of([4.1, 0.0]) is None
    comps = [-0.9, -0.6, -0.5, -0.1]  # normalised: 0.1, 0.4, 0.5, 0.9
    for c in comps:
        gen.report(KIND_GOAL, [0.5, -0.5], c)
    assert np.allclose(t.windows[0], [0.1, 0.4, 0.5, 0.9])
    assert t.progress[0] == pytest.approx(0.25 - 0.7)
    assert not t.progress[1:].any()
    # with no uniform share every goal goes to the only cell with progress, uniform in it
    t.p["random_share"] = 0.0
    pos = np.array([gen.next_goal().position for _ in range(500)])
    assert np.all((pos >= [0, -1]) & (pos <= [2, 0]))
    assert abs(pos[:, 0].mean() - 1.0) < 0.1


@pytest.mark.parametrize("dim", [2, 3])
def test_cell_of_is_numpys_flat_index_of_the_bins(dim):
    # cell_of runs on every report in Python floats: numpy's arithmetic is the reference
    lower, upper = np.array([-0.5, -1.0, 0.2][:dim]), np.array([1.0, 1.0, 3.0][:dim])
    gen = GoalGenerator(resolve(SCHEMA, {"strategy": "discretized-progress", "task_space.lower": lower.tolist(),
                                         "task_space.upper": upper.tolist(), "discretized_progress.cells": 300}))
    t = gen.teacher
    rng = np.random.default_rng(3)
    edges = lower + np.arange(t.shape[0] + 1)[:, None] * t.width  # bin faces, the upper face of Y
    ys = np.concatenate([rng.uniform(lower, upper, (2000, dim)), edges, [upper, lower]])
    for y in ys:
        y = np.minimum(np.maximum(y, lower), upper)
        idx = np.minimum(((y - lower) / t.width).astype(int), np.array(t.shape) - 1)
        assert t.cell_of(y) == int(np.ravel_multi_index(tuple(idx), t.shape)), y
    for bad in (upper + 1e-9, lower - 1e-9, np.full(dim, np.nan), np.zeros(dim + 1)):
        assert t.cell_of(bad) is None


def test_novelty_bonus_credits_a_new_cell_once():
    gen = generator("discretized-progress", **{"discretized_progress.cells": 4, "discretized_progress.window": 4})
    t = gen.teacher
    gen.report(KIND_REACHED, [3.5, 0.5], 0.0)
    gen.report(KIND_EXPLORATION, [3.6, 0.6], 0.0)  # no longer new: its window holds the bonus
    assert np.array_equal(t.windows[3], [0, 0, 0, 1.0])
    assert t.progress[3] == pytest.approx(-0.5)
    off = generator("discretized-progress", **{"discretized_progress.cells": 4, "discretized_progress.window": 4,
                                               "discretized_progress.novelty_bonus": False})
    off.report(KIND_REACHED, [3.5, 0.5], 0.0)
    assert not off.teacher.windows.any()


def test_uniform_share_of_discretized_progress():
    gen = generator("discretized-progress", **{"discretized_progress.random_share": 0.3})
    gen.report(KIND_GOAL, [0.1, -0.9], -0.2)  # one cell with progress
    n = 4000
    modes = np.array([gen.next_goal().mode for _ in range(n)])
    assert abs((modes == MODE_GLOBAL).mean() - 0.3) < 4 * math.sqrt(0.3 * 0.7 / n)
    assert set(modes) == {MODE_GLOBAL, MODE_REGION}


# ----------------------------------------------------------------- every teacher: resume
def _competence(y, i):
    """A made-up learner: competence rises over time in the left half of Y, not in the right."""
    return -1.0 + min(1.0, i / 150) if y[0] < 2.0 else -0.5 - 0.3 * math.sin(5 * y[1])


def _events(gen, n_goals):
    """Run ``gen`` on the made-up learner; returns the event stream (goals and reports)."""
    ev = []
    for i in range(n_goals):
        rec = gen.next_goal()
        ev.append(("goal", rec))
        reached = np.clip(rec.position * 0.8 + 0.1, gen.lower, gen.upper)
        for r in ((KIND_REACHED, reached, 0.0), (KIND_EXPLORATION, reached[::-1].copy(), 0.0),
                  (KIND_GOAL, rec.position, _competence(rec.position, i))):
            gen.report(*r)
            ev.append(("report", r))
    return ev


def _same_goals(a, b):
    return [(g.seq, g.mode, g.after_report, g.position.tobytes(), g.competence) for g in a] == \
           [(g.seq, g.mode, g.after_report, g.position.tobytes(), g.competence) for g in b]


@pytest.mark.parametrize("strategy", GOAL_STRATEGIES)
def test_resume_equals_an_uninterrupted_run(tmp_path, strategy):
    kw = {**FAST_ALP, "discretized_progress.cells": 16, "g_max": 10, "seed": 4}
    full = generator(strategy, **kw)
    ev = _events(full, 160)
    # the same run, checkpointed after report 263 (mid-way between two alp-gmm fits), then resumed
    first = generator(strategy, **kw)
    cut = None
    for cut, e in enumerate(ev):
        _apply(first, e)
        if first.reports == 263:
            break
    GeneratorCheckpointer(tmp_path, first, 10**6).save()
    for p in tmp_path.glob("generator_state_*.npz"):
        with np.load(p, allow_pickle=False) as z:  # arrays only: no pickle
            assert all(z[k].dtype != object for k in z.files)
    json.loads((tmp_path / "generator.json").read_text())
    resumed = generator(strategy, **kw)
    assert GeneratorCheckpointer(tmp_path, resumed, 10**6).resume() == []
    assert resumed.reports == 263 and _same_goals(resumed.goals, first.goals)
    for e in ev[cut + 1:]:
        _apply(resumed, e)
    assert _same_goals(resumed.goals, full.goals) and len(full.goals) == 160
    assert resumed.rng.bit_generator.state == full.rng.bit_generator.state
    assert resumed.teacher.snapshot() == full.teacher.snapshot()
    # what `sagg run` draws: the snapshot read back from the checkpoint, read only, is the teacher's own
    assert teacher_snapshot(tmp_path, first.params) == first.teacher.snapshot()
    assert resumed.next_goal().position.tobytes() == full.next_goal().position.tobytes()
    if strategy == "alp-gmm":
        assert len(full.teacher.fits) >= 6 and {g.mode for g in full.goals} >= {MODE_INITIAL, MODE_REGION}


def test_teacher_snapshot_without_or_with_a_broken_checkpoint(tmp_path):
    gen = generator("discretized-progress", **{"discretized_progress.cells": 16})
    assert teacher_snapshot(tmp_path, gen.params) is None  # no checkpoint: no view
    GeneratorCheckpointer(tmp_path, gen, 10**6).save()
    assert teacher_snapshot(tmp_path, gen.params)["teacher"] == "discretized-progress"
    assert teacher_snapshot(tmp_path, generator("sagg-riac").params) is None  # the paper's: no view of its own
    for p in tmp_path.glob("generator_state_*.npz"):
        p.write_bytes(b"not an npz")
    with pytest.raises((OSError, ValueError, KeyError)):  # (what sagg run's summary catches and names)
        teacher_snapshot(tmp_path, gen.params)


def _apply(gen, e) -> bool:
    """Replay one event on ``gen`` (a goal is chosen again and must be the recorded one)."""
    if e[0] == "goal":
        rec = gen.next_goal()
        assert rec.position.tobytes() == e[1].position.tobytes() and rec.mode == e[1].mode
    else:
        gen.report(*e[1])
    return True


# ----------------------------------------------------------- the paper's two: unchanged
def _paper_next_goal(gen):
    """``GoalGenerator.next_goal`` as it was before the teachers (main 5431257), as the oracle."""
    if gen.strategy == "sagg-random":
        y, mode = gen.uniform(gen.lower, gen.upper), MODE_RANDOM
    elif len(gen.tree.leaves()) < 2:
        y, mode = gen.uniform(gen.lower, gen.upper), MODE_INITIAL
    else:
        mode = int(gen.rng.choice(3, p=gen.mode_probs)) + 1
        if mode == MODE_GLOBAL:
            y = gen.uniform(gen.lower, gen.upper)
        else:
            region = gen._region_by_interest()
            y = (gen.uniform(region.lower, region.upper) if mode == MODE_REGION else gen._near_lowest(region))
    rec = GoalRecord(len(gen.goals) + 1, y, mode, gen.reports)
    gen.goals.append(rec)
    return rec


@pytest.mark.parametrize("strategy", ["sagg-riac", "sagg-random"])
def test_sagg_riac_and_sagg_random_draw_what_they_drew_before(strategy):
    kw = {"g_max": 10, "seed": 2}
    now = generator(strategy, **kw)
    ev = _events(now, 300)
    before = generator(strategy, **kw)
    before.next_goal = lambda: _paper_next_goal(before)
    for e in ev:
        _apply(before, e)
    assert _same_goals(before.goals, now.goals)
    assert before.rng.bit_generator.state == now.rng.bit_generator.state
    if strategy == "sagg-riac":
        assert {g.mode for g in now.goals} == {MODE_INITIAL, MODE_REGION, MODE_GLOBAL, MODE_LOW_COMPETENCE}
    assert now.teacher.snapshot() is None


# ------------------------------------------------------------------ in-process, end to end
@pytest.mark.parametrize("strategy", ["alp-gmm", "discretized-progress"])
def test_in_process_run_of_each_teacher(tmp_path, strategy):
    ov = {"arm.dof": 7, "task_space.lower": [0.0, -60.0], "task_space.upper": [60.0, 60.0],
          "alp_gmm.fit_every": 10, "alp_gmm.bootstrap": 10, "alp_gmm.k_max": 3}
    res = run_experiment("config/arm15.yaml", strategy, 1, 1500, 750, tmp_path, progress=False, overrides=ov)
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["strategy"] == strategy and res["final_mean_error"] == data["final_mean_error"]
    assert data["curve"][-1]["mean_error"] < data["curve"][0]["mean_error"]
    modes = {g["mode_name"] for g in data["goals"]}
    assert "region" in modes, modes
    pos = np.array([g["position"] for g in data["goals"]])
    assert np.all((pos >= [0, -60]) & (pos <= [60, 60]))
    t = data["teacher"]
    assert t["teacher"] == strategy
    if strategy == "alp-gmm":
        assert len(t["fits"]) >= 1 and all(abs(sum(f["weights"]) - 1) < 1e-9 for f in t["fits"])
    else:
        assert t["shape"] == [20, 20] and any(t["progress"])


def test_a_mixture_goal_is_numpys_multivariate_normal_draw_for_draw():
    from sagg_goal_generator.alp_gmm import gaussian_draw, sampling_factor
    r = np.random.default_rng(9)
    for i in range(300):
        d = int(r.integers(2, 6))
        a = r.normal(size=(d, d))
        cov, mean = a @ a.T + 1e-3 * np.eye(d), r.normal(size=d)
        assert np.array_equal(gaussian_draw(np.random.default_rng(i), mean, sampling_factor(cov)),
                              np.random.default_rng(i).multivariate_normal(mean, cov))


def test_the_compiled_nearest_goal_is_numpys_argmin():
    from sagg_goal_generator.compiled import em_kernel
    r = np.random.default_rng(10)
    for i in range(500):
        n, d = int(r.integers(1, 300)), int(r.integers(1, 5))
        pts = np.round(r.uniform(-1, 1, (n, d)), 1)          # coarse grid: many ties
        q = np.round(r.uniform(-1, 1, d), 1)
        diff = pts - q
        assert em_kernel.nearest(pts, q) == int(np.argmin(np.einsum("ij,ij->i", diff, diff)))
    with pytest.raises(ValueError):
        em_kernel.nearest(np.zeros((0, 2)), np.zeros(2))
    with pytest.raises(ValueError):
        em_kernel.nearest(np.zeros((3, 2)), np.zeros(3))          # shapes that do not match are refused
    with pytest.raises(ValueError):
        em_kernel.nearest(np.zeros((3, 5)), np.zeros(5))          # (more than 4 dimensions: numpy's own search)
    # the teacher takes numpy's search there
    from sagg_goal_generator.alp_gmm import absolute_learning_progress
    past = r.uniform(size=(50, 6))
    assert absolute_learning_progress(past[3] + 1e-9, 0.5, past, np.arange(50.0), 6) == abs(0.5 - 3.0)
