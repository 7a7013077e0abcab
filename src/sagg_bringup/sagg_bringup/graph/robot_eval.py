"""The evaluation on the robot of an external-driver run: the robot behind the driver as a reaching
robot (:class:`ContractRobot`: the learner's command, freshness and settle rules), a time bound per
test goal (:class:`TimedRobot`), and the frozen model reaching the test goals from rest
(:class:`RobotEvaluation`)."""
from __future__ import annotations

import time

import numpy as np

from sagg_common.ros_params import HW_DEPTH, reliable
from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame
from sagg_low_level.evaluate import reach_frozen
from sagg_low_level.learner import SCHEMA, EvolvingContextLearner, step_toward, stepped_move_limit

from .driver_monitor import DriverMonitor
from .processes import GraphError
from .session import GraphSession

# Evaluation on the robot: a command asking a joint to move at least this much (rad) is answered
# only by a state that shows the motion (ContractRobot.command). Our choice: above reading noise.
MOTION_FLOOR = 0.01


class ContractRobot:
    """The robot behind the driver as a :class:`~sagg_low_level.evaluate.ReachingRobot`: a command
    is published on ``/<controller>/commands`` (joint order = ``joints``), and answered by a joint
    state and a task point both stamped more than ``observation_delay`` after the newest ones
    before it, once settled (every |velocity| < ``settle_velocity``) and, stricter than the learner
    node, with a task point sampled no earlier than that joint state and once some joint has moved at
    least half the largest commanded displacement (when that is at least :data:`MOTION_FLOOR`); or
    ``settle_timeout`` s after the command (then the latest fresh state). Every target is clipped to
    the joint limits and to ``max_joint_step`` from the newest measured posture (as the learner's
    commands are); a return to rest, or to where learning paused, is a sequence of such commands
    (:meth:`move_to`), never one jump (a jump at full speed on a position controller)."""

    def __init__(self, session: GraphSession, monitor: DriverMonitor, learner_params: dict,
                 answer_timeout: float = 30.0):
        # lazy (heavy): ROS
        from std_msgs.msg import Float64MultiArray
        from sagg_low_level.node import robot_from_params
        lp = learner_params
        self.session, self.monitor = session, monitor
        self.arm = robot_from_params(lp)
        self.lower, self.upper, self.rest = self.arm.lower, self.arm.upper, self.arm.rest
        self.max_step = float(lp["max_joint_step"])
        self.move_steps = 0  # commands of moves done in steps (returns to rest or to a paused posture)
        self.m = len(lp["task_space.lower"])
        self.delay_ns = int(round(lp["observation_delay"] * 1e9))
        self.settle_timeout = lp["settle_timeout"]
        self.answer_timeout = max(answer_timeout, lp["joint_state_timeout"])
        self._msg = Float64MultiArray
        self.pub = session.node.create_publisher(Float64MultiArray, monitor.cmd_topic, reliable(HW_DEPTH))
        self.commands = 0
        self.timeouts = 0  # answers taken after settle_timeout (not settled, or no motion seen)
        self.trace: list[dict] = []  # every command and its answer (DIR/robot_evaluation.json)
        self.rest_tip: np.ndarray | None = None  # the task point at the last reset

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        return self.monitor.alpha.copy(), self.monitor.tip[: self.m].copy()

    def command(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Publish ``target`` (bounded as the class says) and return the answering (posture, task point)."""
        mon = self.monitor
        # take what is queued first: freshness is judged against the newest state the driver has
        # sent, not an older one still waiting in our queue (and the step bound against the newest posture)
        self.session.spin()
        target = step_toward(mon.alpha, np.asarray(target, float), self.max_step + 1e-9, self.arm)
        js_min, tip_min = mon.js_stamp + self.delay_ns, mon.tip_stamp + self.delay_ns
        before = mon.alpha.copy()
        asked = float(np.abs(target - before).max())
        msg = self._msg()
        msg.data = target.tolist()
        self.pub.publish(msg)
        self.commands += 1
        t0 = time.monotonic()
        settled_at = None  # stamp of the first fresh, settled joint state that shows the motion
        while True:
            self.session.spin()
            fresh = mon.js_stamp > js_min and mon.tip_stamp > tip_min
            waited = time.monotonic() - t0
            # a state that shows no motion is not the answer to a command that asks for one (under
            # load the driver may take the command later than observation_delay after our newest
            # state); position control moves at least half way, even with 20 % motor noise. The
            # last steps of a reach can be below the reading noise: no test under MOTION_FLOOR
            moved = asked < MOTION_FLOOR or float(np.abs(mon.alpha - before).max()) >= 0.5 * asked
            if settled_at is None and mon.js_stamp > js_min and mon.settled and moved:
                settled_at = mon.js_stamp
            # the task point must be sampled no earlier than that joint state: a fresh one of the
            # moving arm may still be queued behind it (measured under load: a reset answered by
            # the rest posture and the tip of half-way)
            done = settled_at is not None and mon.tip_stamp >= settled_at
            if done or (fresh and waited > self.settle_timeout):
                if not done:
                    self.timeouts += 1
                self.trace.append({"t": time.time(), "target": target.tolist(), "before": before.tolist(),
                                   "alpha": mon.alpha.tolist(), "tip": mon.tip[: self.m].tolist(),
                                   "waited": waited, "settled": mon.settled, "moved": moved})
                return self.observe()
            if waited > self.answer_timeout:
                raise GraphError(f"no fresh joint state and task point {waited:.0f} s after a command on "
                                 f"{mon.cmd_topic}: the driver stopped answering")

    def move_to(self, posture: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Go to ``posture`` in commands of at most ``max_joint_step`` per joint from the measured
        posture; answered by the observation after the command that reaches it (or after as many
        steps as the learner's return to rest allows: a joint that does not follow)."""
        posture = np.asarray(posture, float)
        for _ in range(stepped_move_limit(self.arm, self.max_step)):
            target = step_toward(self.monitor.alpha, posture, self.max_step, self.arm)
            self.move_steps += 1
            alpha, y = self.command(target)
            if (target == posture).all():
                break
        return alpha, y

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        alpha, y = self.move_to(self.rest)
        self.rest_tip = y
        return alpha, y


def spread_points(points: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``n`` of ``points`` spread by farthest-point selection (the first one drawn with ``seed``):
    test goals over where the robot has been, when the reachable area is unknown."""
    pts = np.unique(np.asarray(points, float), axis=0)
    if len(pts) <= n:
        return pts
    rng = np.random.default_rng(seed)
    chosen = [int(rng.integers(len(pts)))]
    d = np.linalg.norm(pts - pts[chosen[0]], axis=1)
    while len(chosen) < n:
        i = int(np.argmax(d))
        chosen.append(i)
        d = np.minimum(d, np.linalg.norm(pts - pts[i], axis=1))
    return pts[chosen]


class GoalTimeUp(Exception):
    """A test goal's time on the robot is up (:class:`TimedRobot`)."""


class TimedRobot:
    """A reaching robot whose next command is refused once ``deadline`` (monotonic s) has passed:
    the evaluation's time bound per goal. A command already sent is always completed (the arm
    settles); the bound is checked between commands. The last measured task point is kept, the
    error of a goal whose time ran out."""

    def __init__(self, robot, deadline: float):
        self.robot, self.deadline = robot, deadline
        self.y: np.ndarray | None = None

    def reset(self) -> tuple[np.ndarray, np.ndarray]:
        self._check()
        alpha, self.y = self.robot.reset()
        return alpha, self.y

    def command(self, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._check()
        alpha, self.y = self.robot.command(target)
        return alpha, self.y

    def _check(self) -> None:
        if time.monotonic() > self.deadline:
            raise GoalTimeUp()


class RobotEvaluation:
    """The frozen model reaching test goals from rest on the robot, at the scheduled points
    (``every`` micro-actions, 0 = only at the end) and at the end. Results: ``curve`` (micro-actions,
    the evaluation's metrics of sagg_low_level.eval_metrics: mean, median, share within tolerance,
    mean error per distance-from-base band; the errors of every goal) and the initial error (the
    empty model does not move the arm: the distance from the measured rest tip to each goal). Each
    goal has at most ``goal_seconds`` s on the robot (:class:`TimedRobot`): then its error is the
    distance of the last measured task point, and it is counted (``timed_out``), so an evaluation
    ends whatever the arm does."""

    def __init__(self, learner_params: dict, robot: ContractRobot, n_goals: int, every: int, goals=None,
                 base=None, goal_seconds: float = 120.0):
        self.lp, self.robot, self.n_goals, self.every = learner_params, robot, n_goals, every
        self.goal_seconds = goal_seconds
        self.timed_out = 0  # goals whose time ran out
        self.base = base  # the arm's base in Y (the metric bands; None: the origin)
        self.goals = None if goals is None else np.asarray(goals, float)
        self.goal_source = "the simulated model's test goals" if goals is not None else None
        self.curve: list[dict] = []
        self.initial_errors: np.ndarray | None = None
        self.seconds = 0.0
        self.next_at = every if every > 0 else None

    def choose_goals(self, reached: list[np.ndarray]) -> None:
        """The test goals (once): the simulated model's if given, else spread over ``reached``."""
        if self.goals is None:
            if not reached:
                raise GraphError("no task point recorded: nothing to choose test goals from")
            self.goals = spread_points(np.array(reached), self.n_goals, self.lp["eval.seed"])
            self.goal_source = (f"spread over the {len(reached)} task points the robot reached before "
                                "the first evaluation (no model of the reachable area; not independent "
                                "of exploration)")

    def learner(self, alpha, dalpha, dy):
        """A frozen learner (``EvolvingContextLearner`` with the run's parameters) on the samples."""
        # lazy (heavy): ROS
        from sagg_low_level.node import robot_from_params
        core = {p.name: self.lp[p.name] for p in SCHEMA}
        learner = EvolvingContextLearner(core, robot_from_params(self.lp), len(self.lp["task_space.lower"]))
        for a, da, d in zip(alpha, dalpha, dy):
            learner.memory.add(a, da, d)
        return learner

    def run(self, at: int, alpha, dalpha, dy, reached: list[np.ndarray]) -> np.ndarray:
        """Evaluate the model of the first ``at`` samples on the robot (learning must be paused)."""
        self.choose_goals(reached)
        t0 = time.perf_counter()
        learner = self.learner(alpha[:at], dalpha[:at], dy[:at])
        errors, rest = [], []
        for g in self.goals:
            errors.append(self.reach(learner, g))
            rest.append(float(np.linalg.norm(g - self.robot.rest_tip)))
        self.seconds += time.perf_counter() - t0
        errors = np.array(errors)
        if self.initial_errors is None:
            self.initial_errors = np.array(rest)
        # the evaluation's metrics (sagg_low_level.eval_metrics; bands from the arm's base)
        self.curve.append({"micro_actions": int(at), **error_metrics(errors, self.frame()),
                           "errors": errors.tolist()})
        return errors

    def reach(self, learner, goal: np.ndarray) -> float:
        """One test goal reached from rest within ``goal_seconds`` (the final distance)."""
        timed = TimedRobot(self.robot, time.monotonic() + self.goal_seconds)
        try:
            return reach_frozen(learner, timed, goal)
        except GoalTimeUp:
            self.timed_out += 1
            return float(np.linalg.norm(goal - timed.y)) if timed.y is not None else float("nan")

    def frame(self) -> dict:
        """The metric frame of the test goals (R, tolerance, distance bands; eval_metrics)."""
        return metric_frame(self.goals, np.zeros(self.goals.shape[1]) if self.base is None else self.base)

    def summary(self) -> dict:
        init = self.initial_errors
        return {"label": "on the robot", "goals": None if self.goals is None else self.goals.tolist(),
                "goal_source": self.goal_source, "every": self.every,
                "initial_mean_error": float(init.mean()) if init is not None else float("nan"),
                "initial_errors": None if init is None else init.tolist(),
                "curve": self.curve,
                "final_mean_error": self.curve[-1]["mean_error"] if self.curve else float("nan"),
                "final_median_error": self.curve[-1]["median_error"] if self.curve else float("nan"),
                "final_within_share": self.curve[-1]["within_share"] if self.curve else float("nan"),
                "band_mean_errors": self.curve[-1]["band_mean_errors"] if self.curve else None,
                "eval_metrics": None if self.goals is None else frame_summary(self.frame()),
                "commands": self.robot.commands, "move_steps": self.robot.move_steps,
                "goal_seconds": self.goal_seconds, "goals_timed_out": self.timed_out,
                "settle_timeouts": self.robot.timeouts, "seconds": self.seconds}
