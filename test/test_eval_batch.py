"""The batched evaluation (all test goals reached together) gives the per-goal evaluation's floats,
bit for bit, on several set-ups; its parts (batch neighbour search, stacked pseudo-inverse) too."""
import numpy as np
import pytest

from sagg_bringup.inprocess.arm_eval import eval_arms, evaluate_arm
from sagg_bringup.graph.setups import in_process_run
from sagg_low_level import compiled
from sagg_low_level.evaluate import evaluate, evaluate_batch, evaluate_per_goal
from sagg_low_level.memory import SampleMemory
from sagg_low_level.memory_batch import neighbours_many
from sagg_low_level.reach_batch import reach_steps
from sagg_sim_bridge.arm import ArmSim, reachable_area, test_goals

# (config, overrides, learning micro-actions): arm set-ups whose evaluations differ in kind
SETUPS = [
    ("config/arm15.yaml", {"strategy": "sagg-riac"}, 1500),             # 15 DOF, kinematic, clamp
    ("config/arm7_ratio15.yaml", {"strategy": "actuator-random"}, 1500),  # 7 DOF, small units
    ("config/arm15.yaml", {"strategy": "sagg-random", "reach_limits": "clip"}, 1000),
    ("config/arm8.yaml", {"strategy": "sagg-riac"}, 600),               # dynamic, motor noise 0.2
    ("config/arm7_ratio15.yaml", {"strategy": "sagg-riac", "reach_damping": 1.0,  # damped inverse
                                  "arm.rest_shape": "zigzag"}, 1500),
]


def _run_and_goals(cfg, ov, n, goals=40):
    run = in_process_run(cfg, dict(ov, **{"eval.goals": goals}))
    lp = run.config["sagg_learner"]
    area = reachable_area(run.spec, lp["task_space.lower"], lp["task_space.upper"], seed=lp["eval.seed"])
    g = test_goals(run.spec, lp["task_space.lower"], lp["task_space.upper"], n=lp["eval.goals"],
                   seed=lp["eval.seed"], area=area)
    run.step_until(n)
    return run, g


@pytest.mark.parametrize("cfg,ov,n", SETUPS)
def test_batched_evaluation_equals_per_goal(cfg, ov, n):
    run, goals = _run_and_goals(cfg, ov, n)
    digest = run.learner.memory.digest()
    per_goal = evaluate_per_goal(run.learner, eval_arms(run.spec, run.seed, len(goals)), goals)
    batched = evaluate_batch(run.learner, eval_arms(run.spec, run.seed, len(goals)), goals)
    assert batched.tobytes() == per_goal.tobytes(), np.abs(batched - per_goal).max()
    assert run.learner.memory.digest() == digest  # the model stays frozen
    assert np.array_equal(run.evaluate(goals), batched)
    if run.spec.motor_noise == 0:  # noise-free: the same as one simulator reaching goal after goal
        single = evaluate(run.learner, ArmSim(run.spec, seed=7), goals)
        assert single.tobytes() == batched.tobytes()
    # the reaches did something: not every goal ended where it started
    start = np.linalg.norm(goals - ArmSim(run.spec, seed=0).reset()[1], axis=1)
    assert np.any(batched < start - 1e-9)


def test_noisy_goal_noise_does_not_depend_on_other_goals():
    run, goals = _run_and_goals("config/arm8.yaml", {"strategy": "sagg-riac"}, 600, goals=12)
    all_goals = evaluate_arm(run.learner, run.spec, run.seed, goals)
    last_alone = evaluate_arm(run.learner, run.spec, run.seed, goals[:12])[11]
    assert all_goals[11] == last_alone
    # the noise is there: another run seed gives other errors on the same frozen model
    assert not np.array_equal(evaluate_arm(run.learner, run.spec, run.seed + 1, goals), all_goals)


def test_neighbours_many_matches_single_queries():
    rng = np.random.default_rng(3)
    mem = SampleMemory(6, 6, 2, buffer_size=64, checks=4)
    rest = np.full(6, 0.3)
    a = rest.copy()
    for t in range(3000):  # trajectories from a rest posture, as the learner stores them
        a = rest.copy() if t % 40 == 0 else a + rng.normal(0, 0.05, 6)
        mem.add(a, rng.normal(0, 0.05, 6), rng.normal(0, 1, 2))
    q = np.vstack([mem.alpha[rng.integers(0, len(mem), 150)] + rng.normal(0, 0.02, (150, 6)),
                   np.tile(rest, (5, 1)), mem.alpha[-7:], rng.normal(0.3, 1.0, (20, 6))])
    for k in (1, 12, 40):
        want = np.stack([mem.neighbours(x, k) for x in q])
        assert np.array_equal(neighbours_many(mem, q, k), want)
    assert np.array_equal(neighbours_many(mem, q[:3], 5000), np.stack([mem.neighbours(x, 5000) for x in q[:3]]))
    exact = SampleMemory(6, 6, 2, buffer_size=64)
    for a in mem.alpha[:500]:
        exact.add(a, np.zeros(6), np.zeros(2))
    assert np.array_equal(neighbours_many(exact, q, 9), np.stack([exact.neighbours(x, 9) for x in q]))
    with pytest.raises(ValueError):
        neighbours_many(mem, q[:, :5], 3)


def test_reach_steps_match_reach_step_rows():
    run, _ = _run_and_goals("config/arm15.yaml", {"strategy": "actuator-random"}, 1200)
    learner = run.learner
    rng = np.random.default_rng(0)
    alphas = learner.memory.alpha[rng.integers(0, len(learner.memory), 60)]
    alphas = np.clip(alphas + rng.normal(0, 0.3, alphas.shape), learner.robot.lower, learner.robot.upper)
    alphas[::2] = np.where(rng.random((30, alphas.shape[1])) < 0.3, learner.robot.upper, alphas[::2])
    dys = rng.normal(0, 2.0, (60, 2))
    got = reach_steps(learner, alphas, dys)
    want = np.stack([learner.reach_step(a, d) for a, d in zip(alphas, dys)])
    assert got.tobytes() == want.tobytes()
    # some rows hit a joint limit (the clamped re-solve), others not
    lo, up, rcond = learner.robot.lower, learner.robot.upper, learner.p["pinv_rcond"]
    plain = np.stack([compiled.reach_step(learner.jacobian_at(a), d, a, lo, up, rcond, learner.damping, False)
                      for a, d in zip(alphas, dys)])
    differs = np.any(plain != want, axis=1)
    assert differs.any() and not differs.all()


def test_reach_steps_posture_cache_gives_the_same_rows_without_searching(monkeypatch):
    """Postures met again (in one call or a later one with the same cache) take their Jacobian from
    the cache: the same rows as reach_step, and no neighbour search for them."""
    import sagg_low_level.reach_batch as rb
    run, _ = _run_and_goals("config/arm7_ratio15.yaml", {"strategy": "actuator-random"}, 1200)
    learner = run.learner
    rng = np.random.default_rng(2)
    alphas = learner.memory.alpha[rng.integers(0, len(learner.memory), 20)] + rng.normal(0, 0.05, (20, 7))
    alphas = np.clip(alphas, learner.robot.lower, learner.robot.upper)
    alphas[10:] = alphas[:10]  # every posture twice in the first call
    dys = rng.normal(0, 0.04, (20, 2))
    searched = []
    real = rb.neighbours_many
    monkeypatch.setattr(rb, "neighbours_many", lambda mem, q, k: searched.append(len(q)) or real(mem, q, k))
    cache: dict = {}
    first = reach_steps(learner, alphas, dys, cache)
    second = reach_steps(learner, alphas[::-1], dys, cache)  # all met before: no search at all
    assert searched == [20]
    for got, al in ((first, alphas), (second, alphas[::-1])):
        want = np.stack([learner.reach_step(a, d) for a, d in zip(al, dys)])
        assert got.tobytes() == want.tobytes()


@pytest.mark.parametrize("cfg,ov,n", [
    ("config/arm15.yaml", {"context": "fixed", "strategy": "sagg-riac"}, 600),   # arm, fixed context
    ("config/arm8.yaml", {"context": "fixed", "strategy": "sagg-random"}, 300),  # noisy arm
    ("config/fishing.yaml", {"strategy": "sagg-riac", "eval.pool": 150}, 150),
])
def test_batched_fixed_context_evaluation_equals_per_goal(cfg, ov, n):
    from sagg_low_level.fixed_context import evaluate_fixed
    from sagg_low_level.fixed_eval_batch import evaluate_fixed_batch, inverses
    run = in_process_run(cfg, dict(ov, **{"eval.goals": 30}))
    goals = run.test_goals()[0]
    run.step_until(n)
    want = evaluate_fixed(run.learner, run.setup.evaluator(), goals)
    got = evaluate_fixed_batch(run.learner, run.setup.evaluator(), goals)
    assert got.tobytes() == want.tobytes()
    assert np.array_equal(run.evaluate(goals), want)
    thetas = inverses(run.learner, goals)
    assert all(t.tobytes() == run.learner.inverse(g).tobytes() for t, g in zip(thetas, goals))
    assert len({t.tobytes() for t in thetas}) > 1  # the goals got different synergies


def test_exact_mode_batch_scan_equals_the_index():
    rng = np.random.default_rng(5)
    mem = SampleMemory(4, 4, 2, buffer_size=32)  # exact mode (checks 0)
    pts = rng.integers(0, 6, (2000, 4)) / 5.0    # a coarse grid: many exact ties
    for p in pts:
        mem.add(p, np.zeros(4), np.zeros(2))
    q = np.vstack([pts[:40], rng.uniform(0, 1, (40, 4))])
    for k in (1, 7, 33):
        assert np.array_equal(neighbours_many(mem, q, k), np.stack([mem.neighbours(x, k) for x in q]))
