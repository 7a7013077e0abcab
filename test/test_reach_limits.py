"""Arm geometry by link ratio, reaching that respects joint limits (clamping and
re-solving), the blocking timeout's scope, and where a run's micro-actions went."""
import math

import numpy as np
import pytest

from sagg_common.params import resolve
from sagg_common.report_kinds import KIND_GOAL, KIND_SUBGOAL
from sagg_low_level.evaluate import reach_frozen
from sagg_low_level.learner import SCHEMA, EvolvingContextLearner, Robot
from sagg_low_level.local_model import clamp_rounds, clamped_step, damped_steps, pseudo_inverse_step
from sagg_sim_bridge.arm import GOLDEN_RATIO, ArmSim, ArmSpec, forward_kinematics, tip_jacobian

from test_learner import StuckRobot, drive, make_learner
from installed import SAGG


# ------------------------------------------------------------------------------ link_ratio
def test_link_ratio_geometry_matches_hand_computed_tips():
    # ratio 2, total 7: links 4, 2, 1
    spec = ArmSpec(dof=3, total_length=7.0, link_ratio=2.0, joint_limit=math.pi, base_limit=math.pi,
                   rest_bend=0.5)
    assert np.allclose(spec.link_lengths(), [4.0, 2.0, 1.0])
    sim = ArmSim(spec, seed=0)
    h = math.pi / 2
    cases = {(0.0, 0.0, 0.0): (7.0, 0.0),            # straight along +x
             (h, 0.0, 0.0): (0.0, 7.0),              # straight along +y
             (0.0, h, h): (4.0 - 1.0, 2.0),          # 4 along x, 2 along y, 1 along -x
             (0.0, h, -h): (4.0 + 1.0, 2.0),         # 4 along x, 2 along y, 1 along +x
             (h, -h, -h): (2.0, 4.0 - 1.0)}          # 4 along y, 2 along x, 1 along -y
    for alpha, tip in cases.items():
        _, y = sim.command(np.array(alpha))          # MuJoCo's kinematics
        assert np.allclose(y, tip, atol=1e-9), (alpha, y, tip)
        assert np.allclose(forward_kinematics(np.array([alpha]), spec.link_lengths())[0], tip, atol=1e-12)


def test_link_ratio_generalises_link_profile_bit_for_bit():
    for dof in (1, 7, 15, 30):
        assert np.array_equal(ArmSpec(dof=dof, link_profile="golden").link_lengths(),
                              ArmSpec(dof=dof, link_ratio=GOLDEN_RATIO).link_lengths())
        assert np.array_equal(ArmSpec(dof=dof).link_lengths(), ArmSpec(dof=dof, link_ratio=1.0).link_lengths())
    lengths = ArmSpec(dof=7, total_length=1.0, link_ratio=1.5).link_lengths()
    assert lengths.sum() == pytest.approx(1.0)
    assert np.allclose(lengths[:-1] / lengths[1:], 1.5)


@pytest.mark.parametrize("bad", [{"link_ratio": -1.0}, {"link_ratio": 0.001}, {"link_ratio": 101.0},
                                 {"link_ratio": 1.5, "link_profile": "golden"}])
def test_link_ratio_rejects_bad_values(bad):
    with pytest.raises(ValueError, match="link_ratio"):
        ArmSpec(dof=7, **bad).validate()


def test_tip_jacobian_matches_finite_differences():
    spec = ArmSpec(dof=7, total_length=1.0, link_ratio=1.5)
    rng = np.random.default_rng(3)
    lengths = spec.link_lengths()
    for _ in range(5):
        a = rng.uniform(-1, 1, 7)
        num = np.stack([(forward_kinematics((a + e)[None], lengths)[0]
                         - forward_kinematics((a - e)[None], lengths)[0]) / 2e-6
                        for e in np.eye(7) * 1e-6], axis=1)
        assert np.allclose(tip_jacobian(a, lengths), num, atol=1e-7)


def test_zigzag_rest_alternates_and_keeps_the_tip_on_x():
    spec = ArmSpec(dof=7, total_length=1.0, link_ratio=1.5, joint_limit=math.pi / 3,
                   base_limit=math.pi / 3, rest_shape="zigzag", rest_bend=0.6)
    rest = spec.rest_posture()
    assert np.allclose(rest[1:], 0.1 * np.array([1, -1, 1, -1, 1, -1]))
    tip = forward_kinematics(rest[None], spec.link_lengths())[0]
    assert abs(tip[1]) < 1e-12 and tip[0] > 0.99
    with pytest.raises(ValueError, match="rest_shape"):
        ArmSpec(rest_shape="spiral").validate()


# ------------------------------------------------------------------------------ clamping
def test_clamped_step_is_the_pseudo_inverse_step_when_no_limit_is_in_the_way():
    rng = np.random.default_rng(0)
    jac = rng.normal(size=(2, 5))
    dy = np.array([0.01, -0.02])
    a = np.zeros(5)
    assert np.allclose(clamped_step(jac, dy, a, np.full(5, -1.0), np.full(5, 1.0), 1e-6),
                       pseudo_inverse_step(jac, dy, 1e-6))


def test_clamped_step_stops_a_joint_at_its_limit_and_redistributes():
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(2, 5))
    dy = np.array([0.3, 0.1])
    plain = pseudo_inverse_step(jac, dy, 1e-6)
    i = int(np.argmax(np.abs(plain)))
    lower, upper = np.full(5, -10.0), np.full(5, 10.0)
    a = np.zeros(5)
    # put joint i's limit right where it is, in the direction the plain step moves it
    (upper if plain[i] > 0 else lower)[i] = 0.0
    step = clamped_step(jac, dy, a, lower, upper, 1e-6)
    assert step[i] == 0.0                                  # the saturated joint stays at its limit
    assert np.allclose(jac @ step, dy)                     # the others still make the whole move
    clipped = np.clip(a + plain, lower, upper) - a         # the old reacher: clipped, not re-solved
    assert np.linalg.norm(jac @ clipped - dy) > 1e-3



def _rounds_only(jac, dy, a, lower, upper, rcond, damping):
    """clamped_step without its shortcut: every step through the rounds."""
    rounds = clamp_rounds(jac, dy, a, lower, upper)
    cols, target = next(rounds)
    try:
        while True:
            cols, target = rounds.send(pseudo_inverse_step(cols, target, rcond, damping))
    except StopIteration as done:
        return done.value


@pytest.mark.parametrize("damping", [0.0, 0.3])
def test_clamped_step_shortcut_gives_the_rounds_floats(damping):
    # steps inside the limits take the shortcut, the others the rounds started with that step:
    # both must equal the rounds alone, bit for bit (the learning runs before/after are identical)
    rng = np.random.default_rng(5)
    lower, upper = np.full(7, -1.0), np.full(7, 1.0)
    inside = beyond = 0
    for _ in range(300):
        jac = rng.normal(size=(2, 7))
        dy = rng.normal(size=2) * rng.choice([0.01, 0.5])
        a = rng.uniform(-1.0, 1.0, 7)
        plain = pseudo_inverse_step(jac, dy, 1e-10, damping)
        beyond_now = bool(((a + plain > upper) | (a + plain < lower)).any())
        inside, beyond = inside + (not beyond_now), beyond + beyond_now
        got = clamped_step(jac, dy, a, lower, upper, 1e-10, damping)
        assert got.tobytes() == _rounds_only(jac, dy, a, lower, upper, 1e-10, damping).tobytes()
    assert inside > 30 and beyond > 30

def _limit_goals(sim, count, joint, seed):
    """Tips of random postures with ``joint`` at its upper limit: goals that need it there."""
    rng = np.random.default_rng(seed)
    post = rng.uniform(sim.lower, sim.upper, (count, sim.n_joints))
    post[:, joint] = sim.upper[joint]
    return sim.tip_positions(post)


@pytest.mark.parametrize("mode", ["clamp", "clip"])
def test_reacher_with_analytic_jacobian_reaches_goals_that_need_a_joint_at_its_limit(mode):
    spec = ArmSpec(dof=4, total_length=4.0, joint_limit=math.pi / 4, base_limit=math.pi / 2, rest_bend=0.6)
    sim = ArmSim(spec, 0)
    p = resolve(SCHEMA, {"reach_limits": mode, "v": 0.1, "task_space.lower": [-4.0, -4.0],
                         "task_space.upper": [4.0, 4.0], "eval.tolerance": 1e-4,
                         "eval.timeout_factor": 3.0})
    learner = EvolvingContextLearner(p, Robot(sim.joint_names, sim.lower, sim.upper, sim.rest), 2)
    learner.jacobian_at = lambda a: tip_jacobian(a, sim.link_lengths)  # the true Jacobian
    errors = np.array([reach_frozen(learner, sim, g) for g in _limit_goals(sim, 100, 2, seed=1)])
    if mode == "clamp":
        assert errors.max() < 1e-3
    else:  # the old reacher (clipped J⁺ steps) stalls against the limit on some of them
        assert (errors > 1e-3).sum() >= 2


# ------------------------------------------------------------------------------ blocking scope
@pytest.mark.parametrize("scope", ["goal", "subgoal"])
def test_blocking_declares_the_goal_or_only_the_subgoal_unreached(scope):
    learner = make_learner(q=5, blocking_w=3, subgoals=3, timeout_factor=1000.0, eps_c=0.0, v=0.5,
                           min_samples=2, blocking_scope=scope)
    robot = StuckRobot([1, 1, 1], np.full(3, 0.3))
    reports = []
    goal = robot.fk(robot.rest) + np.array([1.5, 0.0])
    drive(learner, robot, [goal], 300, reports)
    ends = [r.micro_actions for r in reports if r.kind in (KIND_GOAL, KIND_SUBGOAL)]
    per_point = np.diff(ends[3:9])  # second and third attempts: 3 points each
    if scope == "goal":   # blocked on its first subgoal: the other two points cost nothing
        assert list(per_point) == [0, 0, 18, 0, 0]
    else:                 # every point is blocked on its own: 3 × (1 reach + 5 explore) each
        assert list(per_point) == [18, 18, 18, 18, 18]


# ------------------------------------------------------------------------------ phases
def test_result_says_where_the_micro_actions_went(tmp_path):
    from sagg_bringup.graph.setups import run_experiment
    res = run_experiment("config/arm7_ratio15.yaml", "sagg-riac", 0, 600, 600, tmp_path, progress=False)
    ph = res["phases"]
    assert ph["reach"] + ph["explore"] + ph["babble"] == res["micro_actions"] == 600
    assert ph["babble"] == 0 and ph["reach"] > 0 and ph["explore"] > 0
    # reset_every 1: one return to rest per attempt; every attempt's micro-actions are split
    # between goals inside and outside the reachable area
    assert ph["rest_returns"] == len(res["goals"])
    split = ph["reachable_goals"], ph["unreachable_goals"]
    assert sum(s["goals"] for s in split) == len(res["goals"])
    assert sum(s["reach"] + s["explore"] for s in split) == 600
    cov = res["coverage"]
    assert 0 <= cov["median"] <= cov["max"] and 0 <= cov["mean"] <= cov["max"]


# ------------------------------------------------------------------------------ damped inverse
def test_damped_step_is_the_closed_form_and_the_same_alone_or_in_a_stack():
    rng = np.random.default_rng(5)
    jac = rng.normal(size=(2, 7))
    dy = np.array([0.03, -0.01])
    lam = 0.3
    closed = jac.T @ np.linalg.inv(jac @ jac.T + lam ** 2 * np.eye(2)) @ dy
    assert np.allclose(pseudo_inverse_step(jac, dy, 1e-2, lam), closed, atol=1e-12)
    # minimises ||J Δα − Δy||² + λ²||Δα||²: any other step costs more
    step = pseudo_inverse_step(jac, dy, 1e-2, lam)
    def cost(d):
        return np.sum((jac @ d - dy) ** 2) + lam ** 2 * np.sum(d ** 2)
    assert all(cost(step) < cost(step + 1e-4 * rng.normal(size=7)) for _ in range(20))
    # damping 0 is the paper's J⁺ step, numpy's pinv, the same floats
    assert pseudo_inverse_step(jac, dy, 1e-2).tobytes() == (np.linalg.pinv(jac, rcond=1e-2) @ dy).tobytes()
    # a stack gives each row's own floats (the batched evaluation relies on it)
    stack, dys = rng.normal(size=(4, 2, 7)), rng.normal(size=(4, 2))
    for j in range(4):
        assert damped_steps(stack, dys, lam)[j].tobytes() == pseudo_inverse_step(stack[j], dys[j], 1e-2, lam).tobytes()


def test_damped_step_stays_small_near_a_singularity_where_the_plain_one_explodes():
    lengths = ArmSpec(dof=7, total_length=1.0, link_ratio=1.5).link_lengths()
    nearly_straight = np.array([0.0, 0.01, -0.01, 0.01, -0.01, 0.01, -0.01])
    jac = tip_jacobian(nearly_straight, lengths)
    dy = np.array([-0.04, 0.0])                    # straight in toward the base: the singular direction
    lam = 0.3
    plain = pseudo_inverse_step(jac, dy, 1e-6)
    damped = pseudo_inverse_step(jac, dy, 1e-6, lam)
    assert np.linalg.norm(plain) > 1.0             # J⁺: radians for a 0.04 move
    assert np.linalg.norm(damped) <= np.linalg.norm(dy) / (2 * lam) + 1e-12  # the DLS bound
    # away from the singular direction the damped step still moves the tip the requested way
    side = np.array([0.0, -0.04])
    moved = jac @ pseudo_inverse_step(jac, side, 1e-6, lam)
    assert moved[1] < -0.03 and abs(moved[0]) < 1e-3


def test_reach_damping_is_in_units_of_v_over_the_largest_exploratory_micro_action():
    p = resolve(SCHEMA, {"reach_damping": 2.0, "v": 0.04, "explore_amplitude": 0.05,
                         "task_space.lower": [-1.0, -1.0], "task_space.upper": [1.0, 1.0]})
    learner = EvolvingContextLearner(p, Robot([f"j{i}" for i in range(7)], np.full(7, -1.0),
                                              np.full(7, 1.0), np.zeros(7)), 2)
    assert learner.damping == pytest.approx(2.0 * 0.04 / (0.05 * math.sqrt(7)))
    p["reach_damping"] = 0.0
    assert EvolvingContextLearner(p, learner.robot, 2).damping == 0.0


# Goals beside the base on the y < 0 side of config/arm7_ratio15.yaml's arm, beyond the base joint's
# −π/3: every inverse-kinematics solution curls the arm clockwise (joints 1-3 at −π/3), the opposite
# of the counter-clockwise arc rest (docs/notes/reaching-joint-limits.md).
CLOCKWISE_GOALS = np.array([[0.151, -0.42], [-0.236, -0.389], [0.081, -0.54], [-0.212, -0.673],
                            [-0.114, -0.636]])


def _arm7_reach(rest_shape, damping, goals):
    spec = ArmSpec(dof=7, total_length=1.0, link_ratio=1.5, joint_limit=math.pi / 3,
                   base_limit=math.pi / 3, rest_shape=rest_shape)
    sim = ArmSim(spec, 0)
    p = resolve(SCHEMA, {"v": 0.04, "eps_c": 0.002, "eval.tolerance": 0.0002, "reach_damping": damping,
                         "task_space.lower": [-0.5, -1.0], "task_space.upper": [1.0, 1.0]})
    learner = EvolvingContextLearner(p, Robot(sim.joint_names, sim.lower, sim.upper, sim.rest), 2)
    learner.jacobian_at = lambda a: tip_jacobian(a, sim.link_lengths)  # the true Jacobian
    return np.array([reach_frozen(learner, sim, g) for g in goals])


def test_clockwise_curl_goals_need_a_rest_without_net_curl_and_the_damped_inverse():
    # the paper's J⁺ from the counter-clockwise arc rest curls the arm further the wrong way
    assert np.all(_arm7_reach("arc", 0.0, CLOCKWISE_GOALS) > 0.03)
    # from the zigzag rest (no net curl) J⁺'s huge radial steps bend joint 1 counter-clockwise first
    assert np.sum(_arm7_reach("zigzag", 0.0, CLOCKWISE_GOALS) > 0.03) >= 4
    # zigzag rest + damped inverse: the tangential motion curls the arm toward the goal's side
    assert np.all(_arm7_reach("zigzag", 1.0, CLOCKWISE_GOALS) < 1e-3)


def test_arm7_ratio15_reaches_its_test_goals_with_the_true_jacobian_and_the_paper_rest_does_not():
    from sagg_lab.quality import analytic_reach
    cfg = "config/arm7_ratio15.yaml"
    now = analytic_reach(cfg, modes=("clamp",))["clamp"]          # zigzag rest + reach_damping 1
    assert now["mean"] <= 0.001                                  # the arm's target error
    paper = analytic_reach(cfg, {"arm.rest_shape": "arc", "reach_damping": 0.0,
                                 "eval.timeout_factor": 5.0}, modes=("clamp",))["clamp"]
    assert paper["mean"] > 0.05 and paper["missed"] >= 15        # the clockwise-curl goals


def test_graph_learner_reaches_with_the_damped_inverse_like_the_in_process_run(tmp_path):
    """config/arm7_ratio15.yaml (zigzag rest, reach_damping 1) through `sagg run`: the learner node
    takes the damped step and Inefficient's aim exactly as in-process (same samples, same curve)."""
    import json
    import subprocess
    from sagg_bringup.graph.setups import run_experiment
    sagg = SAGG
    out = tmp_path / "run"
    proc = subprocess.run([sagg, "run", "config/arm7_ratio15.yaml", "--micro-actions", "200", "--eval-every",
                           "200", "--out", str(out), "--quiet", "--no-report"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["config"]["sagg_learner"]["reach_damping"] == 1.0
    r = run_experiment("config/arm7_ratio15.yaml", None, None, 200, 200, None, progress=False)
    assert s["memory"]["digest"] == r["memory"]["digest"] and s["curve"] == r["curve"]
    # and the damping matters: the paper's J⁺ learns other samples from the same seed
    r0 = run_experiment("config/arm7_ratio15.yaml", None, None, 200, 200, None, progress=False,
                        overrides={"reach_damping": 0.0})
    assert r0["memory"]["digest"] != r["memory"]["digest"]
