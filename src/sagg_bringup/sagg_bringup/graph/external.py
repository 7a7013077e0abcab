"""``sagg run CONFIG --driver external``: the goal generator and the learner against a robot driver
that is already running (your arm's ros2_control stack, a tracker, or ``test/fake_driver.py``).

Like :func:`~sagg_bringup.graph.graph.run_graph` (same session: private ``ROS_DOMAIN_ID`` unless
``--domain-id`` names the driver's, recorder, progress, summary and report), except:

- no bridge is started; before the nodes start, the driver's side of the contract is checked and
  what is missing is named (:class:`DriverMonitor`: topic, type, joint names), every few seconds,
  until ``driver_timeout``;
- the learner's ``joints`` / ``joint_limits`` / ``rest_posture`` are the config's when it sets
  ``joints`` (your arm), else those of the config's simulated arm;
- **evaluation on the robot** (:class:`RobotEvaluation`): with learning paused (at the end, the
  learner has stopped at ``max_micro_actions``; in between, ``/sagg/pause``), each test goal is
  reached from rest with the frozen model *through the driver* (:class:`ContractRobot`: the same
  commands, freshness and settle rules as the learner node, joint limits and ``max_joint_step``),
  and the final distance is measured by the task-point topic. ``robot_eval_goals`` goals, at the
  end and every ``robot_eval_every`` micro-actions (0: only at the end; real robots are slow);
- **simulated evaluation**, labelled as such: when the config's simulated arm is the same arm (same
  number of joints, limits and rest posture; :func:`sim_model_matches`), the offline evaluation of
  ``sagg run`` from the recorded samples, on the model's 100 test goals, is given too.

Test goals on the robot: the simulated model's test-goal set (``test_goals(spec, Y, n, eval.seed)``)
when there is one; else (the reachable area is unknown) ``n`` points spread by farthest-point
selection (seeded by ``eval.seed``) over the task points the robot reached before the first
evaluation, which is stated in the summary (``robot_evaluation.goal_source``): such goals are
reachable but not independent of the exploration.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError, read_config
from sagg_common.progress import Progress
from sagg_common.ros_params import HW_DEPTH, reliable
from sagg_common.joint_intake import AMBIGUOUS, OTHER, TAKEN
from sagg_common.sources import ACCEPT, AMBIGUOUS as SOURCES_AMBIGUOUS, NO_INFO, SourceChains, with_message_info
from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame
from sagg_low_level.evaluate import reach_frozen
from sagg_low_level.learner import EvolvingContextLearner, SCHEMA, step_toward, stepped_move_limit
from sagg_low_level.schema import joint_intake

from ..inprocess.arm_params import NODES, graph_params
from ..inprocess.evaluator import Evaluator
from ..report.report import arm_rows, write_report
from ..bags.topics import graph_topics
from .arm_run import ArmStreams, plan_arm_run
from .processes import GraphError
from .run_file import write_run_file
from .session import STALL_TIMEOUT, FollowedEvaluation, GraphSession

JS_TYPE = "sensor_msgs/msg/JointState"
TIP_TYPE = "geometry_msgs/msg/PointStamped"
CMD_TYPE = "std_msgs/msg/Float64MultiArray"
EXTERNAL_NODES = {k: v for k, v in NODES.items() if k != "sagg_sim_bridge"}
# Evaluation on the robot: a command asking a joint to move at least this much (rad) is answered
# only by a state that shows the motion (ContractRobot.command). Our choice: above reading noise.
MOTION_FLOOR = 0.01
# Seconds between two "waiting for the driver" lines.
WAIT_REPORT_EVERY = 5.0


# ------------------------------------------------------------------------------ parameters
def explicit_joints(config_path: str | Path, overrides: dict[str, Any] | None) -> bool:
    """True when the config (learner section or ``/**``) or an override sets ``joints``: the
    learner then uses the config's joints, limits and rest posture (your arm)."""
    sections = read_config(config_path)
    return any("joints" in sections.get(s, {}) for s in ("/**", "sagg_learner")) or "joints" in (overrides or {})


def external_params(full: dict[str, dict], micro_actions: int, own_joints: bool, spec=None) -> dict[str, dict]:
    """The nodes' parameters for an external driver: :func:`~sagg_bringup.inprocess.arm_params.graph_params`, but
    the learner keeps the config's ``joints`` / ``joint_limits`` / ``rest_posture`` when
    ``own_joints`` (they are checked here, before anything starts); ``spec``: the config's arm, when
    the caller has it."""
    # lazy (heavy): ROS
    from sagg_low_level.node import robot_from_params
    if full["sagg_learner"].get("rest_return") == "direct":
        raise ConfigError("parameter 'rest_return': 'direct' (one command across the range to the rest "
                          "posture) is for the simulated bridge only; allowed with --driver external: 'stepped'")
    params = graph_params(full, micro_actions, "lockstep", spec)
    params["sagg_learner"]["rest_return"] = "stepped"
    if own_joints:
        lp = params["sagg_learner"]
        for k in ("joints", "joint_limits.lower", "joint_limits.upper", "rest_posture"):
            lp[k] = full["sagg_learner"][k]
        robot_from_params(lp)  # ConfigError naming the parameter
    return params


def sim_model_matches(learner_params: dict, spec) -> bool:
    """The config's simulated arm (``spec``) is a model of the learner's arm: same number of joints,
    same joint limits and rest posture (to 1e-9 rad). Joint names may differ (a driver names its
    joints its own way); link lengths cannot be checked here, the config states them."""
    lower, upper = spec.limits()
    lp = learner_params
    if len(lp["joints"]) != len(spec.joint_names()):
        return False
    return all(np.allclose(np.asarray(lp[k], float), v, rtol=0.0, atol=1e-9) for k, v in (
        ("joint_limits.lower", lower), ("joint_limits.upper", upper), ("rest_posture", spec.rest_posture())))


# ------------------------------------------------------------------------------ the driver
class DriverMonitor:
    """What the driver publishes, from this process's own subscriptions (:meth:`subscribe`): joint
    states read by the learners' one intake (:class:`~sagg_common.joint_intake.JointStateIntake`,
    with the learner parameters ``lp``: mapped by name, checked, one source, stamps), the newest
    task point and its stamp, receive times; and :meth:`missing`, the contract items not yet met,
    each naming topic, type or joints. A JointState naming none of the joints is another driver's
    and ignored (its name list is kept for the report), and while the joints (or the task points)
    come from two sources (:class:`~sagg_common.sources.SourceChains`) nothing of that stream is
    taken: the evaluation on the robot commands from these readings."""

    def __init__(self, lp: dict, task_topic: str, cmd_topic: str, task_fk=None):
        self.joints = list(lp["joints"])
        self.task_topic, self.cmd_topic = task_topic, cmd_topic
        self.intake = joint_intake(lp, self.joints, lp["joint_limits.lower"], lp["joint_limits.upper"])
        self.js_names: list[str] | None = None   # names of the last joint state carrying our joints
        self.rejected: dict[str, int] = {}       # joint states not taken for their content, per kind
        self.alpha: np.ndarray | None = None
        self.js_stamp = -1
        self.settled = False
        self.tip: np.ndarray | None = None
        self.tip_stamp = -1
        self.js_count = self.tip_count = 0
        self.cmd_rx = 0.0  # receive time (monotonic) of the last message on the commands topic
        self.js_rx: list[float] = []  # receive times (monotonic) of the last joint states
        self.tip_rx: list[float] = []
        self.tip_sources = SourceChains(lp["plausibility.source_grace"])
        self.rejected_sources = {"/joint_states": 0, task_topic: 0}  # messages refused: two sources
        self.on_tip = None  # called with each accepted task point (xyz array)
        # task_source 'model' (a TaskFromJoints): the task point is computed from each accepted
        # joint state, as the learner does; no task topic
        self.task_fk = task_fk

    @property
    def other_names(self) -> dict[tuple, int]:
        """Name lists without any of our joints -> messages (another driver's: ignored)."""
        return self.intake.other_joints

    def subscribe(self, node) -> None:
        """This monitor's subscriptions on ``node`` (with the message info: the sources)."""
        # lazy (heavy): ROS
        from geometry_msgs.msg import PointStamped
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        node.create_subscription(JointState, "/joint_states", with_message_info(self.on_joint_state), reliable(100),
                                 raw=True)
        if self.task_fk is None:
            node.create_subscription(PointStamped, self.task_topic, with_message_info(self.on_task_point),
                                     reliable(100))
        node.create_subscription(Float64MultiArray, self.cmd_topic, self.on_command, reliable(100))

    @staticmethod
    def _stamp(msg) -> int:
        return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)

    def on_joint_state(self, data: bytes, info: dict = NO_INFO) -> None:
        """One raw JointState (the intake's verdict; counted when not taken)."""
        intake = self.intake
        verdict = intake.take(data, info["publication_sequence_number"])
        if verdict.code is OTHER:
            return
        if intake.names is not None:
            self.js_names = list(intake.names)
        self.js_count += 1
        self.js_rx = (self.js_rx + [time.monotonic()])[-200:]
        if verdict.code is AMBIGUOUS:
            self.rejected_sources["/joint_states"] += 1
        elif verdict.code is not TAKEN and verdict.kind:
            self.rejected[verdict.kind] = self.rejected.get(verdict.kind, 0) + 1
        if verdict.code is not TAKEN:
            return
        self.alpha, self.js_stamp, self.settled = intake.position, intake.stamp, intake.settled
        if self.task_fk is not None:
            self._take_tip(np.append(self.task_fk.point(self.alpha), [0.0] * (3 - self.task_fk.task_dim)),
                           self.js_stamp)

    def on_command(self, msg) -> None:  # noqa: ARG002 - only its time matters
        self.cmd_rx = time.monotonic()

    def on_task_point(self, msg, info: dict = NO_INFO) -> None:
        p = np.array([msg.point.x, msg.point.y, msg.point.z])
        st = self._stamp(msg)
        self.tip_count += 1
        self.tip_rx = (self.tip_rx + [time.monotonic()])[-200:]
        if self._refused(self.tip_sources, self.task_topic, info):
            return
        if np.all(np.isfinite(p)) and st >= self.tip_stamp:
            self._take_tip(p, st)

    def _take_tip(self, p: np.ndarray, st: int) -> None:
        self.tip, self.tip_stamp = p, st
        if self.task_fk is not None:
            self.tip_count += 1
            self.tip_rx = (self.tip_rx + [time.monotonic()])[-200:]
        if self.on_tip is not None:
            self.on_tip(p)

    def _refused(self, chains: SourceChains, topic: str, info: dict) -> bool:
        """Whether a message is not taken for its source (two sources: counted; a gap: not)."""
        verdict = chains.classify(info["publication_sequence_number"], time.monotonic())
        if verdict == SOURCES_AMBIGUOUS:
            self.rejected_sources[topic] += 1
        return verdict != ACCEPT

    def two_sources(self) -> list[str]:
        """The streams that have two live sources now, in words (empty: none)."""
        now = time.monotonic()
        return [f"{t}: {what} from two sources" for t, what, c in (
            ("/joint_states", "the joints " + ", ".join(self.joints), self.intake.sources),
            (self.task_topic, "task points", self.tip_sources)) if c.ambiguous(now)]

    def missing(self, node, own_node: str = "sagg_run") -> list[str]:
        """The contract items not met yet (empty: the driver is ready), in words."""
        out = []
        js_any = self.js_count + sum(self.other_names.values())  # (messages of other joints count as arrived)
        streams = [("/joint_states", JS_TYPE, js_any)] + ([] if self.task_fk is not None else
                                                          [(self.task_topic, TIP_TYPE, self.tip_count)])
        for topic, kind, count in streams:
            pubs = node.get_publishers_info_by_topic(topic)
            wrong = sorted({p.topic_type for p in pubs if p.topic_type != kind})
            if not pubs:
                out.append(f"{topic} ({kind}): no publisher")
            elif wrong:
                out.append(f"{topic}: published as {', '.join(wrong)}; expected {kind}")
            elif count == 0:
                out.append(f"{topic} ({kind}): a publisher but no message received (it must be reliable "
                           "and publish continuously, or at least once)")
        names = self.js_names
        if names is None and self.other_names:  # only other joints so far: name what came
            names = list(next(reversed(self.other_names)))
        if names is not None:
            lacking = [j for j in self.joints if j not in names]
            if lacking:
                out.append(f"/joint_states lacks joint(s) {', '.join(lacking)} (it names "
                           f"{', '.join(names) or 'none'}; the learner's 'joints': {', '.join(self.joints)})")
            elif self.alpha is None:
                out.append("/joint_states: no valid message yet (one finite position per name, stamps not "
                           "decreasing)")
        out += self.two_sources()
        subs = [s for s in node.get_subscriptions_info_by_topic(self.cmd_topic) if s.node_name != own_node]
        wrong = sorted({s.topic_type for s in subs if s.topic_type != CMD_TYPE})
        if not subs:
            out.append(f"{self.cmd_topic} ({CMD_TYPE}): no subscriber (the driver's position controller)")
        elif wrong:
            out.append(f"{self.cmd_topic}: subscribed as {', '.join(wrong)}; expected {CMD_TYPE}")
        return out

    @staticmethod
    def rate(rx: list[float]) -> float:
        """Messages per second over the recent receive times."""
        return (len(rx) - 1) / (rx[-1] - rx[0]) if len(rx) > 1 and rx[-1] > rx[0] else float("nan")


def model_task(lp: dict):
    """The learner's ``task_source: model`` as this process computes it too (a TaskFromJoints), or
    None (the task point comes from task_topic)."""
    if lp.get("task_source") != "model":
        return None
    # lazy (heavy): mujoco
    from sagg_common.robot_model import task_from_params
    return task_from_params(lp, lp["joints"], len(lp["task_space.lower"]), os.getcwd())


def wait_for_driver(session: GraphSession, monitor: DriverMonitor, timeout: float, progress: bool) -> float:
    """Spin until the driver meets the contract; print what is missing every
    :data:`WAIT_REPORT_EVERY` s; GraphError naming it after ``timeout`` s. Returns the seconds waited."""
    t0 = time.monotonic()
    last = None
    while True:
        session.spin()
        missing = monitor.missing(session.node)
        now = time.monotonic()
        if not missing:
            return now - t0
        if now - t0 > timeout:
            raise GraphError(f"the driver did not come up in {timeout:.0f} s; missing:\n  - " + "\n  - ".join(missing))
        if now - t0 > 1.0 and (last is None or now - last >= WAIT_REPORT_EVERY):
            last = now
            if progress:
                print(f"waiting for the driver (ROS_DOMAIN_ID {session.domain}):\n  - " + "\n  - ".join(missing),
                      file=sys.stderr, flush=True)


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


class Pauser:
    """``/sagg/pause`` (std_srvs/SetBool) from the orchestrator: pause the learner and wait until it
    has stopped acting, or resume it. Stopped: paused in /sagg/status, and neither a new micro-action
    nor a command on the commands topic for ``quiet`` s (the micro-action in flight when the pause
    came completes first: its command, if it reached the driver after ours, would move the arm
    elsewhere; measured under load before this wait)."""

    def __init__(self, session: GraphSession, monitor: DriverMonitor, quiet: float):
        # lazy (heavy): ROS
        from std_srvs.srv import SetBool
        self.session, self.monitor, self.quiet, self._req = session, monitor, quiet, SetBool.Request
        self.client = session.node.create_client(SetBool, "/sagg/pause")

    def set(self, paused: bool, timeout: float = 30.0) -> None:
        fut = self.client.call_async(self._req(data=paused))
        t0 = time.monotonic()
        while not fut.done():
            self.session.spin()
            if time.monotonic() - t0 > timeout:
                raise GraphError("/sagg/pause: no answer from the learner")
        if not paused:
            return
        st, mon = self.session.st, self.monitor
        last = (st.samples, time.monotonic())
        while True:
            self.session.spin()
            now = time.monotonic()
            if st.samples != last[0]:
                last = (st.samples, now)
            paused = st.status is not None and st.status["paused"]
            if paused and now - last[1] > self.quiet and now - mon.cmd_rx > self.quiet:
                return
            if now - t0 > timeout + self.quiet:
                raise GraphError("the learner did not pause")


# ------------------------------------------------------------------------------ the run
def run_external_graph(config_path: str | Path, micro_actions: int, out_dir: str | Path, *,
                       seed: int | None = None, strategy: str | None = None, eval_every: int = 1000,
                       overrides: dict[str, Any] | None = None, progress: bool = True,
                       domain_id: int | None = None, stall_timeout: float = STALL_TIMEOUT, report: bool = True,
                       robot_eval_goals: int = 10, robot_eval_every: int = 0,
                       robot_eval_goal_seconds: float = 120.0, driver_timeout: float = 120.0) -> dict:
    """``sagg run CONFIG --driver external``; returns the summary (also in DIR/summary.json)."""
    if robot_eval_goals < 1 or robot_eval_every < 0 or not robot_eval_goal_seconds > 0:
        raise ConfigError(f"--robot-eval-goals {robot_eval_goals} / --robot-eval-every {robot_eval_every} / "
                          f"--robot-eval-goal-seconds {robot_eval_goal_seconds}; allowed: goals >= 1, every >= 0, "
                          "seconds > 0")
    plan = plan_arm_run(config_path, micro_actions, out_dir, nodes=EXTERNAL_NODES, eval_every=eval_every,
                        strategy=strategy, seed=seed, overrides=overrides, domain_id=domain_id,
                        node_params=lambda full, spec, ov: external_params(full, micro_actions,
                                                                           explicit_joints(config_path, ov), spec))
    out, lp, spec = plan.out, plan.lp, plan.spec
    simulated = sim_model_matches(lp, spec)
    if not simulated:
        plan.config.pop("sagg_sim_bridge")  # not a model of this arm: no reachable area, no simulated evaluation
    # the driver runs in the environment's domain and discovery range (not a private one)
    if domain_id is None:
        domain_id = int(os.environ.get("ROS_DOMAIN_ID") or 0)
    # before anything starts: a killed run is known to have learned on this robot (never resumed otherwise)
    write_run_file(out, setup="arm", driver="external", timing="external driver", domain_id=domain_id,
                   domain_private=False, micro_actions=micro_actions, eval_every=eval_every, config=config_path,
                   overrides=plan.overrides, robot_eval_goals=robot_eval_goals, robot_eval_every=robot_eval_every,
                   robot_eval_goal_seconds=robot_eval_goal_seconds,
                   driver_timeout=driver_timeout)
    # (the driver's state streams go on after the nodes stop: the final drain does not wait for them)
    session = GraphSession(plan.procs, domain_id, graph_topics(lp), plan.bag_path, out, drain=2000, localhost=False)
    try:
        robot_run = RobotRun(session, plan, robot_eval_goals, robot_eval_every, robot_eval_goal_seconds, simulated,
                             progress)
        bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']} (graph, external driver)", enabled=progress)

        def body() -> None:
            if robot_run.evaluator is not None:
                robot_run.evaluator.start()
            robot_run.driver_wait = wait_for_driver(session, robot_run.monitor, driver_timeout, progress)
            session.start_nodes(plan.params_file, robot_run.streams.node_extra())
            session.wait_for_learner(
                micro_actions, stall_timeout, "micro-actions", bar, tick=robot_run.tick,
                may_end=robot_run.evaluation.may_end if robot_run.evaluation is not None else None,
                stall_detail=robot_run.driver_state)
            robot_run.evaluate(session.st.samples, final=True)
            session.final_drain()
    except BaseException:
        session.close()
        raise

    session.run(body, bar, between=robot_run.evaluator.stop if robot_run.evaluator is not None else None)
    summary = robot_run.summary()

    def report_now() -> None:
        path = write_report(summary, out, area=robot_run.area,
                            setup_rows=arm_rows(plan.config.get("sagg_sim_bridge") or {}))
        path.write_text(path.read_text() + robot_report_section(summary))

    return session.finish(summary, report_now if report and summary["curve"] else None)


class RobotRun:
    """The parts of an external-driver run that a simulated one lacks: the driver's monitor (its
    contract, what it measures), the evaluation on the robot (:class:`RobotEvaluation`, at the end
    and every ``every`` micro-actions with learning paused), and, when the config's simulated arm is
    this arm (``simulated``), the offline evaluation of the recorded samples in simulation."""

    def __init__(self, session: GraphSession, plan, n_goals: int, every: int, goal_seconds: float, simulated: bool,
                 progress: bool):
        # lazy (heavy): mujoco
        from sagg_sim_bridge.arms import arm_base_point, arm_reachable_area, arm_test_goals
        self.session, self.plan, self.progress, self.simulated = session, plan, progress, simulated
        lp, spec = plan.lp, plan.spec
        t_lower, t_upper = plan.task_box
        cmd_topic = f"/{lp['controller'].strip('/')}/commands"
        task_topic = lp["task_topic"] if lp["task_topic"].startswith("/") else "/" + lp["task_topic"]
        self.monitor = DriverMonitor(lp, task_topic, cmd_topic, model_task(lp))
        self.monitor.subscribe(session.node)
        self.evaluator = Evaluator(plan.config["sagg_learner"], spec, plan.checkpoints) if simulated else None
        self.evaluation = FollowedEvaluation(session, self.evaluator, progress) if simulated else None
        self.streams = ArmStreams(session, plan, self.evaluator)
        self.reached: list[np.ndarray] = []  # task points measured while learning (robot test goals)
        self.monitor.on_tip = self._on_tip
        self.streams.record()
        self.robot = ContractRobot(session, self.monitor, lp)
        self.area = arm_reachable_area(spec, t_lower, t_upper, seed=lp["eval.seed"]) if simulated else None
        goals = (arm_test_goals(spec, t_lower, t_upper, n=n_goals, seed=lp["eval.seed"], area=self.area)
                 if simulated else None)
        self.robot_eval = RobotEvaluation(lp, self.robot, n_goals, every, goals,
                                          arm_base_point(spec) if simulated else None, goal_seconds)
        self.pauser = Pauser(session, self.monitor, lp["settle_timeout"] + 0.5)
        self.driver_wait = float("nan")

    def _on_tip(self, p) -> None:
        if self.session.st.samples and len(self.reached) < 200_000:
            self.reached.append(p[:len(self.plan.lp["task_space.lower"])].copy())

    def driver_state(self) -> str:
        """What the driver lacks now (the stall error's detail)."""
        return "driver: " + ("; ".join(self.monitor.missing(self.session.node)) or "meets the contract")

    def tick(self, now: float) -> bool:
        """The simulated evaluation followed; an evaluation on the robot when one is due (learning
        paused meanwhile: True, the stall clock starts again)."""
        if self.evaluation is not None:
            self.evaluation.tick(now)
        st, total, r = self.session.st, self.plan.micro_actions, self.robot_eval
        done = st.status is not None and st.status["micro_actions"] >= total
        if r.next_at is not None and r.next_at < total and st.samples >= r.next_at \
                and not done:  # (the end has its own)
            self.evaluate(min(st.samples, total), final=False)
            r.next_at += r.every
            return True
        return False

    def evaluate(self, at: int, final: bool) -> None:
        """The evaluation on the robot at ``at`` micro-actions; during learning (not ``final``) with
        learning paused, and the arm brought back where it paused (in steps) before learning resumes."""
        session, monitor = self.session, self.monitor
        if self.progress:
            print(f"\nevaluating on the robot at {at} micro-actions ({self.robot_eval.n_goals} goals from rest"
                  + (", learning paused)" if not final else ")"), file=sys.stderr, flush=True)
        if not final:
            self.pauser.set(True)
            posture = monitor.alpha.copy()
        errors = self.robot_eval.run(at, *self.streams.received(), self.reached)
        session.view.set_test_goals(self.robot_eval.goals)
        if not final:
            self.robot.move_to(posture)
            self.pauser.set(False)
        session.st.last_error = float(errors.mean())

    def summary(self) -> dict:
        """summary.json: the session's keys, the arm's, the robot's evaluation and which curve is which."""
        session, plan, monitor, r = self.session, self.plan, self.monitor, self.robot_eval
        robot_summary = r.summary()
        robot_summary.update(driver_wait_seconds=self.driver_wait, joint_state_rate=DriverMonitor.rate(monitor.js_rx),
                             task_point_rate=DriverMonitor.rate(monitor.tip_rx))
        robot_curve = [{k: c[k] for k in ("micro_actions", "mean_error", "median_error")} for c in r.curve]
        if r.initial_errors is not None:
            e = r.initial_errors
            robot_curve.insert(0, {"micro_actions": 0, "mean_error": float(e.mean()),
                                   "median_error": float(np.median(e))})
        ev = self.evaluator
        if ev is not None and ev.area is not None:
            self.area = ev.area
        sim_curve = sorted(ev.curve, key=lambda c: c["micro_actions"]) if ev is not None else []
        summary = session.summary(
            plan.lp, plan.config, plan.params, plan.params_file, "external driver", plan.micro_actions,
            sim_curve if self.simulated else robot_curve, self.area, plan.t_start, self.streams.prior_samples,
            eval_seconds=(ev.eval_seconds if ev is not None else 0.0) + r.seconds, test_goals=robot_summary["goals"],
            driver="external", robot_evaluation=robot_summary,
            curve_source="simulated (offline, from the recorded samples)" if self.simulated else "on the robot",
            simulated_evaluation=self.simulated, **self.streams.summary_keys())
        if ev is not None:
            summary["test_goals"] = ev.test_goals.tolist() if ev.test_goals is not None else None
        write_json_atomic(plan.out / "robot_evaluation.json", {"summary": robot_summary, "trace": self.robot.trace})
        return summary


def robot_report_section(summary: dict) -> str:
    """The report's section on the evaluation on the robot (and which curve is which)."""
    r = summary["robot_evaluation"]
    lines = ["", "## Evaluation on the robot", "",
             f"The frozen model reached {len(r['goals'] or [])} test goals from rest through the driver, learning "
             f"paused ({'every ' + str(r['every']) + ' micro-actions and ' if r['every'] else ''}at the end); "
             f"test goals: {r['goal_source']}. Errors measured by the task-point topic.", "",
             "| micro-actions | mean error (on the robot) | median error | within tolerance |",
             "|---:|---:|---:|---:|",
             f"| 0 (empty model: the arm stays at rest) | {r['initial_mean_error']:.3f} | "
             f"{float(np.median(r['initial_errors'])) if r['initial_errors'] else float('nan'):.3f} | – |"]
    lines += [f"| {c['micro_actions']:,} | {c['mean_error']:.3f} | {c['median_error']:.3f} | "
              f"{c['within_share']:.0%} |" for c in r["curve"]]
    frame = r.get("eval_metrics")
    if frame and r["curve"]:
        bands = r["curve"][-1]["band_mean_errors"]
        edges = frame["band_edges"]
        lines += ["", f"Within tolerance: within {frame['within']:.3g} (2 % of R = {frame['radius']:.3g}, the "
                  "farthest test goal from the base). Final mean error per distance-from-base band: "
                  + "; ".join(f"{a:.3g}-{b:.3g} ({c} goals): {'–' if e is None else f'{e:.3f}'}"
                              for a, b, c, e in zip(edges, edges[1:], frame["band_counts"], bands)) + "."]
    lines += ["", f"Joint states at {r['joint_state_rate']:.0f}/s, task points at {r['task_point_rate']:.0f}/s; "
              f"{r['commands']} evaluation commands in {r['seconds']:.1f} s ({r['settle_timeouts']} answered only "
              "after settle_timeout).", ""]
    if summary.get("simulated_evaluation"):
        lines += ["The learning curve above is the **simulated** evaluation (offline, the recorded samples "
                  "in the config's simulated model of the same arm, on its test goals).", ""]
    else:
        lines += ["The config's simulated arm is not this arm (joints, limits or rest posture differ): "
                  "no simulated evaluation; the learning curve above is the evaluation on the robot.", ""]
    return "\n".join(lines)
