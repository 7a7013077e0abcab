"""/sagg/compute_ik's core (sagg_low_level.ik, evaluate.open_loop_reach, known_points): joint positions for
a point of Y from the learned model alone, on a known arm (the forward kinematics of the answer), the
points of the stored postures rebuilt from the memory (against a simulated arm's forward kinematics),
the start from the nearest known point and the fallback to rest, the request checks, the start point,
the scene, and the model's files. ROS-free."""
from __future__ import annotations

import json

import numpy as np
import pytest

from sagg_common.params import resolve
from sagg_common.scene import Refusal
from sagg_low_level.evaluate import frozen_reach, open_loop_reach
from sagg_low_level.ik import (compute_ik, load_model, nearest_sample, predicted_point, request_problem,
                               rest_point_file, start_candidates, write_rest_point)
from sagg_low_level.known_points import KnownPoints, sample_points
from sagg_low_level.learner import SCHEMA, EvolvingContextLearner, Robot
from sagg_low_level.memory import SampleMemory
from sagg_low_level.prior import Prior

LENGTHS = np.array([1.0, 0.8, 0.6])
REST = np.array([0.3, 0.4, 0.4])


def fk(alpha):
    ang = np.cumsum(np.atleast_2d(alpha), axis=1)
    return np.stack([(LENGTHS * np.cos(ang)).sum(1), (LENGTHS * np.sin(ang)).sum(1)], axis=1)


def planar_learner():
    p = resolve(SCHEMA, {"task_space.lower": [-3.0, -3.0], "task_space.upper": [3.0, 3.0], "v": 0.1})
    return EvolvingContextLearner(p, Robot(["j0", "j1", "j2"], np.full(3, -2.0), np.full(3, 2.0), REST), 2)


def known_arm(samples=20000, seed=0):
    """A 3-link planar arm's model: ``samples`` micro-actions of 0.05 rad at most from postures
    spread over the joint range, stored as the learner stores them (α, Δα, Δy); no two consecutive
    (no point known but the rest point)."""
    learner = planar_learner()
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(-1.6, 1.6, (samples, 3)) + REST * 0.0
    dalpha = rng.uniform(-0.05, 0.05, (samples, 3))
    dy = fk(alpha + dalpha) - fk(alpha)
    for a, da, d in zip(alpha, dalpha, dy):
        learner.memory.add(a, da, d)
    return learner


def chained_arm(chains=400, length=50, seed=0):
    """The same arm's model learned as the learner learns: chains of ``length`` consecutive
    micro-actions (random walks of 0.05 rad at most per joint) from the rest posture, each followed
    by an unstored return to rest, and one chain after an unstored move elsewhere."""
    learner = planar_learner()
    rng = np.random.default_rng(seed)
    for c in range(chains + 1):
        alpha = REST.copy() if c < chains else np.array([1.0, -0.5, 0.2])  # (the last: after an unstored move)
        for _ in range(length):
            nxt = np.clip(alpha + rng.uniform(-0.05, 0.05, 3), -1.9, 1.9)
            learner.memory.add(alpha, nxt - alpha, fk(nxt)[0] - fk(alpha)[0])
            alpha = nxt
    return learner


@pytest.fixture(scope="module")
def arm():
    return known_arm()


@pytest.fixture(scope="module")
def chained():
    return chained_arm()


def targets(n, seed=1):
    rng = np.random.default_rng(seed)
    return fk(REST + rng.uniform(-0.8, 0.8, (n, 3)))


def test_the_answer_puts_the_known_arm_at_the_target(arm):
    rest_point = fk(REST)[0]
    errors, nearest = [], []
    for goal in targets(20):
        a = compute_ik(arm, rest_point, goal, tolerance=0.005)
        assert a.success and a.outcome == "reached", a.message
        assert np.all(a.joints >= arm.robot.lower) and np.all(a.joints <= arm.robot.upper)
        assert a.predicted_error <= 0.005 and np.linalg.norm(a.predicted - goal) == pytest.approx(a.predicted_error)
        errors.append(np.linalg.norm(fk(a.joints)[0] - goal))      # the forward kinematics of the answer
        nearest.append(a.nearest_sample)
    # open loop: the model's small errors add up along the way (a measured reach corrects them)
    assert np.median(errors) < 0.04 and max(errors) < 0.1, errors  # (targets about 1.0 from the rest point)
    assert 0 < max(nearest) < 0.3  # dense samples: never far from one


def test_open_loop_reach_takes_frozen_reachs_steps(arm):
    """Answered with what the model predicts, the steps are frozen_reach's (the same generator)."""
    goal = targets(1, seed=5)[0]
    y0 = fk(REST)[0]
    alpha, y, dist, steps, outcome, refusal = open_loop_reach(arm, REST, y0, goal, 0.005)
    reach = frozen_reach(arm, REST.copy(), y0, goal, 0.005)
    a, yy = REST.copy(), y0.copy()
    try:
        target = next(reach)
        while True:
            yy = yy + arm.predict(a, target - a)
            a = target
            target = reach.send((a, yy))
    except StopIteration as done:
        assert np.array_equal(done.value[0], y) and done.value[2] == steps and done.value[3] == outcome
    assert np.array_equal(a, alpha) and refusal is None


def test_a_start_posture_is_reached_from_rest_on_the_model(arm):
    start = REST + np.array([0.5, -0.4, 0.3])
    assert np.linalg.norm(predicted_point(arm, fk(REST)[0], start) - fk(start)[0]) < 0.08  # (1.3 rad away)
    assert np.array_equal(predicted_point(arm, fk(REST)[0], REST), fk(REST)[0])
    goal = targets(1, seed=7)[0]
    a = compute_ik(arm, fk(REST)[0], goal, start=start, tolerance=0.005)
    b = compute_ik(arm, None, goal, start=start, start_point=fk(start)[0], tolerance=0.005)  # measured
    assert a.success and b.success
    assert np.linalg.norm(fk(b.joints)[0] - goal) < 0.1


def test_without_a_rest_point_a_start_point_is_needed(arm):
    a = compute_ik(arm, None, targets(1)[0])
    assert not a.success and a.outcome == "no rest point" and "start_point" in a.message


def test_too_few_samples_is_no_model():
    small = known_arm(samples=2)
    a = compute_ik(small, fk(REST)[0], targets(1)[0])
    assert not a.success and a.outcome == "no model" and "too few samples" in a.message


def test_a_step_the_scene_refuses_ends_the_answer(arm):
    class Wall:  # refuses every posture whose first joint passes 0.5
        def segment(self, a0, a1):
            return Refusal("box", "wall", 0.0, 0.0) if a1[0] > 0.5 else None
    arm.scene = Wall()
    try:
        a = compute_ik(arm, fk(REST)[0], fk(np.array([1.2, 0.4, 0.4]))[0], tolerance=0.005)
    finally:
        arm.scene = None
    assert not a.success and a.outcome == "scene" and "box: wall" in a.message
    assert a.joints[0] <= 0.5 and a.steps >= 1


@pytest.mark.parametrize("field, kwargs, words", [
    ("target", {"target": [1.0]}, "target at [1.0]: allowed: 2"),                       # wrong dimension
    ("target", {"target": [np.nan, 0.0]}, "finite"),                    # NaN
    ("target", {"target": [9.0, 0.0]}, "within task_space"),            # outside Y
    ("start", {"start": [0.0, 0.0]}, "start [0.0, 0.0]: allowed"),        # wrong dimension
    ("start", {"start": [0.0, 0.0, 3.0]}, "within the joint limits"),   # outside the limits
    ("start_point", {"start_point": [np.inf, 0.0]}, "start_point"),
    ("tolerance", {"tolerance": -1.0}, "tolerance -1.0: allowed"),
    ("max_steps", {"max_steps": 10 ** 9}, "max_steps 1000000000: allowed"),
])
def test_bad_requests_say_what_is_wrong(arm, field, kwargs, words):
    req = {"target": [1.0, 1.0], "start": [], "start_point": [], "tolerance": 0.0, "max_steps": 0, **kwargs}
    why = request_problem(arm, req["target"], req["start"], req["start_point"], req["tolerance"],
                          req["max_steps"], 1000)
    assert why.startswith(field) and words in why, why
    assert request_problem(arm, [1.0, 1.0], [], [], 0.0, 0, 1000) == ""


def test_nearest_sample_is_the_distance_to_the_closest_stored_posture(arm):
    q = np.array([0.1, -0.2, 0.3])
    assert nearest_sample(arm.memory, q) == pytest.approx(np.linalg.norm(arm.memory.alpha[:len(arm.memory)] - q,
                                                                         axis=1).min())


def test_the_model_files(tmp_path, arm):
    with pytest.raises(ValueError, match="no learned model"):
        load_model(tmp_path)
    arm.memory.save(tmp_path / "memory.npz")
    mem, rest, what = load_model(tmp_path)
    assert len(mem) == len(arm.memory) and rest is None and what.endswith("memory.npz")
    write_rest_point(tmp_path, fk(REST)[0], "test")
    assert np.array_equal(rest_point_file(tmp_path), fk(REST)[0])
    assert json.loads((tmp_path / "model.json").read_text())["source"] == "test"
    assert np.array_equal(load_model(tmp_path / "memory.npz")[1], fk(REST)[0])


# ---------------------------------------------------------------- known points and the start nearest the target

def test_the_rebuilt_points_are_the_forward_kinematics_where_known(chained):
    mem = chained.memory
    known, start = sample_points(mem.alpha, mem.delta_alpha, mem.delta_y, REST, fk(REST)[0])
    assert known.sum() == len(mem) - 50 and not known[-50:].any()  # the chain after the unstored move
    assert np.isnan(start[~known]).all()
    assert np.abs(start[known] - fk(mem.alpha[known])).max() < 1e-9


def test_the_points_of_an_in_process_run_are_the_simulators():
    """On a simulated arm's run (the learner, its returns to rest and its scene, as `sagg experiment`),
    every rebuilt point is the simulator's forward kinematics of its posture."""
    from sagg_bringup.inprocess.experiment import InProcessRun, load_arm_config  # lazy (heavy): mujoco
    run = InProcessRun(load_arm_config("config/arm7_urdf.yaml", {"seed": 0}))
    run.step_until(1500)
    mem, rest = run.learner.memory, run.learner.robot.rest
    rest_point = run.sim.tip_positions(rest[None])[0]
    known, start = sample_points(mem.alpha, mem.delta_alpha, mem.delta_y, rest, rest_point)
    assert known.mean() > 0.9, known.mean()
    assert np.abs(start[known] - run.sim.tip_positions(mem.alpha[known])).max() < 1e-9


def test_the_index_follows_a_growing_memory(chained):
    """Read in pieces (as the learner node's memory grows between calls), the index knows the same
    points as read at once, and finds the nearest."""
    whole = KnownPoints().update(chained.memory, REST)
    growing, part = KnownPoints(), SampleMemory(3, 3, 2)
    mem = chained.memory
    for i in range(len(mem)):
        part.add(mem.alpha[i], mem.delta_alpha[i], mem.delta_y[i])
        if i % 997 == 0 or i == len(mem) - 1:
            growing.update(part, REST)
    assert whole.known == growing.known == len(mem) - 50 and growing.rows == len(mem)
    target = fk(REST + 0.3)[0] - fk(REST)[0]
    for index in (whole, growing):
        alpha, offset = index.nearest(target, 3)
        assert alpha.shape == (3, 3) and np.allclose(fk(alpha) - fk(REST)[0], offset, atol=1e-9)
    ends = mem.alpha[:-50] + mem.delta_alpha[:-50]
    best = np.linalg.norm(fk(ends) - fk(REST)[0] - target, axis=1).min()
    assert np.linalg.norm(whole.nearest(target, 1)[1][0] - target) == pytest.approx(best)
    assert KnownPoints().update(SampleMemory(3, 3, 2), REST).nearest(target, 3)[0].shape[0] == 0


def test_the_answer_from_the_nearest_known_point_is_accurate(chained, arm):
    """Started from the stored posture whose point is nearest, a few short steps: FK of the answer
    under a millimetre (median), where the reach from rest (the same model) misses by centimetres."""
    rest_point, points = fk(REST)[0], KnownPoints()
    rng = np.random.default_rng(3)
    goals = fk(REST + rng.uniform(-0.5, 0.5, (20, 3)))
    near, from_rest = [], []
    for goal in goals:
        a = compute_ik(chained, rest_point, goal, tolerance=0.001, points=points)
        assert a.success and a.start == "stored posture" and "from the stored posture" in a.message, a.message
        near.append(np.linalg.norm(fk(a.joints)[0] - goal))
        b = compute_ik(chained, rest_point, goal, start=REST, tolerance=0.001)
        from_rest.append(np.linalg.norm(fk(b.joints)[0] - goal))
    assert np.median(near) < 0.001 and max(near) < 0.03, near
    assert np.median(near) < np.median(from_rest) / 3, (np.median(near), np.median(from_rest))
    assert points.rows == len(chained.memory)  # (built once, kept by the caller)


def test_rest_is_the_fallback(chained, arm):
    rest_point = fk(REST)[0]
    # no stored point known (no two consecutive samples): from rest, as before
    a = compute_ik(arm, rest_point, targets(1)[0], tolerance=0.005)
    assert a.start == "rest posture" and "from the rest posture" in a.message
    # the rest point nearer the target than every stored point: rest first, then the stored ones
    starts = start_candidates(chained, rest_point, rest_point + 1e-6)
    assert starts[0][2] == "rest posture" and np.array_equal(starts[0][0], REST) and len(starts) == 5
    assert all(kind == "stored posture" for _, _, kind in starts[1:])
    # the start point given without a start: the rest point as the caller measured it
    b = compute_ik(chained, None, rest_point + 1e-6, start_point=rest_point, tolerance=0.001)
    assert b.success and b.start == "rest posture" and b.steps == 0 and np.array_equal(b.joints, REST)


def test_a_stored_posture_the_scene_refuses_is_no_start(chained):
    class Wall:  # refuses every posture whose first joint passes 0.5
        def segment(self, a0, a1):
            return Refusal("box", "wall", 0.0, 0.0) if a1[0] > 0.5 else None
    goal = fk(np.array([0.7, 0.2, 0.2]))[0]
    free = compute_ik(chained, fk(REST)[0], goal, tolerance=0.005)
    assert free.start == "stored posture" and free.joints[0] > 0.5  # (the nearest stored points are past it)
    chained.scene = Wall()
    try:
        a = compute_ik(chained, fk(REST)[0], goal, tolerance=0.005)
    finally:
        chained.scene = None
    assert a.joints[0] <= 0.5, (a.start, a.joints)


def test_a_given_start_is_honoured(chained):
    start = REST + np.array([0.5, -0.4, 0.3])
    a = compute_ik(chained, fk(REST)[0], fk(start)[0], start=start, start_point=fk(start)[0], tolerance=1e-6)
    assert a.start == "given" and a.steps == 0 and np.array_equal(a.joints, start)
    goal = targets(1, seed=7)[0]
    b = compute_ik(chained, fk(REST)[0], goal, start=start, start_point=fk(start)[0], tolerance=0.005)
    assert b.start == "given" and "from the given start" in b.message
    c = compute_ik(chained, fk(REST)[0], goal, start=start, start_point=fk(start)[0], tolerance=0.005, max_steps=1)
    assert c.steps == 1 and np.max(np.abs(c.joints - start)) <= chained.p["max_joint_step"] + 1e-12


def test_nearest_sample_counts_the_prior_in_use(arm):
    q = np.array([0.1, -0.2, 0.3])
    own = nearest_sample(arm.memory, q)
    arm.prior = Prior(q[None] + 1e-4, np.zeros((1, 3)), np.zeros((1, 2)), radius=1e-6)
    try:
        assert nearest_sample(arm.memory, q, arm.prior) == pytest.approx(np.sqrt(3) * 1e-4)
        arm.prior.superseded[:] = True
        arm.prior.superseded_count = 1
        assert nearest_sample(arm.memory, q, arm.prior) == own  # (a superseded prior sample is not used)
    finally:
        arm.prior = None
    assert np.isnan(nearest_sample(SampleMemory(3, 3, 2), q))
