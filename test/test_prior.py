"""A prior from another run (sagg_low_level/prior.py) and the calibration gap of the simulated arm
(sagg_sim_bridge/calibration.py)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sagg_common.params import ConfigError
from sagg_low_level.learner import SCHEMA as LEARNER_SCHEMA, EvolvingContextLearner, Robot
from sagg_low_level.memory import SampleMemory
from sagg_low_level.prior import Prior, default_radius, load_prior, merged_neighbours
from sagg_low_level.reach_batch import reach_steps

N, M = 3, 2


def _params(**kw) -> dict:
    p = {q.name: q.default for q in LEARNER_SCHEMA}
    p.update({"task_space.lower": [-2.0, -2.0], "task_space.upper": [2.0, 2.0]})
    p.update(kw)
    return p


def _robot() -> Robot:
    return Robot([f"j{i}" for i in range(N)], np.full(N, -3.0), np.full(N, 3.0), np.zeros(N))


def _samples(rng, count, jac):
    a = rng.uniform(-1, 1, size=(count, N))
    da = rng.uniform(-0.05, 0.05, size=(count, N))
    return a, da, da @ jac.T


def test_a_prior_sample_near_a_robot_sample_is_superseded_and_not_used():
    prior = Prior(np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0]]), np.full((3, N), 0.01), np.zeros((3, M)),
                  radius=0.2)
    mem = SampleMemory(N, N, M)
    r, p = merged_neighbours(mem, prior, np.zeros(N), 3)
    assert len(r) == 0 and sorted(p.tolist()) == [0, 1, 2]
    mem.add([0.05, 0.0, 0.0], np.full(N, 0.01), np.zeros(M))   # 0.05 from prior 0 (within 0.2)
    assert prior.cover(mem.alpha[0]) == 1
    assert prior.superseded.tolist() == [True, False, False] and prior.live_count == 2
    r, p = merged_neighbours(mem, prior, np.zeros(N), 3)
    assert r.tolist() == [0] and 0 not in p.tolist() and sorted(p.tolist()) == [1, 2]
    # a robot sample farther than the radius supersedes nothing
    assert prior.cover(np.array([0.5, 0.5, 0.0])) == 0


def test_the_superseded_set_depends_on_the_samples_not_their_order():
    rng = np.random.default_rng(3)
    a, da, dy = _samples(rng, 400, rng.normal(size=(M, N)))
    robot = rng.uniform(-1, 1, size=(60, N))
    one = Prior(a, da, dy, radius=0.25)
    for x in robot:
        one.cover(x)
    other = Prior(a, da, dy, radius=0.25)
    other.cover_all(robot[::-1])
    assert 0 < one.superseded_count < len(a)
    assert np.array_equal(one.superseded, other.superseded) and one.superseded_count == other.superseded_count


def test_merged_neighbours_are_the_nearest_of_the_robot_and_the_live_prior():
    rng = np.random.default_rng(4)
    jac = rng.normal(size=(M, N))
    pa, pda, pdy = _samples(rng, 300, jac)
    prior = Prior(pa, pda, pdy, radius=0.15)
    mem = SampleMemory(N, N, M)
    for a, da, dy in zip(*_samples(rng, 80, jac)):
        mem.add(a, da, dy)
        prior.cover(a)
    for q in rng.uniform(-1, 1, size=(20, N)):
        r, p = merged_neighbours(mem, prior, q, 6)
        # brute force over every robot sample and every live prior sample
        pts = np.concatenate((mem.alpha, pa[~prior.superseded]))
        d = np.sum((pts - q) ** 2, axis=1)
        expect = np.sort(d)[:6]
        got = np.sort(np.concatenate((np.sum((mem.alpha[r] - q) ** 2, axis=1), np.sum((pa[p] - q) ** 2, axis=1))))
        assert np.allclose(got, expect) and not prior.superseded[p].any()


def test_a_learner_with_a_prior_fits_from_it_before_any_robot_sample(tmp_path):
    rng = np.random.default_rng(5)
    jac = rng.normal(size=(M, N))
    src = SampleMemory(N, N, M)
    a, da, dy = _samples(rng, 500, jac)
    a[:50] *= 0.05  # some near the origin, where the robot's samples will be
    for row in zip(a, da, dy):
        src.add(*row)
    src.save(tmp_path / "prior.npz")
    without = EvolvingContextLearner(_params(), _robot(), M)
    assert without.jacobian_at(np.zeros(N)) is None
    learner = EvolvingContextLearner(_params(**{"prior.memory": str(tmp_path / "prior.npz")}), _robot(), M)
    assert learner.prior is not None and learner.model_samples() == 500 and len(learner.memory) == 0
    assert learner.prior.radius == pytest.approx(default_radius(learner.p["explore_amplitude"], N))
    assert np.allclose(learner.jacobian_at(np.zeros(N)), jac, atol=1e-8)
    # robot samples of another arm: the prior near them is no longer used, theirs is
    other = -jac
    for a, da, dy in zip(*_samples(np.random.default_rng(6), 40, other)):
        learner.store(a * 0.05, da, dy)  # all near the origin
    assert learner.prior.superseded_count > 0 and len(learner.memory) == 40
    assert np.allclose(learner.jacobian_at(np.zeros(N)), other, atol=1e-8)
    # the evaluation's batch reaching fits the same local models
    alphas = rng.uniform(-1, 1, size=(8, N))
    dys = rng.uniform(-0.1, 0.1, size=(8, M))
    batch = reach_steps(learner, alphas, dys)
    one = np.array([learner.reach_step(a, d) for a, d in zip(alphas, dys)])
    assert np.array_equal(batch, one)


def test_a_prior_of_another_robot_is_refused_naming_the_parameter(tmp_path):
    src = SampleMemory(N + 1, N + 1, M)
    src.add(np.zeros(N + 1), np.zeros(N + 1), np.zeros(M))
    src.save(tmp_path / "p.npz")
    with pytest.raises(ConfigError, match="prior.memory.*4 joints.*allowed.*3 joints"):
        load_prior(_params(**{"prior.memory": str(tmp_path / "p.npz")}), N, M)
    with pytest.raises(ConfigError, match="prior.memory"):
        load_prior(_params(**{"prior.memory": str(tmp_path / "missing.npz")}), N, M)
    with pytest.raises(ValueError, match="prior.radius"):
        Prior(np.zeros((1, N)), np.zeros((1, N)), np.zeros((1, M)), radius=0.0)


# ---------------------------------------------------------------------- the calibration gap
def _arm7():
    from sagg_bringup.inprocess.experiment import load_arm_config
    from sagg_sim_bridge.arms import arm_spec_from_params
    return arm_spec_from_params(load_arm_config("config/arm7_urdf.yaml")["sagg_sim_bridge"])


def test_joint_offsets_move_the_effector_as_the_offset_posture_of_the_model_does():
    from sagg_sim_bridge.arms import make_arm_sim
    from sagg_sim_bridge.calibration import Calibration
    spec = _arm7()
    n = len(spec.joint_names())
    offsets = np.linspace(-0.04, 0.05, n)
    true = make_arm_sim(dataclasses.replace(spec, calibration=Calibration(1.0, tuple(offsets))), 0)
    nominal = make_arm_sim(spec, 0)
    lo, hi = spec.limits()
    postures = np.random.default_rng(0).uniform(lo + 0.1, hi - 0.1, size=(5, n))
    for q in postures:
        alpha, y = true.command(q)
        assert np.allclose(alpha, q)   # reported (encoder) angles: the commanded ones
        assert np.allclose(y, nominal.tip_positions(q + offsets), atol=1e-12)
        assert np.linalg.norm(y - nominal.tip_positions(q)) > 1e-3
    # the batch kinematics (reachable set, test goals) and MuJoCo's agree on the calibrated arm
    assert np.allclose(true.tip_positions(postures), true.fk_mujoco(postures), atol=1e-12)


def test_a_length_scale_scales_the_arm_about_its_base():
    from sagg_sim_bridge.arms import make_arm_sim
    from sagg_sim_bridge.calibration import Calibration, test_gap
    spec = _arm7()
    long = dataclasses.replace(spec, calibration=Calibration(1.05))
    q = spec.rest_posture()
    y0, y1 = make_arm_sim(spec, 0).tip_positions(q), make_arm_sim(long, 0).tip_positions(q)
    assert np.allclose(y1, 1.05 * y0, atol=1e-12)  # the base sits at the world origin
    assert long.reach() == spec.reach()  # the task-unit defaults are the model file's
    gap = test_gap(7, 2.0)
    assert gap.length_scale == pytest.approx(1.06) and gap.joint_offsets[:2] == pytest.approx((0.06, -0.06))


def test_a_bad_calibration_names_its_parameter():
    from sagg_bringup.inprocess.experiment import load_arm_config
    with pytest.raises(ConfigError, match="arm.calibration.joint_offsets.*one per commanded joint"):
        load_arm_config("config/arm7_urdf.yaml", {"arm.calibration.joint_offsets": [0.01, 0.02]})
    with pytest.raises(ConfigError, match="arm.calibration.length_scale"):
        load_arm_config("config/arm7_urdf.yaml", {"arm.calibration.length_scale": 3.0})
    with pytest.raises(ConfigError, match="arm.calibration.*the planar arm"):
        load_arm_config("config/arm8.yaml", {"arm.calibration.length_scale": 1.03})


# ---------------------------------------------------------------------- regions, sources, the graph
def test_the_goal_generator_starts_from_a_prior_region_tree(tmp_path):
    from sagg_bringup.inprocess.experiment import load_arm_config, run_arm_experiment
    from sagg_goal_generator.core import GoalGenerator
    run_arm_experiment("config/arm6_mjcf.yaml", None, 0, 3000, 3000, tmp_path / "p", progress=False,
                       save_model=True)
    gp = load_arm_config("config/arm6_mjcf.yaml")["sagg_goal_generator"]
    fresh = GoalGenerator(gp)
    started = GoalGenerator({**gp, "prior.regions": str(tmp_path / "p" / "regions.npz")})
    assert len(fresh.tree.leaves()) == 1 and len(started.tree.leaves()) > 1
    assert started.tree.splits == [] and started.goals == []  # this run's own history
    started.next_goal()  # the tree is usable
    with pytest.raises(ConfigError, match="prior.regions.*allowed: a tree of this task space"):
        GoalGenerator({**gp, "task_space.upper": [2.0, 2.0, 2.0], "prior.regions": str(tmp_path / "p" / "regions.npz")})


def test_a_prior_source_without_a_model_or_a_tree_is_refused(tmp_path):
    from sagg_bringup.graph.prior_source import prepare_prior
    with pytest.raises(ConfigError, match="--prior: .* does not exist"):
        prepare_prior(tmp_path / "nothing", tmp_path / "out", say=lambda _: None)
    src = tmp_path / "model"
    src.mkdir()
    mem = SampleMemory(N, N, M)
    mem.add(np.zeros(N), np.zeros(N), np.zeros(M))
    mem.save(src / "memory.npz")
    ov = prepare_prior(src, tmp_path / "out", say=lambda _: None)
    assert ov == {"prior.memory": str((tmp_path / "out" / "prior" / "memory.npz").resolve())}
    with pytest.raises(ConfigError, match="--prior-regions: .* holds no region tree"):
        prepare_prior(src, tmp_path / "out2", regions=True, say=lambda _: None)


def test_a_graph_run_with_a_prior_and_a_gap_equals_the_in_process_run_and_resumes(tmp_path):
    """sagg run --prior (the simulated bridge with a calibration gap as the robot): the same samples,
    curve and prior counts as the in-process run; then --resume, whose superseded set is rebuilt
    from the restored samples (a resumed learner starts a new attempt, so its run is its own)."""
    import json
    import os
    import shutil
    import subprocess

    from installed import SAGG
    from sagg_low_level.checkpoint import checkpoint_memory
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    gap = ["--set", "arm.calibration.length_scale=1.03", "--set",
           "arm.calibration.joint_offsets=[0.03,-0.03,0.03,-0.03,0.03,-0.03]"]

    def sagg(*args):
        p = subprocess.run([SAGG, *args], env=env, capture_output=True, text=True, timeout=400)
        assert p.returncode == 0, p.stdout + p.stderr
        return p

    sagg("experiment", "--config", "config/arm6_mjcf.yaml", "--seed", "7", "--micro-actions", "3000",
         "--eval-every", "3000", "--out", str(tmp_path / "sim"), "--quiet", "--save-model")
    run = tmp_path / "robot"
    prior = ["--prior", str(tmp_path / "sim"), "--prior-regions", *gap]
    sagg("run", "config/arm6_mjcf.yaml", "--seed", "1", "--micro-actions", "300", "--eval-every", "150", *prior,
         "--out", str(run), "--quiet", "--no-report")
    sagg("experiment", "--config", "config/arm6_mjcf.yaml", "--seed", "1", "--micro-actions", "300",
         "--eval-every", "150", *prior, "--out", str(tmp_path / "ip"), "--quiet")
    s = json.loads((run / "summary.json").read_text())
    r = json.loads((tmp_path / "ip" / "result.json").read_text())
    assert s["memory"]["digest"] == r["memory"]["digest"] and s["memory"]["samples"] == 300
    assert [c["mean_error"] for c in s["curve"]] == [c["mean_error"] for c in r["curve"]]
    assert s["prior"] == {"samples": r["prior"]["samples"], "superseded": r["prior"]["superseded"]}
    assert 0 < s["prior"]["superseded"] < s["prior"]["samples"] == 3000
    assert json.loads((run / "prior" / "prior.json").read_text())["regions"] is True
    moved = tmp_path / "moved"  # (the run directory moved: its own prior is found)
    shutil.move(run, moved)
    run = moved
    sagg("run", "--resume", str(run), "--micro-actions", "450", "--quiet", "--no-report")
    s = json.loads((run / "summary.json").read_text())
    robot = checkpoint_memory(run / "checkpoint")
    recount = Prior(*(getattr(SampleMemory.load(run / "prior" / "memory.npz"), k)
                      for k in ("alpha", "delta_alpha", "delta_y")), radius=r["prior"]["radius"])
    recount.cover_all(robot.alpha)
    assert len(robot) == 450 and s["prior"]["superseded"] == recount.superseded_count

