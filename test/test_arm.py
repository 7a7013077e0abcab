"""Tests of the MuJoCo planar arm core (sagg_sim_bridge.arm)."""
import dataclasses
import json
import math

import mujoco
import numpy as np
import pytest

from sagg_sim_bridge.arm import (
    GOLDEN_RATIO,
    NOISE_BLOCK,
    ArmSim,
    ArmSpec,
    ReachableArea,
    arm_mjcf,
    reachable_area,
)
from sagg_sim_bridge.arm import test_goals as make_test_goals
from sagg_lab.arm_bench import bench_arm

L = 50.0


def mujoco_tip(sim: ArmSim, alpha: np.ndarray) -> np.ndarray:
    sim.data.qpos[:] = alpha
    mujoco.mj_kinematics(sim.model, sim.data)
    return sim.data.site("tip").xpos[:2].copy()


# ------------------------------------------------------------------ geometry
@pytest.mark.parametrize("dof", [1, 2, 7, 15, 30, 100])
def test_link_lengths_equal_and_golden(dof):
    eq = ArmSpec(dof=dof).link_lengths()
    assert eq.shape == (dof,)
    assert eq.sum() == pytest.approx(L, abs=1e-9)
    assert np.allclose(eq, L / dof)
    g = ArmSpec(dof=dof, link_profile="golden").link_lengths()
    assert g.sum() == pytest.approx(L, abs=1e-9)
    if dof > 1:
        assert np.allclose(g[:-1] / g[1:], GOLDEN_RATIO)
        assert np.all(np.diff(g) < 0)  # decreasing from the base


@pytest.mark.parametrize("dof,profile", [(1, "equal"), (2, "golden"), (7, "equal"), (8, "golden"),
                                         (15, "equal"), (30, "golden"), (100, "equal")])
def test_rest_posture_within_limits_bent_and_pointing_along_x(dof, profile):
    spec = ArmSpec(dof=dof, link_profile=profile)
    sim = ArmSim(spec, seed=0)
    rest = spec.rest_posture()
    assert np.all(rest >= sim.lower) and np.all(rest <= sim.upper)
    a, y = sim.reset()
    np.testing.assert_array_equal(a, rest)
    assert y[0] > 0 and abs(y[1]) < 1e-9          # tip on the +x axis
    if dof > 1:
        assert rest[1:].sum() == pytest.approx(spec.rest_bend)   # bent by rest_bend in total
        assert np.allclose(rest[1:], rest[1])                    # spread evenly
        assert y[0] < L - 1e-3                                    # not straight
    else:
        assert y[0] == pytest.approx(L)


def test_mjcf_radians_names_and_zero_points_along_x():
    spec = ArmSpec(dof=5)
    xml = arm_mjcf(spec)
    assert '<compiler angle="radian"' in xml
    sim = ArmSim(spec, seed=0)
    assert sim.joint_names == [f"joint_{i}" for i in range(5)]
    model_names = [sim.model.joint(i).name for i in range(sim.model.njnt)]
    assert model_names == spec.joint_names()
    np.testing.assert_allclose(mujoco_tip(sim, np.zeros(5)), [L, 0.0], atol=1e-12)
    np.testing.assert_allclose(mujoco_tip(sim, np.r_[np.pi / 2, 0, 0, 0, 0]), [0.0, L], atol=1e-12)
    # the model's joint ranges are the spec's limits
    np.testing.assert_allclose(sim.model.jnt_range[:, 0], sim.lower)
    np.testing.assert_allclose(sim.model.jnt_range[:, 1], sim.upper)
    assert sim.upper[0] == spec.base_limit and np.all(sim.upper[1:] == spec.joint_limit)


@pytest.mark.parametrize("dof,profile", [(1, "equal"), (7, "golden"), (15, "equal"), (30, "golden"), (100, "equal"),
                                         (100, "golden")])
def test_numpy_fk_equals_mujoco_tip_site(dof, profile):
    spec = ArmSpec(dof=dof, link_profile=profile, joint_limit=math.pi, base_limit=math.pi, rest_bend=0.5)
    sim = ArmSim(spec, seed=0)
    rng = np.random.default_rng(1)
    alphas = rng.uniform(sim.lower, sim.upper, size=(40, dof))
    ys = sim.tip_positions(alphas)
    assert ys.shape == (40, 2)
    for a, y in zip(alphas, ys):
        np.testing.assert_allclose(y, mujoco_tip(sim, a), rtol=0, atol=1e-9)
    np.testing.assert_allclose(sim.tip_positions(alphas[0]), ys[0], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="alphas"):
        sim.tip_positions(np.zeros((3, dof + 1)))


# ------------------------------------------------------------------ command
def test_kinematic_command_sets_joints_exactly_and_clips():
    spec = ArmSpec(dof=7)
    sim = ArmSim(spec, seed=0)
    rng = np.random.default_rng(2)
    for _ in range(50):
        target = rng.uniform(sim.lower, sim.upper)
        a, y = sim.command(target)
        np.testing.assert_array_equal(a, target)
        np.testing.assert_allclose(y, sim.tip_positions(a), atol=1e-9)
        a2, y2 = sim.observe()
        np.testing.assert_array_equal(a2, a)
        np.testing.assert_array_equal(y2, y)
    # out-of-range targets are clipped to the limits
    target = np.linspace(-4, 4, 7)
    a, _ = sim.command(target)
    np.testing.assert_array_equal(a, np.clip(target, sim.lower, sim.upper))
    assert a[0] == sim.lower[0] and a[-1] == sim.upper[-1]
    # returned arrays are copies: mutating them does not move the arm
    a[:] = 0.0
    assert not np.all(sim.observe()[0] == 0.0)
    # list input works too
    a, _ = sim.command(list(sim.rest))
    np.testing.assert_array_equal(a, sim.rest)


@pytest.mark.parametrize("mode", ["kinematic", "dynamic"])
def test_command_rejects_bad_input(mode):
    sim = ArmSim(ArmSpec(dof=4, mode=mode), seed=0)
    before = sim.get_state()
    for bad in (np.zeros(3), np.zeros(5), np.zeros((2, 4)), [0.1, 0.2]):
        with pytest.raises(ValueError, match="alpha_target"):
            sim.command(bad)
    for value in (np.nan, np.inf, -np.inf):
        t = sim.rest.copy()
        t[2] = value
        with pytest.raises(ValueError, match="finite"):
            sim.command(t)
    assert sim.get_state() == before  # nothing moved


def test_motor_noise_statistics_and_reproducibility():
    noise = 0.2
    spec = ArmSpec(dof=8, motor_noise=noise)
    sim = ArmSim(spec, seed=123)
    rng = np.random.default_rng(5)
    ratios = []
    for _ in range(2000):
        a0, _ = sim.reset()
        delta = rng.choice([-0.05, 0.05], size=8)  # small enough never to reach a limit
        a1, _ = sim.command(a0 + delta)
        ratios.append((a1 - a0) / delta)
    r = np.concatenate(ratios)
    assert r.size == 16000
    # mean 1, std = motor_noise (std error of the mean ~0.0016, of the std ~0.0011)
    assert abs(r.mean() - 1.0) < 0.01
    assert abs(r.std() - noise) < 0.01
    # same seed -> same sequence; other seed -> other sequence
    def run(seed):
        s = ArmSim(spec, seed=seed)
        out = []
        for i in range(20):
            out.append(s.command(s.rest + 0.03 * np.sin(np.arange(8) + i))[0])
        return np.array(out)
    np.testing.assert_array_equal(run(7), run(7))
    assert not np.array_equal(run(7), run(8))
    # the exact noise model: α1 = α0 + (target - α0)·(1 + motor_noise·z), z the generator's
    # standard normals in order, one per joint per micro-action (also across noise blocks)
    sim = ArmSim(spec, seed=21)
    z = np.random.default_rng(21).standard_normal((600, 8))
    for i in range(600):
        if i % 50 == 0:
            sim.reset()
        a0 = sim.observe()[0]
        target = a0 + 0.02 * np.cos(np.arange(8) * (i + 1))
        a1, _ = sim.command(target)
        factor = z[i] * noise
        factor += 1.0
        np.testing.assert_array_equal(a1, np.clip(a0 + (target - a0) * factor, sim.lower, sim.upper))
    # noise-free spec: no RNG draws at all
    quiet = ArmSim(ArmSpec(dof=8), seed=1)
    state = quiet.rng.bit_generator.state
    quiet.command(quiet.rest + 0.05)
    quiet.reset()
    assert quiet.rng.bit_generator.state == state
    assert quiet.get_state()["noise_index"] is None


def test_reset_draws_no_noise_and_zeroes_velocity():
    sim = ArmSim(ArmSpec(dof=6, mode="dynamic", motor_noise=0.3), seed=3)
    sim.command(sim.rest + 0.2)
    rng_state = sim.rng.bit_generator.state
    a, y = sim.reset()
    assert sim.rng.bit_generator.state == rng_state
    np.testing.assert_array_equal(a, sim.rest)
    np.testing.assert_array_equal(sim.data.qvel, 0.0)
    np.testing.assert_allclose(y, sim.tip_positions(sim.rest), atol=1e-9)


def test_dynamic_mode_reaches_commanded_posture():
    spec = ArmSpec(dof=8, mode="dynamic")
    sim = ArmSim(spec, seed=0)
    rng = np.random.default_rng(4)
    a = sim.rest.copy()
    for _ in range(30):  # micro-actions of ~0.05 rad per joint
        target = np.clip(a + rng.uniform(-0.05, 0.05, 8), sim.lower, sim.upper)
        a, y = sim.command(target)
        assert sim.last_settled and 0 < sim.last_settle_steps < spec.max_settle_steps
        assert np.linalg.norm(a - target) < spec.settle_tolerance
        assert np.linalg.norm(sim.data.qvel) < spec.settle_velocity
        np.testing.assert_allclose(y, sim.tip_positions(a), atol=1e-9)   # y is of the final posture
    # a large move to an arbitrary posture, then back to rest, settles too
    far = rng.uniform(sim.lower, sim.upper)
    a, _ = sim.command(far)
    assert sim.last_settled and np.linalg.norm(a - far) < spec.settle_tolerance
    a, y = sim.command(sim.rest)
    assert sim.last_settled and np.linalg.norm(a - sim.rest) < spec.settle_tolerance
    assert np.linalg.norm(y - sim.tip_positions(sim.rest)) < L * spec.settle_tolerance
    # a tiny budget is reported as not settled
    quick = ArmSim(ArmSpec(dof=8, mode="dynamic", max_settle_steps=2), seed=0)
    quick.command(quick.rest + 0.3)
    assert not quick.last_settled and quick.last_settle_steps == 2


@pytest.mark.parametrize("mode,before", [("kinematic", 0), ("kinematic", 5), ("kinematic", 250),
                                         ("dynamic", 5), ("dynamic", 250)])
def test_get_set_state_round_trip(mode, before):
    # `before` commands before the snapshot: 0 = no noise drawn yet; 250 = the 10 commands after
    # the snapshot cross a pre-drawn noise block boundary (NOISE_BLOCK = 256)
    assert NOISE_BLOCK == 256
    spec = ArmSpec(dof=7, mode=mode, motor_noise=0.2)
    sim = ArmSim(spec, seed=11)
    rng = np.random.default_rng(6)
    for i in range(before):
        if i % 20 == 0:
            sim.reset()
        sim.command(sim.observe()[0] + rng.uniform(-0.05, 0.05, 7))
    snap = json.loads(json.dumps(sim.get_state()))   # JSON-able
    targets = [sim.observe()[0] + rng.uniform(-0.05, 0.05, 7) for _ in range(10)]

    def run(s):
        out = []
        a = s.observe()[0]
        for t in targets:
            a, y = s.command(a + (t - targets[0]) * 0.5 + 0.01)
            out.append(np.r_[a, y, s.data.qvel])
        return np.array(out)

    first = run(sim)
    sim.set_state(snap)
    np.testing.assert_array_equal(run(sim), first)
    other = ArmSim(spec, seed=999)           # a fresh instance restored from the snapshot
    other.set_state(snap)
    np.testing.assert_array_equal(run(other), first)
    np.testing.assert_array_equal(other.observe()[0], sim.observe()[0])
    with pytest.raises(ValueError, match="n_joints"):
        ArmSim(ArmSpec(dof=6, mode=mode), seed=0).set_state(snap)
    bad = dict(snap, qpos=snap["qpos"][:-1])
    with pytest.raises(ValueError, match="qpos"):
        sim.set_state(bad)


# ------------------------------------------------------------------ reachable area
def test_reachable_area_full_disk_for_wide_limits():
    spec = ArmSpec(dof=15, joint_limit=math.pi, base_limit=math.pi)
    area = reachable_area(spec, [-60, -60], [60, 60])
    disk = math.pi * L ** 2
    assert area.area() == pytest.approx(disk, rel=0.03)
    assert area.share() == pytest.approx(area.area() / 120 ** 2)
    inside = np.array([[0.0, 0.0], [30.0, -20.0], [-45.0, 10.0], [0.0, 48.0]])
    outside = np.array([[51.0, 0.0], [40.0, 40.0], [-59.0, -59.0], [100.0, 0.0], [0.0, -70.0]])
    assert area.contains(inside).all()
    assert not area.contains(outside).any()
    # half disk when the bounds cut it (the paper's Y = [0,150]x[-150,150] case)
    half = reachable_area(spec, [0, -150], [150, 150])
    assert half.area() == pytest.approx(disk / 2, rel=0.03)
    assert half.share() == pytest.approx(disk / 2 / (150 * 300), rel=0.03)


def test_reachable_area_annulus_of_two_unequal_links():
    spec = ArmSpec(dof=2, link_profile="golden", joint_limit=math.pi, base_limit=math.pi)
    l0, l1 = spec.link_lengths()
    area = reachable_area(spec, [-60, -60], [60, 60])
    assert area.area() == pytest.approx(math.pi * (L ** 2 - (l0 - l1) ** 2), rel=0.03)
    r_in = l0 - l1
    assert not area.contains(np.array([[0.0, 0.0], [0.5 * r_in, 0.0], [0.0, -0.7 * r_in]])).any()
    assert area.contains(np.array([[r_in + 2.0, 0.0], [0.0, -(r_in + 5.0)]])).all()


def test_reachable_area_default_arm_sample_and_validation():
    spec = ArmSpec(dof=7)
    area = reachable_area(spec, [0, -150], [150, 150], seed=1)
    assert isinstance(area, ReachableArea)
    assert area.mask.dtype == bool and area.mask.shape == (300, 600)
    # the paper: "the arm covers less than 1/9 of the space Y"
    assert 0.05 < area.share() < 1 / 9
    pts = area.sample(500, np.random.default_rng(0))
    assert pts.shape == (500, 2)
    assert np.all(pts >= area.lower) and np.all(pts <= area.upper)
    assert area.contains(pts).all()
    np.testing.assert_array_equal(pts, area.sample(500, np.random.default_rng(0)))
    assert np.all(np.linalg.norm(pts, axis=1) <= L + 1.0)   # within a cell of the arm's reach
    # every recorded reached point really lies in its own cell of the mask
    ok = np.all(np.isfinite(area.cell_points), axis=1)
    assert ok.mean() > 0.99 and area.contains(area.cell_points[ok]).all()
    # bounds that miss the arm entirely: empty grid
    empty = reachable_area(spec, [100, 100], [120, 130])
    assert empty.area() == 0.0 and not empty.mask.any()
    with pytest.raises(ValueError, match="upper"):
        reachable_area(spec, [0, 0], [0, 10])
    with pytest.raises(ValueError, match="resolution"):
        reachable_area(spec, [0, 0], [10, 10], resolution=0.0)
    with pytest.raises(ValueError, match="samples"):
        reachable_area(spec, [0, 0], [10, 10], samples=0)


def test_test_goals_inside_reachable_and_bounds_and_reproducible():
    spec = ArmSpec(dof=7)
    lo, hi = np.array([0.0, -150.0]), np.array([150.0, 150.0])
    goals = make_test_goals(spec, lo, hi, n=100, seed=3)
    assert goals.shape == (100, 2)
    assert np.all(goals >= lo) and np.all(goals <= hi)
    area = reachable_area(spec, lo, hi, seed=3)
    assert area.contains(goals).all()
    assert np.all(np.linalg.norm(goals, axis=1) <= L + 1e-9)   # actually reached tip positions
    assert len(np.unique(goals, axis=0)) == 100
    np.testing.assert_array_equal(goals, make_test_goals(spec, lo, hi, n=100, seed=3))
    np.testing.assert_array_equal(goals, make_test_goals(spec, lo, hi, n=100, seed=3, area=area))
    assert not np.array_equal(goals, make_test_goals(spec, lo, hi, n=100, seed=4))
    # spread over the area: both halves (y<0, y>0) and near/far from the base are represented
    r = np.linalg.norm(goals, axis=1)
    assert 25 < (goals[:, 1] > 0).sum() < 75
    assert (r < 25).sum() > 10 and (r > 35).sum() > 20
    # a smaller box: goals stay inside it
    small = make_test_goals(spec, [0, 0], [20, 20], n=30, seed=0)
    assert np.all(small >= 0) and np.all(small <= 20)


# ------------------------------------------------------------------ validation
@pytest.mark.parametrize("field,value", [
    ("dof", 0), ("dof", 101), ("dof", 2.5), ("total_length", 0.0), ("total_length", float("nan")),
    ("link_profile", "fibonacci"), ("joint_limit", 0.0), ("joint_limit", 4.0), ("base_limit", -1.0),
    ("rest_bend", -0.1), ("mode", "torque"), ("motor_noise", -0.1), ("timestep", 0.0), ("kp", -1.0),
    ("damping", -1.0), ("armature", 0.0), ("arm_mass", 0.0), ("settle_tolerance", 0.0),
    ("settle_velocity", 0.0), ("max_settle_steps", 0), ("settle_check_every", 0),
])
def test_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        ArmSpec(**{field: value}).validate()
    with pytest.raises(ValueError, match=field):
        ArmSpec.from_dict({field: value})
    with pytest.raises(ValueError, match=field):
        ArmSim(ArmSpec(**{field: value}), seed=0)


def test_rest_bend_must_fit_the_limits():
    with pytest.raises(ValueError, match="rest_bend"):
        ArmSpec(dof=3, joint_limit=0.2, rest_bend=1.0).validate()
    with pytest.raises(ValueError, match="rest_bend"):
        ArmSpec(dof=8, base_limit=0.1, rest_bend=1.0).validate()


def test_from_dict():
    spec = ArmSpec.from_dict({"dof": 15, "link_profile": "golden", "kp": 20000, "motor_noise": 0.2})
    assert spec == ArmSpec(dof=15, link_profile="golden", kp=20000.0, motor_noise=0.2)
    assert isinstance(spec.kp, float)
    assert ArmSpec.from_dict(dataclasses.asdict(spec)) == spec
    with pytest.raises(ValueError, match="lenght"):
        ArmSpec.from_dict({"total_lenght": 50.0})


def test_bench_function_returns_rates():
    for mode in ("kinematic", "dynamic"):
        r = bench_arm(4, mode, 30, repeats=1)
        assert r["dof"] == 4 and r["mode"] == mode and r["n"] == 30
        assert r["rate"] > 0 and r["us_per_command"] == pytest.approx(1e6 / r["rate"])
        assert r["unsettled"] == 0
        assert (r["mean_settle_steps"] > 0) == (mode == "dynamic")
