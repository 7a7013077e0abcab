"""Synergy simulators (paper Sec. 4-5): synergy → trajectory, outcome frames, water contact, short runs."""
from __future__ import annotations

import json
import math

import mujoco
import numpy as np
import pytest

from sagg_common.synergy import SinusoidSynergy, Trajectory, VelocitySynergy
from sagg_low_level.fixed_context import QUADRUPED_JOINTS, QUADRUPED_REST
from sagg_sim_bridge import fishing, quadruped
from sagg_sim_bridge.fishing import FishingSim, first_crossing
from sagg_sim_bridge.quadruped import QuadrupedSim, QuadrupedSpec, start_frame_outcome, wrap


def test_sinusoid_synergy_to_trajectory():
    rest = np.linspace(-0.3, 0.3, 12)
    syn = SinusoidSynergy(QUADRUPED_JOINTS, rest, [0.5] * 12, 2 * math.pi, 3.0, 50.0)
    assert syn.dim == 24 and np.all(syn.upper[12:] == 2 * math.pi) and np.all(syn.upper[:12] == 0.5)
    theta = np.concatenate([np.linspace(0.0, 0.5, 12), np.linspace(0, 2 * math.pi, 12)])
    traj = syn.trajectory(theta)
    assert traj.times[0] == 0.0 and traj.times[-1] == 3.0 and len(traj.times) == 151
    for k in (0, 37, 150):
        t = traj.times[k]
        np.testing.assert_allclose(traj.positions[k], rest + theta[:12] * np.sin(2 * math.pi * t + theta[12:]),
                                   atol=1e-12)
    # between points the simulated controller interpolates linearly (control period 8 ms, points every 20 ms)
    sim = QuadrupedSim()
    targets = sim._targets(traj)
    k = int(round(traj.times[10] / sim.dt_control)) + 1            # 8 ms after point 10
    w = (k * sim.dt_control - traj.times[10]) / (traj.times[11] - traj.times[10])
    assert 0.0 < w < 1.0
    np.testing.assert_allclose(targets[k], (1 - w) * traj.positions[10] + w * traj.positions[11], atol=1e-12)
    with pytest.raises(ValueError, match="theta"):
        syn.trajectory(np.zeros(23))


def test_velocity_synergy_to_trajectory():
    syn = VelocitySynergy(fishing.JOINT_NAMES, [-1.0, -2.0, 0.0, -1.5], [1.0, 2.0, 1.0, 1.5], 2.0, 50.0)
    traj = syn.trajectory([0.5, 1.0, 0.25, 0.0])
    assert traj.positions is None and traj.times[-1] == 2.0
    np.testing.assert_allclose(traj.velocities[0], [0.0, 2.0, 0.25, -1.5])
    np.testing.assert_array_equal(traj.velocities[-1], 0.0)     # stop at 2 s
    np.testing.assert_allclose(traj.sample_velocities(1.99), [0.0, 2.0, 0.25, -1.5])
    np.testing.assert_array_equal(traj.sample_velocities(2.5), 0.0)
    with pytest.raises(ValueError, match="velocity_upper"):
        VelocitySynergy(["a"], [1.0], [1.0], 2.0, 50.0)


def test_trajectory_validation():
    with pytest.raises(ValueError, match="increasing"):
        Trajectory(["a"], [0.0, 0.0], positions=[[0.0], [1.0]])
    with pytest.raises(ValueError, match="positions"):
        Trajectory(["a", "b"], [0.0, 1.0], positions=[[0.0], [1.0]])


def test_learner_defaults_match_the_quadruped():
    assert QUADRUPED_JOINTS == quadruped.JOINT_NAMES
    assert QUADRUPED_REST == quadruped.REST_POSTURE


def test_start_frame_outcome_known_values():
    # facing +y (yaw0 = π/2), moved 1 m along +y: 1 m forward, 0 sideways
    np.testing.assert_allclose(start_frame_outcome([1, 2], math.pi / 2, [1, 3], 0.3, 10.0), [10.0, 0.0, 0.3],
                               atol=1e-12)
    # facing +x, moved along -y: to the right (negative v)
    np.testing.assert_allclose(start_frame_outcome([0, 0], 0.0, [0, -0.5], 0.0, 10.0), [0.0, -5.0, 0.0])
    assert wrap(3 * math.pi / 2) == pytest.approx(-math.pi / 2)


def _floating_quadruped():
    """A quadruped without gravity, floor contacts or head (symmetric: z is a principal axis), lifted
    above the floor: its torso moves as its start velocity says."""
    sim = QuadrupedSim(QuadrupedSpec(head_mass=0.0))
    sim.model.opt.gravity[:] = 0.0
    sim.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return sim


def set_rest_state(sim, qpos, qvel) -> None:
    """Replace the rest state every experiment of ``sim`` starts from (a known start pose/motion)."""
    assert qpos.shape == sim._rest_qpos.shape and qvel.shape == sim._rest_qvel.shape
    sim._rest_qpos, sim._rest_qvel = np.array(qpos, dtype=float), np.array(qvel, dtype=float)
    sim.reset()


def _still(sim, duration=2.0):
    syn = SinusoidSynergy(quadruped.JOINT_NAMES, sim.rest, [0.1] * 12, 2 * math.pi, duration, 50.0)
    return syn.trajectory(np.zeros(24))


def test_quadruped_known_translation_in_a_rotated_start_frame():
    sim = _floating_quadruped()
    qpos, qvel = sim._rest_qpos.copy(), np.zeros_like(sim._rest_qvel)
    yaw0 = 0.7
    qpos[0:3] = [0.4, -0.3, 1.0]
    qpos[3:7] = [math.cos(yaw0 / 2), 0.0, 0.0, math.sin(yaw0 / 2)]
    qvel[0:2] = [0.3, 0.1]                      # world-frame linear velocity (m/s)
    set_rest_state(sim, qpos, qvel)
    y = sim.execute(_still(sim, 2.0))
    d = np.array([0.6, 0.2])                    # 2 s at (0.3, 0.1)
    c, s = math.cos(yaw0), math.sin(yaw0)
    expected = 10.0 * np.array([c * d[0] + s * d[1], -s * d[0] + c * d[1]])
    np.testing.assert_allclose(y[:2], expected, atol=0.02)
    assert abs(y[2]) < 1e-3


def test_quadruped_yaw_is_unwrapped_beyond_half_a_turn():
    sim = _floating_quadruped()
    qpos, qvel = sim._rest_qpos.copy(), np.zeros_like(sim._rest_qvel)
    qpos[2] = 1.0
    qvel[5] = 0.75 * math.pi                    # body-frame yaw rate: 1.5π in 2 s
    set_rest_state(sim, qpos, qvel)
    y = sim.execute(_still(sim, 2.0))
    assert y[2] == pytest.approx(1.5 * math.pi, rel=0.02)    # not wrapped to -π/2
    assert np.all(np.abs(y[:2]) < 0.05)


def test_quadruped_still_synergy_stays_and_runs_are_deterministic():
    sim = QuadrupedSim()
    np.testing.assert_allclose(sim.execute(_still(sim, 1.0)), 0.0, atol=0.05)
    syn = SinusoidSynergy(quadruped.JOINT_NAMES, sim.rest, [0.2, 0.5, 0.5] * 4, 2 * math.pi, 1.0, 50.0)
    theta = np.random.default_rng(0).uniform(syn.lower, syn.upper)
    a = sim.execute(syn.trajectory(theta))
    b = QuadrupedSim().execute(syn.trajectory(theta))
    np.testing.assert_array_equal(a, b)
    assert np.linalg.norm(a[:2]) > 0.05          # a gait moves the body
    with pytest.raises(ValueError, match="positions"):
        sim.execute(Trajectory(quadruped.JOINT_NAMES, [0.0, 1.0], velocities=np.zeros((2, 12))))


def test_first_crossing():
    assert first_crossing(1.0, 0.5, [0, 0, 1], [1, 1, 0.5], 0.0) is None
    np.testing.assert_allclose(first_crossing(1.0, -1.0, [0, 0, 1], [2, 4, -1], 0.0), [1, 2, 0])
    np.testing.assert_allclose(first_crossing(0.3, 0.1, [0, 0, 0.3], [1, 0, 0.1], 0.2), [0.5, 0, 0.2])


def test_fishing_contact_detection():
    sim = FishingSim()
    assert sim.rest_float[2] > sim.spec.float_radius            # hangs above the water at rest
    syn = VelocitySynergy(fishing.JOINT_NAMES, [-1.5] * 4, [1.5] * 4, 2.0, 50.0)
    # θ = 0.5: zero velocities, nothing moves: no contact, discarded and counted
    assert sim.execute(syn.trajectory([0.5] * 4)) is None
    assert sim.no_contact == 1
    # a cast: the float lands; at that moment it sits on the water plane, where the outcome says
    rng = np.random.default_rng(0)
    landed = 0
    for _ in range(8):
        y = sim.execute(syn.trajectory(rng.uniform(0, 1, 4)))
        if y is None:
            continue
        landed += 1
        f = sim.data.xpos[sim._float]  # the float's position (m) after the experiment
        assert f[2] <= sim.spec.float_radius
        step = 0.2 * sim.spec.timestep * sim.spec.check_every * 50   # < one check of travel
        assert np.linalg.norm(f[:2] * sim.spec.position_scale - y) < step
        assert np.linalg.norm(y) < 1.2                               # reachable disk of radius ≈ 1
    assert landed >= 3
    assert sim.no_contact == 1 + 8 - landed


def test_fishing_runs_are_deterministic():
    syn = VelocitySynergy(fishing.JOINT_NAMES, [-1.5] * 4, [1.5] * 4, 2.0, 50.0)
    traj = syn.trajectory([0.9, 0.1, 0.8, 0.3])
    a, b = FishingSim().execute(traj), FishingSim().execute(traj)
    assert (a is None) == (b is None)
    if a is not None:
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("config", ["config/quadruped.yaml", "config/fishing.yaml"])
def test_short_learning_run(config, tmp_path):
    from sagg_bringup.graph.setups import run_experiment
    # 60 experiments: the test goals spread over the reachable outcome set (eval.pool_rounds) lie
    # further out than random synergies' outcomes; 30 experiments did not always beat the rest outcome
    res = run_experiment(config, "sagg-riac", 0, 60, 30, tmp_path, progress=False,
                         overrides={"eval.pool": 30, "eval.goals": 10})
    saved = json.loads((tmp_path / "result.json").read_text())
    assert saved["micro_actions"] == res["micro_actions"] == 60
    syn = saved["synergy"]
    assert len(syn["outcomes"]) == 60 and syn["trials"] == 60 + syn["discarded"]
    assert [c["micro_actions"] for c in saved["curve"]] == [0, 30, 60]
    assert len(saved["test_goals"]) == 10 and saved["goals"]
    # the untrained model scores the distance from the rest outcome
    assert saved["curve"][-1]["mean_error"] < saved["curve"][0]["mean_error"]
    for key in ("strategy", "seed", "config", "micro_actions_per_second", "final_mean_error", "memory",
                "regions", "splits", "goal_stats"):
        assert key in saved
