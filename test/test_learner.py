"""Low level with evolving context (paper Sec. 3.3-3.7, Algorithm 3), on analytic robots."""
import numpy as np
import pytest

from sagg_common.params import resolve
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED, KIND_SUBGOAL
from sagg_low_level.evaluate import evaluate
from sagg_low_level.learner import (SCHEMA, Command, EvolvingContextLearner, GoalRequest, Observe,
                                    Robot, safe_target, subgoal_points, timeout_budget)
from sagg_low_level.local_model import desired_displacement, local_jacobian, pseudo_inverse_step


class PlanarArm:
    """Analytic planar arm: y = tip of a chain of links, joints set exactly (ideal position control)."""

    def __init__(self, lengths, rest):
        self.lengths = np.asarray(lengths, float)
        self.rest = np.asarray(rest, float)
        self.alpha = self.rest.copy()
        self.commands = 0

    def fk(self, alpha):
        ang = np.cumsum(alpha)
        return np.array([np.sum(self.lengths * np.cos(ang)), np.sum(self.lengths * np.sin(ang))])

    def reset(self):
        self.alpha = self.rest.copy()
        return self.alpha.copy(), self.fk(self.alpha)

    def observe(self):
        return self.alpha.copy(), self.fk(self.alpha)

    def command(self, target):
        self.commands += 1
        self.alpha = np.asarray(target, float).copy()
        return self.alpha.copy(), self.fk(self.alpha)


class StuckRobot(PlanarArm):
    """Never moves: every micro-action misses, so exploration is always triggered."""

    def command(self, target):
        self.commands += 1
        return self.alpha.copy(), self.fk(self.alpha)


def make_learner(n=3, **kw):
    p = resolve(SCHEMA, {"task_space.lower": [-3.0, -3.0], "task_space.upper": [3.0, 3.0], **kw})
    robot = Robot([f"j{i}" for i in range(n)], np.full(n, -2.5), np.full(n, 2.5),
                  np.full(n, 0.3))
    return EvolvingContextLearner(p, robot, 2)


def drive(learner, robot, goals, micro_actions, reports=None):
    """Answer the learner's requests: goals from a list (cycled), commands from the robot."""
    if reports is not None:
        learner.on_report = reports.append
    coro = learner.run()
    req = next(coro)
    k = 0
    while learner.micro_actions < micro_actions:
        if isinstance(req, Observe):
            ans = robot.observe()
        elif isinstance(req, Command):
            ans = robot.command(req.target)
        elif isinstance(req, GoalRequest):
            k += 1
            ans = (k, np.asarray(goals[(k - 1) % len(goals)], float))
        req = coro.send(ans)
    return coro


# ------------------------------------------------------------------------------ equations
def test_subgoal_positions_are_evenly_spaced_and_end_at_goal():
    pts = subgoal_points(np.array([1.0, 1.0]), np.array([6.0, -4.0]), 5)
    assert len(pts) == 5
    assert np.allclose(pts[0], [2.0, 0.0]) and np.allclose(pts[2], [4.0, -2.0])
    assert np.allclose(pts[-1], [6.0, -4.0])
    assert len(subgoal_points(np.zeros(2), np.ones(2), 1)) == 1


def test_timeout_budget_is_1_5_times_distance_over_speed():
    assert timeout_budget(10.0, 2.0, 1.5) == 8   # ceil(7.5)
    assert timeout_budget(0.0, 2.0, 1.5) == 1


def test_jacobian_recovered_on_linear_map():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(2, 7))
    da = rng.normal(size=(20, 7)) * 0.05
    assert np.allclose(local_jacobian(da, da @ A.T), A, atol=1e-10)


def test_pseudo_inverse_step_hits_the_desired_displacement():
    rng = np.random.default_rng(1)
    J = rng.normal(size=(2, 5))
    dy = np.array([0.3, -0.2])
    dalpha = pseudo_inverse_step(J, dy, rcond=1e-6)
    assert np.allclose(J @ dalpha, dy)
    # minimum norm: orthogonal to J's null space
    null = np.linalg.svd(J)[2][2:]
    assert np.allclose(null @ dalpha, 0, atol=1e-12)


def test_desired_displacement_points_to_goal_and_does_not_overshoot():
    d = desired_displacement(np.array([0.0, 0.0]), np.array([10.0, 0.0]), 2.0)
    assert np.allclose(d, [2.0, 0.0])
    assert np.allclose(desired_displacement(np.zeros(2), np.array([0.5, 0.0]), 2.0), [0.5, 0.0])


def test_safe_target_limits_step_and_joint_range():
    robot = Robot(["a", "b"], np.array([-1.0, -1.0]), np.array([1.0, 1.0]), np.zeros(2))
    t = safe_target(np.zeros(2), np.array([2.0, 1.0]), 0.5, robot)
    assert np.allclose(t, [0.5, 0.25])  # scaled as a whole, direction kept
    t = safe_target(np.array([0.9, 0.0]), np.array([1.3, 0.0]), 0.5, robot)
    assert np.allclose(t, [1.0, 0.0])


# ------------------------------------------------------------------------------- timeouts
def test_distance_timeout_bounds_micro_actions_per_goal():
    learner = make_learner(q=3, exploration_respects_timeout=True, subgoals=1, v=0.1,
                           timeout_factor=1.5, eps_c=0.0)
    robot = StuckRobot([1, 1, 1], np.full(3, 0.3))
    reports = []
    y0 = robot.fk(robot.rest)
    goal = y0 + np.array([1.0, 0.0])       # D = 1, v = 0.1 -> budget ceil(15) = 15
    drive(learner, robot, [goal], 15 * 4, reports)
    goal_reports = [r for r in reports if r.kind == KIND_GOAL]
    assert len(goal_reports) >= 4
    per_goal = np.diff([0] + [r.micro_actions for r in goal_reports])
    assert np.all(per_goal[:4] == 15)
    assert all(r.competence == -1.0 or r.competence < 0 for r in goal_reports)


def test_default_timeout_cuts_exploration_phase_at_the_budget():
    # Sec. 3.6.2: the counter runs through both phases and the budget is a maximum ("up to 1.5
    # times", "including explorative movements"): with the defaults a q = 20 exploration phase
    # must stop when the goal's budget is spent, not run its 20 micro-actions.
    learner = make_learner(q=20, subgoals=1, v=0.1, timeout_factor=1.5, eps_c=0.0)
    assert learner.p["exploration_respects_timeout"] is True
    robot = StuckRobot([1, 1, 1], np.full(3, 0.3))
    reports = []
    goal = robot.fk(robot.rest) + np.array([0.5, 0.0])  # D = 0.5, v = 0.1 -> budget ceil(7.5) = 8
    drive(learner, robot, [goal], 8 * 6, reports)
    ends = [r.micro_actions for r in reports if r.kind == KIND_GOAL]
    assert len(ends) >= 5
    assert np.all(np.diff([0] + ends[:5]) == 8)
    # every micro-action of a goal is counted: 1 reach + 7 exploratory (the first goal: 8
    # exploratory, the memory being empty)
    kinds = [r.kind for r in reports if r.micro_actions <= ends[1]]
    assert kinds.count(KIND_REACHED) == 1 and kinds.count(KIND_EXPLORATION) == 15


@pytest.mark.parametrize("scope, per_goal", [("subgoal", 3 + 5 + 7 + 9 + 11), ("goal", 11)])
def test_timeout_scope_subgoal_or_whole_goal(scope, per_goal):
    # stuck robot, goal at D = 0.9, v = 0.125, 5 points on the path. 'subgoal': each point gets its
    # own budget from where the effector is (it never moves: distances 0.18 ... 0.9 -> ceil of
    # 2.16, 4.32, 6.48, 8.64, 10.8). 'goal': one budget ceil(1.5 × 0.9 / 0.125) = 11 for the whole
    # attempt; the points after it is spent are reported unreached without a micro-action.
    learner = make_learner(q=2, subgoals=5, v=0.125, timeout_factor=1.5, eps_c=0.0,
                           timeout_scope=scope)
    robot = StuckRobot([1, 1, 1], np.full(3, 0.3))
    reports = []
    goal = robot.fk(robot.rest) + np.array([0.9, 0.0])
    drive(learner, robot, [goal], per_goal * 3 + 1, reports)
    ends = [r.micro_actions for r in reports if r.kind == KIND_GOAL]
    assert len(ends) >= 3
    assert np.all(np.diff([0] + ends[:3]) == per_goal)
    firsts = [r for r in reports if r.kind in (KIND_SUBGOAL, KIND_GOAL) and r.micro_actions <= ends[0]]
    assert [r.kind for r in firsts] == [KIND_SUBGOAL] * 4 + [KIND_GOAL]
    assert all(r.competence == -1.0 for r in firsts)


def test_timeout_scope_rejects_unknown_value():
    with pytest.raises(ValueError, match="timeout_scope"):
        make_learner(timeout_scope="attempt")


def test_blocking_timeout_stops_after_w_exploration_phases():
    # stuck robot: every reaching step misses -> an exploration phase each time
    learner = make_learner(q=5, blocking_w=3, subgoals=1, timeout_factor=1000.0, eps_c=0.0, v=0.5,
                           min_samples=2)
    robot = StuckRobot([1, 1, 1], np.full(3, 0.3))
    reports = []
    goal = robot.fk(robot.rest) + np.array([1.0, 0.0])
    drive(learner, robot, [goal], 200, reports)
    ends = [r.micro_actions for r in reports if r.kind == KIND_GOAL]
    # first goal: explore (empty memory) 5 + 2 × (1 reach + 5 explore) = 17
    assert ends[0] == 17
    # later goals: 3 × (1 reach + 5 explore)
    assert np.all(np.diff(ends[:5]) == 18)


def test_rest_reset_every_r_attempts():
    for r in (1, 3):
        learner = make_learner(reset_every=r, subgoals=1)
        arm = PlanarArm([1, 1, 1], np.full(3, 0.3))
        cmds = []
        orig = arm.command
        arm.command = lambda t: (cmds.append(np.array(t)), orig(t))[1]
        rng = np.random.default_rng(0)
        goals = [rng.uniform(-2, 2, 2) for _ in range(50)]
        drive(learner, arm, goals, 400)
        resets = sum(np.array_equal(c, arm.rest) for c in cmds)
        assert resets == -(-learner.attempts // r)


# ------------------------------------------------------------------------------- learning
def test_reaching_converges_on_analytic_arm():
    """SAGG-style learning toward goals on a 3-link arm, then frozen-model reaching is accurate."""
    learner = make_learner(v=0.2, q=10, explore_amplitude=0.05, subgoals=3)
    arm = PlanarArm([1.0, 0.8, 0.6], np.array([0.3, 0.4, 0.4]))
    rng = np.random.default_rng(4)

    def reachable_goal():
        return arm.fk(rng.uniform(-1.2, 1.2, 3) + np.array([0.3, 0.4, 0.4]))
    goals = [reachable_goal() for _ in range(400)]
    test = np.array([reachable_goal() for _ in range(30)])
    initial = np.linalg.norm(test - arm.fk(arm.rest), axis=1).mean()
    drive(learner, arm, goals, 6000)
    errors = evaluate(learner, PlanarArm(arm.lengths, arm.rest), test)
    assert errors.mean() < 0.1 * initial
    assert np.median(errors) < 0.05


def test_every_micro_action_is_stored_and_reported():
    learner = make_learner(q=4)
    arm = PlanarArm([1, 1, 1], np.full(3, 0.3))
    reports = []
    drive(learner, arm, [np.array([1.0, 1.0]), np.array([-1.0, 1.5])], 300, reports)
    point_reports = [r for r in reports if r.kind in (KIND_REACHED, KIND_EXPLORATION)]
    assert len(learner.memory) == learner.micro_actions == len(point_reports)
    assert [r.seq for r in reports] == list(range(1, len(reports) + 1))
    assert {KIND_SUBGOAL, KIND_GOAL} <= {r.kind for r in reports}
    # Δα and Δy are exactly what the robot did
    a, da, dy = learner.memory.alpha, learner.memory.delta_alpha, learner.memory.delta_y
    assert np.allclose(arm.fk(a[5] + da[5]) - arm.fk(a[5]), dy[5])


@pytest.mark.parametrize("strategy", ["sagg-riac", "actuator-random", "actuator-riac"])
def test_same_seed_gives_identical_memory(strategy):
    def digest(seed):
        learner = make_learner(strategy=strategy, seed=seed)
        drive(learner, PlanarArm([1, 1, 1], np.full(3, 0.3)), [np.array([1.0, 1.0])], 500)
        return learner.memory.digest()
    assert digest(3) == digest(3)
    assert digest(3) != digest(4)


def test_actuator_random_returns_to_rest_every_max():
    learner = make_learner(strategy="actuator-random", actuator_reset_every=25)
    arm = PlanarArm([1, 1, 1], np.full(3, 0.3))
    cmds = []
    orig = arm.command
    arm.command = lambda t: (cmds.append(np.array(t)), orig(t))[1]
    drive(learner, arm, [], 100)
    rest_idx = [i for i, c in enumerate(cmds) if np.array_equal(c, arm.rest)]
    assert np.all(np.diff(rest_idx) == 26)  # 25 micro-actions + the reset command
    steps = np.abs(learner.memory.delta_alpha)
    assert steps.max() <= learner.p["explore_amplitude"] + 1e-12


def test_actuator_reset_period_derived_from_task_space():
    learner = make_learner(strategy="actuator-random", v=0.5)
    learner.rest_y = np.array([0.0, 0.0])
    # farthest corner of [-3,3]^2 from the origin: 3√2 -> ceil(8.49) = 9
    assert learner.actuator_reset_period() == 9


def test_actuator_riac_builds_regions_over_alpha_dalpha():
    learner = make_learner(strategy="actuator-riac", **{"riac.g_max": 20})
    drive(learner, PlanarArm([1, 1, 1], np.full(3, 0.3)), [], 600)
    tree = learner.riac_tree
    assert tree.dim == 6 and len(tree.leaves()) > 5
    assert sum(r.count for r in tree.leaves()) == 600
