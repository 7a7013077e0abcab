"""The learner node (``learner``): the SAGG-RIAC low level on ROS 2, speaking the hardware contract.

It drives the :class:`~sagg_low_level.learner.EvolvingContextLearner` coroutine from callbacks (a
state machine; nothing ever sleeps or blocks the executor):

- ``Observe``: answered with the latest observation (joint_states mapped by name + task point);
- ``Command``: checked against the scene (:mod:`.move_check`), then sent as setpoints
  (``std_msgs/Float64MultiArray`` on ``/<controller>/commands``, joint order = the ``joints``
  parameter) streamed within the velocity limits, or one ``JointTrajectory`` (:mod:`.motion`; the
  simulator alone gets one setpoint), and answered by a *fresh, settled* observation: a joint
  state and a task point both received after the last setpoint was published and stamped later
  than the newest ones received before it (plus ``observation_delay``); settled when every
  |velocity| is below ``settle_velocity`` (a streamed move: and every joint within
  ``settle_tolerance`` of the last setpoint), or, after ``settle_timeout`` seconds, the latest
  fresh one is taken; an arm that stops following is held (``follow``) and probed;
- ``GoalRequest``: calls ``/sagg/next_goal`` (the generator answers once it has processed the
  reports 1..after_report), answered from the response.

Every report is published on ``/sagg/competence`` and every stored sample on ``/sagg/sample``, in
order, in bursts right after a command (or goal request) went out, so the driver works while we
publish: every goal request, every ``publish_batch`` items and at least every ``publish_period``
(a burst costs each receiver one wake-up, not one per message); ``/sagg/status`` at 2 Hz. Hot-path
topics travel as raw CDR (``sagg_common.cdr``). At ``max_micro_actions`` the learner stops
acting (exactly where the in-process ``InProcessRun.step_until`` stops) and says so in its status.
"""
from __future__ import annotations

import math
import os
import struct
import sys
import time

import numpy as np

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, UInt64
from std_srvs.srv import SetBool

from sagg_common.cdr import decode_point_stamped
from sagg_common.diagnostics import InputGuard, diagnostic_array
from sagg_common.envelope import ACCEPT, FUTURE, OUT_OF_ORDER, RejectRun, StampTracker
from sagg_common.msg_codecs import encode_report, encode_sample
from sagg_common.params import ConfigError
from sagg_common import sources
from sagg_common.joint_intake import AMBIGUOUS, FUTURE_STAMP, OTHER, OUT_OF_ORDER_STAMP, REJECTED, TAKEN
from sagg_common.publishers import UNKNOWN_NODE, describe
from sagg_common.ros_params import HW_DEPTH, params_dir, reliable, run_node
from sagg_common.report_kinds import KIND_EXPLORATION
from sagg_msgs.srv import ComputeIK, NextGoal

from .checkpoint import LearnerCheckpointer
from .holds import PAUSED_BY_SERVICE, SERVICE, Holds
from .rest_return import RestReturn
from .evaluate import frozen_reach, reach_steps_limit
from .ik import load_model, rest_point_file, write_rest_point
from .ik_service import SERVICE as IK_SERVICE, answer_ik
from .known_points import KnownPoints
from .learner import Command, EvolvingContextLearner, GoalRequest, Observe, Report, Robot
from .reach_server import ACTION, ReachJob, ReachServer
from .recorder_acks import RecorderAcks
from .node_base import NODE_NAME, LearnerNodeBase
from .node_moves import MoveSender
from .schema import LEARNER_CORE_SCHEMA as CORE_SCHEMA, LEARNER_SCHEMA as SCHEMA, command_topic, joint_intake

class ReachDone:
    """The last request of a reach (:meth:`LearnerNode._reach_requests`): the learner's own
    coroutine takes over again."""






def robot_from_params(p: dict) -> Robot:
    n = len(p["joints"])
    if len(set(p["joints"])) != n:
        raise ConfigError(f"parameter 'joints': got {p['joints']!r}; allowed: distinct joint names")
    for name in ("joint_limits.lower", "joint_limits.upper", "rest_posture"):
        if len(p[name]) != n:
            raise ConfigError(f"parameter '{name}': got {len(p[name])} values; allowed: one per joint "
                              f"({n}, as in 'joints')")
    try:
        return Robot(list(p["joints"]), p["joint_limits.lower"], p["joint_limits.upper"], p["rest_posture"])
    except ValueError as exc:
        raise ConfigError(f"parameters 'joint_limits.*'/'rest_posture': {exc}") from exc


class LearnerNode(LearnerNodeBase, MoveSender):
    """The learner node: the learner's coroutine driven by callbacks, as a state machine.

    ===============  ==============================================  =====================================
    state            what it waits for                               next
    ===============  ==============================================  =====================================
    STARTING         joint states, a task point, the driver's        the first request dispatched
                     controller, the recorder and the generator      (:meth:`on_poll`)
    RUNNING_COMMAND  the move's setpoints streamed at command_rate   the coroutine's next request
                     (:class:`.node_moves.MoveSender`), then          (:meth:`advance`); a return to rest
                     a fresh, settled observation after the last     steps on (:mod:`.rest_return`);
                     one (:meth:`_try_answer_command`); while the    a move the scene refuses is answered
                     arm does not follow: the ``follow`` hold and    where the arm is (:meth:`_not_sent`)
                     its probes
    RUNNING_GOAL     the answer of ``/sagg/next_goal``               the next request (``on_goal``)
    PAUSED           a command is due but a hold is set              the command, once no hold blocks and
                     (:mod:`.holds`) or the recorder is behind        the recorder caught up
    STOPPED          nothing: ``max_micro_actions`` reached, or a    (a reach of ``/sagg/reach`` still
                     frozen model                                     runs)
    ===============  ==============================================  =====================================

    A ``/sagg/reach`` goal takes over between two requests (:meth:`_poll_reach`): learning is held
    (the ``reach`` hold), the learner's coroutine is kept aside and the reach's own requests
    (:meth:`_reach_requests`) are dispatched through the same states; then the learner's
    coroutine is put back (:meth:`_finish_reach`)."""

    STARTING, RUNNING_COMMAND, RUNNING_GOAL, STOPPED = "starting", "command", "goal", "stopped"
    PAUSED = "paused"  # a command is due but a hold (pause service, stale driver) is active

    def __init__(self):
        super().__init__(SCHEMA)
        p = self.params
        self.robot = robot_from_params(p)
        self.frozen = bool(p["frozen_memory"])  # a learned model used without learning (sagg reach)
        # the effector's point at rest, measured at each return to rest (or the frozen model's): the
        # point /sagg/compute_ik starts from
        self.rest_point: np.ndarray | None = None
        core = self._build_learner(CORE_SCHEMA, "2 or 3 (the task point is a geometry_msgs/PointStamped)",
                                   lambda core, m: EvolvingContextLearner(core, self.robot, m,
                                                                          memory=self._frozen_memory(p, m)))
        if self.frozen:
            self.uses_goals = False
        self.max_micro_actions = p["max_micro_actions"]
        self.settle_timeout = p["settle_timeout"]
        self.delay_ns = int(round(p["observation_delay"] * 1e9))
        self.exit_code = 0
        self.done = False
        self.sim_time = bool(self.get_parameter("use_sim_time").value)
        self._init_inputs(p)
        self._init_outputs(p)
        self._init_learning(p)
        self.get_logger().info(
            f"strategy {core['strategy']}, {self.robot.n} joints, commands on {self.cmd_topic}, "
            + (f"task point on {p['task_topic']}" if self.task_fk is None else
               f"task point from the joints through {self.task_fk.robot.path} "
               f"(effector {self.task_fk.robot.effector!r})")
            + (f", stops at {self.max_micro_actions} micro-actions" if self.max_micro_actions else ""))

    def _init_inputs(self, p: dict) -> None:
        """The measured inputs, their checks (docs/safety.md) and the holds they may set."""
        self.guard = InputGuard(self.get_logger().error)
        self.holds = Holds(self.get_logger().warning, self.get_logger().info)  # no command goes out while any is set
        self.js_rx = self.tip_rx = time.monotonic()  # last valid joint state / task point received
        # the plausibility envelope of the task point: Y ± margin, stamps neither in the future of
        # their stream nor wedged by a clock jump back (the joint states': their intake's)
        margin = p["plausibility.task_margin"]
        t_lo = np.asarray(p["task_space.lower"], dtype=float)
        t_hi = np.asarray(p["task_space.upper"], dtype=float)
        ext = margin * (t_hi - t_lo)
        self.tip_box = tuple(zip((t_lo - ext).tolist(), (t_hi + ext).tolist()))
        self.tip_track = StampTracker(p["plausibility.future_tolerance"], p["plausibility.resync_after"])
        self.js_run = RejectRun(p["plausibility.hold_after"])
        self.tip_run = RejectRun(p["plausibility.hold_after"])
        # /joint_states: decoded, mapped by name, checked, attributed to a source, stamped (one rule set);
        # hot path: raw CDR (sagg_common.cdr) with the message info (the publishers' sequence numbers)
        self.js_intake = joint_intake(p, self.robot.joint_names, self.robot.lower, self.robot.upper)
        self.create_subscription(JointState, "/joint_states", sources.with_message_info(self.on_joint_state),
                                 reliable(10), raw=True)
        # the task point: from task_topic, or from the measured joints through the robot's model
        self.task_topic = p["task_topic"]
        self.task_fk = None
        if p["task_source"] == "model":
            # lazy (heavy): mujoco, only for task_source 'model'
            from sagg_common.robot_model import in_learner_terms, task_from_params
            self.task_fk = task_from_params(p, self.robot.joint_names, self.m, params_dir() or os.getcwd())
            if self.task_fk.robot.mesh_notice:  # (the held joints' rest values come from the model: no notice)
                self.get_logger().info("task_model: " + in_learner_terms(self.task_fk.robot.mesh_notice))
        if self.task_fk is None:
            self.create_subscription(PointStamped, p["task_topic"], sources.with_message_info(self.on_task_point),
                                     reliable(10), raw=True)
        self._init_scene(p)
        # one source per input (docs/safety.md, sagg_common.sources): judged by the messages that
        # arrive, never by who merely publishes
        self.check_sources = p["plausibility.check_sources"]
        self.tip_sources = sources.SourceChains(p["plausibility.source_grace"])
        self.source_text: dict[str, str] = {}     # topic -> its current source hold, in words
        # the newest observation (mapped), its stamp, settled; the freshness of a command's answer
        self.js_alpha: np.ndarray | None = None
        self.js_stamp = -1
        self.js_settled = False
        self.tip: np.ndarray | None = None
        self.tip_stamp = -1
        self.js_min = self.tip_min = 0
        self.js_fresh = self.tip_fresh = False
        self.cmd_time = 0.0

    def _init_outputs(self, p: dict) -> None:
        """The commands, the /sagg topics, the pause service and the recorders' backpressure."""
        self.cmd_topic = command_topic({**p, "command_interface": "position"})[0]
        # messages published per topic (logged at shutdown and on /diagnostics: what a bag must hold)
        self.published = {self.cmd_topic: 0, "/sagg/sample": 0, "/sagg/competence": 0}
        self.cmd_pub = self.create_publisher(Float64MultiArray, self.cmd_topic, reliable(HW_DEPTH))
        self._create_sagg_endpoints()  # /sagg/competence, /sagg/sample, /sagg/status, /diagnostics, goals
        # the return to rest (rest_return): stepped unless the simulator is the only listener
        self.rest_return = p["rest_return"]
        self.rest_moves = RestReturn(self.robot, self.learner.p, self.get_logger().warning)
        self._cmd_subs = (-1, None)  # (subscriber count, only the simulator listens) of the commands topic
        self._init_motion(p)
        self.create_service(SetBool, "/sagg/pause", self.on_pause)
        # backpressure: a recorder's acknowledgements (recorder_max_lag)
        self.rec_max_lag = p["recorder_max_lag"]
        self.rec_acks = RecorderAcks(p["recorder_timeout"])  # per recorder (told apart by its publisher)
        self.rec_acked = 0          # what the slowest live recorder acknowledged (samples from index 0)
        self.rec_waiting = False    # a command waits for the recorder
        self.rec_waits = 0          # how often, and for how long in all
        self.rec_wait_seconds = 0.0
        self.rec_wait_t0 = 0.0
        self.samples_published = 0  # samples published (index of the last one + 1)
        self.rec_sub = self.create_subscription(UInt64, "/sagg/recorded", sources.with_message_info(self.on_recorded),
                                                reliable(10))

    def _init_learning(self, p: dict) -> None:
        """The coroutine (STARTING), its outbox and checkpoints, the reach server, the timers."""
        self.state = self.STARTING
        self.pause_reason = "waiting for joint_states, task point, controller and goal generator"
        # Reports and samples are queued while the coroutine runs and published in bursts right
        # after a command (or goal request) went out: the driver then works on the command while we
        # publish, instead of waiting for us (same messages, same order; publish_batch).
        self.outbox: list = []
        self.publish_batch, self.publish_period = p["publish_batch"], p["publish_period"]
        self.last_flush = time.monotonic()
        self.learner.on_report = self.outbox.append
        self.learner.on_sample = self.outbox.append
        self.checkpointer = None
        self._setup_checkpoint(p)  # may restore the learner, journals samples/reports, queues republishing
        self.coro = self.learner.run()
        self.pending = next(self.coro)  # the first request (Observe)
        # /sagg/reach (use what was learned): jobs from the action's thread, run one at a time
        self.reach: ReachJob | None = None
        self.reach_saved: tuple | None = None  # the learner's (coroutine, pending request, state)
        self.steps_limit = reach_steps_limit(self.learner, p["task_space.lower"], p["task_space.upper"])
        self.reach_server = ReachServer(self, p["task_space.lower"], p["task_space.upper"], self.steps_limit,
                                        self.robot.joint_names)
        # /sagg/compute_ik: answered in this node's thread (the one that grows the memory)
        self.create_service(ComputeIK, IK_SERVICE, self.on_compute_ik)
        self.ik_answered = 0
        self.ik_points = KnownPoints()  # (the points of the stored postures, kept across /sagg/compute_ik requests)
        self.goals_received = 0
        self.t_started = time.monotonic()
        self.ma_start = self.learner.micro_actions  # (resumed: those of earlier segments, not in the stop line's rate)
        self.rate_window: list[tuple[float, int]] = [(time.monotonic(), 0)]
        self.create_timer(0.5, self.publish_status)
        self.create_timer(1.0, self.publish_diagnostics)
        self.poll_timer = self.create_timer(0.05, self.on_poll)

    # ------------------------------------------------------------------ observations
    def on_joint_state(self, data: bytes, info: dict = sources.NO_INFO) -> None:
        """A JointState, read by the one intake (:class:`~sagg_common.joint_intake.JointStateIntake`:
        decoded, mapped to our joints by name, checked, its source and its stamp); what is taken is
        the newest measured posture. A rejection is counted and logged, and after
        ``plausibility.hold_after`` in a row the learner holds; another driver's joints are ignored."""
        intake = self.js_intake
        verdict = intake.take(data, info["publication_sequence_number"])
        code = verdict.code
        if code is not TAKEN:
            if code is REJECTED:
                self._reject_js(verdict.kind, verdict.message)
            elif code is OTHER:
                names = intake.names
                if intake.other_joints[names] == 1:  # (once per name list: not an error)
                    self.get_logger().info(
                        f"/joint_states: messages naming {', '.join(names) or 'no joint'} carry none of the "
                        "learner's joints: ignored (another driver's joints, e.g. a gripper)")
            elif code is AMBIGUOUS:
                self._second_source("/joint_states", "joint_states", intake.sources,
                                    "joints " + ", ".join(self.robot.joint_names))
            elif code is OUT_OF_ORDER_STAMP:
                self.guard.reject(verdict.kind, verdict.message)
            elif code is FUTURE_STAMP:
                self.guard.reject(verdict.kind, verdict.message)
                self.js_run.reject()
            return  # (GAP: the chain's next message is taken)
        st = intake.stamp
        if verdict.kind:  # a clock jump back: logged, the stream re-synchronised
            self.guard.reject(verdict.kind, verdict.message)
            if self.state is self.RUNNING_COMMAND:  # the command's freshness bound moves back too
                self.js_min = min(self.js_min, st - 1 + self.delay_ns)
        alpha = intake.position
        self.js_alpha, self.js_settled, self.js_stamp = alpha, intake.settled, st
        self.js_rx = time.monotonic()
        if self.task_fk is not None:  # task_source 'model': the task point of this posture
            y = self.task_fk.point(alpha)
            if self._plausible_tip(y, f"the task point of this posture through {self.task_fk.robot.path}"):
                if self.tip_run.ok():
                    self._set_hold("task_point", None)
                self._take_tip(y, st)
        if self.source_text:
            self._source_settled("/joint_states")
        if self.js_run.ok():
            self._set_hold("joint_states", None)
        if self.holds:
            self._check_driver()
        if self.state is self.RUNNING_COMMAND and st > self.js_min:
            self.js_fresh = True
            self._try_answer_command(False)

    def _reject_js(self, kind: str, message: str) -> None:
        """A rejected joint state: counted, logged, and after ``plausibility.hold_after`` in a row a hold."""
        self.guard.reject(kind, message)
        if self.js_run.reject() and "joint_states" not in self.holds:  # (named once: no log flood)
            self._set_hold("joint_states", f"{self.js_run.run} rejected joint states in a row, the last: "
                                           f"[{kind}] {message}")

    def _stamp_verdict(self, verdict: int, topic: str, st: int) -> bool:
        """A task point's stamp that was not simply accepted: False (rejected: logged, counted) for
        one out of order or in the future; True for a clock jump back (logged; the stream is
        re-synchronised)."""
        field, message = self.tip_track.describe(verdict, topic, st, time.monotonic_ns())
        self.guard.reject(f"task_point.{field}", message)
        if verdict == FUTURE:
            self.tip_run.reject()
        return verdict not in (OUT_OF_ORDER, FUTURE)

    def on_task_point(self, data: bytes, info: dict = sources.NO_INFO) -> None:
        """A task point: decoded, checked (finite, within Y enlarged by ``plausibility.task_margin``),
        then its source and its stamp. A message rejected for its content is skipped in its
        publisher's chain (no gap)."""
        if not self._take_task_point(data, info):
            self.tip_sources.skip(info["publication_sequence_number"])

    def _take_task_point(self, data: bytes, info: dict) -> bool:
        """False: not taken for its content (before the source check)."""
        topic = self.params["task_topic"]
        try:
            st, xyz = decode_point_stamped(data)
        except (ValueError, IndexError, struct.error) as exc:
            self._reject_tip("task_point.undecodable", f"{topic}: undecodable message ({exc})")
            return False
        xyz = xyz[:self.m]
        if not self._plausible_tip(xyz, topic):
            return False
        if self.check_sources:
            verdict = self.tip_sources.classify(info["publication_sequence_number"], time.monotonic())
            if verdict != sources.ACCEPT:
                if verdict == sources.AMBIGUOUS:
                    self._second_source(topic, "task_point", self.tip_sources, "task points")
                return True
        verdict = self.tip_track.check(st, time.monotonic_ns())
        if verdict != ACCEPT:
            if not self._stamp_verdict(verdict, topic, st):
                return True
            if self.state is self.RUNNING_COMMAND:
                self.tip_min = min(self.tip_min, st - 1 + self.delay_ns)
        if self.source_text:
            self._source_settled(topic)
        if self.tip_run.ok():
            self._set_hold("task_point", None)
        self._take_tip(np.array(xyz), st)
        if self.holds:
            self._check_driver()
        if self.state is self.RUNNING_COMMAND and st > self.tip_min:
            self._try_answer_command(False)
        return True

    def _take_tip(self, y: np.ndarray, st: int) -> None:
        """The newest task point (from task_topic, or computed from the measured joints), stamped ``st``."""
        self.tip, self.tip_stamp, self.tip_rx = y, st, time.monotonic()
        if self.state is self.RUNNING_COMMAND and st > self.tip_min:
            self.tip_fresh = True

    def _second_source(self, topic: str, key: str, chains: sources.SourceChains, what: str) -> None:
        """A message while ``topic``'s stream has two live sources: rejected (counted, logged), and
        the learner holds (named) until one source has been quiet for ``plausibility.source_grace``
        s and a message of the remaining one is taken (:meth:`_source_settled`): no command goes out
        from a posture measured before the hold."""
        hold = f"sources {topic}"
        # (the publishers are read once per episode, not per message; again while one is not known yet)
        if hold not in self.holds or UNKNOWN_NODE in self.source_text.get(topic, ""):
            infos = self.get_publishers_info_by_topic(topic)
            names = ", ".join(f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos) or "none left"
            self.source_text[topic] = (
                f"2 sources on {topic} (publishers: {names}): {what} from both; held until one has been "
                f"quiet for {chains.grace:g} s (plausibility.source_grace); rclpy names no publisher per "
                f"message, the topic's publishers: {'; '.join(describe(i) for i in infos) or 'none'}")
            self._set_hold(hold, self.source_text[topic])
        self.guard.reject(f"{key}.second_source", f"{self.source_text[topic]}; message dropped")

    def _source_settled(self, topic: str) -> None:
        """A message of ``topic``'s one remaining source was taken: its hold ends (learning resumes)."""
        if topic in self.source_text:
            del self.source_text[topic]
            self._set_hold(f"sources {topic}", None)

    def _plausible_tip(self, xyz, where: str) -> bool:
        """Whether a task point is finite and within Y enlarged by ``plausibility.task_margin``;
        else rejected, naming ``where`` it came from."""
        for (lo, hi), x in zip(self.tip_box, xyz):
            if not lo <= x <= hi:  # (NaN fails too)
                if all(map(math.isfinite, xyz)):
                    self._reject_tip("task_point.outside_task_space",
                                     f"{where}: point {list(map(float, xyz))}; allowed: within "
                                     f"{[list(b) for b in self.tip_box]} (task_space enlarged by "
                                     "plausibility.task_margin)")
                else:
                    self._reject_tip("task_point.non_finite",
                                     f"{where}: NaN/inf coordinate {list(map(float, xyz))}; allowed: finite values")
                return False
        return True

    def _reject_tip(self, kind: str, message: str) -> None:
        self.guard.reject(kind, message)
        if self.tip_run.reject() and "task_point" not in self.holds:
            self._set_hold("task_point", f"{self.tip_run.run} rejected task points in a row, the last: "
                                         f"[{kind}] {message}")

    def _try_answer_command(self, timed_out: bool) -> None:
        if not (self.js_fresh and self.tip_fresh):
            return
        if self.streamed:
            if self.stream.busy:
                return  # (setpoints still to go, or the arm stopped)
            if not timed_out and not self._settled_at(self.stream.target):
                return
            self.stream.done()
        elif not self.js_settled and not timed_out:
            return
        if not self.rest_moves.final:  # a step of the return to rest: the next one, from the measured posture
            self.state = None
            self.dispatch(self.pending)
            return
        self.rest_moves.answered()
        self._note_rest_point(self.pending)
        self.advance((self.js_alpha, self.tip))

    def _note_rest_point(self, req) -> None:
        """A return to rest answered with the arm at rest (within ``explore_amplitude`` per joint; a
        return the scene stopped is not): the task point measured there is the rest point."""
        if (getattr(req, "kind", None) == "reset"
                and np.abs(self.js_alpha - self.robot.rest).max() <= self.learner.p["explore_amplitude"]):
            self.rest_point = self.tip.copy()

    # ------------------------------------------------------------------ coroutine driving
    def on_poll(self) -> None:
        """Every 50 ms: the start-up checks or the timeouts of the state, the driver's freshness,
        the reach queue, the recorder's backpressure and the periodic burst of the outbox."""
        self._poll_state()
        if self.state not in (self.STARTING, self.STOPPED):
            self._check_driver()
        self._poll_reach_queue()
        if self.rec_waiting and not self._recorder_behind():  # e.g. the recorder is gone
            self._recorder_caught_up()
        if (self.outbox and self.state is not self.STARTING
                and time.monotonic() - self.last_flush >= self.publish_period):
            self.flush()

    def _poll_state(self) -> None:
        """STARTING: start once ready; RUNNING_GOAL: ask again after ``goal_retry``; RUNNING_COMMAND:
        after ``settle_timeout`` s take the latest fresh observation (or say that none came)."""
        if self.state is self.STARTING:
            if self._ready():
                self.state = None
                self.pause_reason = ""
                self.get_logger().info("graph ready: starting")
                self.t_started = time.monotonic()
                self.dispatch(self.pending)
        elif self.state is self.RUNNING_GOAL:
            self._retry_goal_request()
        elif self.state is self.RUNNING_COMMAND and time.monotonic() - self.cmd_time > self.settle_timeout:
            if self.streamed:
                if self.stream.busy:
                    return  # (the arm stopped on the way: the follow hold and its probes decide)
                self.stream.done()  # (settle_timeout runs from the last setpoint: the move is over)
            if self.js_fresh and self.tip_fresh:
                self.get_logger().warning(
                    f"no settled observation {self.settle_timeout} s after a command: taking the "
                    "latest", throttle_duration_sec=5.0)
                self._try_answer_command(True)
            else:
                self.get_logger().warning(
                    f"no fresh joint_states/task point {time.monotonic() - self.cmd_time:.1f} s after "
                    f"a command on {self.cmd_topic}: is the driver running?", throttle_duration_sec=5.0)

    def _poll_reach_queue(self) -> None:
        """The reach server's rejected and canceled goals answered, the next reach started."""
        while self.reach_server.rejections:  # (rejected goals, counted here: the guard is this thread's)
            self.guard.reject(*self.reach_server.rejections.popleft())
        canceled = self.reach_server.take_canceled()
        for job in canceled:  # (canceled before its turn: nothing moved)
            y = self.tip if self.tip is not None else np.full(job.target.shape, np.nan)
            self._answer_reach(job, (y, float(np.linalg.norm(job.target - y)), 0, "canceled"))
        if canceled and self.reach is None and not self.reach_server.jobs:
            # the hold _poll_reach set for them while a command was in flight: nothing is left to
            # reach (kept, it held learning for ever once the other holds were gone)
            self._set_hold("reach", None)
        if self.reach_server.jobs and self.reach is None:
            self._poll_reach()
        elif (self.reach is not None and self.reach.cancel and self.state is self.PAUSED
              and getattr(self.pending, "kind", None) in ("reset", "reach")):
            self.state = None  # canceled while a hold keeps its command waiting: nothing moved
            self.dispatch(self.coro.send(None))
        elif (self.reach is not None and self.reach.cancel and self.state is self.RUNNING_COMMAND
              and self.streamed and self.stream.phase in (self.stream.STOPPED, self.stream.PROBING)):
            self.stream.done()  # canceled while the arm does not follow: the move ends where the arm is
            self._answer_where_it_is()

    # ------------------------------------------------------------------ safety holds
    def _check_driver(self) -> None:
        """Hold (no new command) while joint states or task points are stale or /joint_states has
        no publisher; release when they are back. The command in flight, if any, completes when
        fresh settled observations arrive: its sample holds measured values only."""
        now = time.monotonic()
        limit = self.params["joint_state_timeout"]
        stale = [name for name, t in (("joint_states", self.js_rx), ("task point", self.tip_rx)) if now - t > limit]
        if stale:
            # (while a stream has two sources every message of it is rejected: name that cause)
            two = [t for k, t in self.holds.items() if k.startswith("sources ")]
            why = f"rejected: {'; '.join(two)}" if two else "driver stopped or disconnected?"
            self._set_hold("driver", f"no valid {' or '.join(stale)} for more than {limit} s ({why})")
        elif self.count_publishers("/joint_states") == 0:
            self._set_hold("driver", "/joint_states has no publisher (driver gone)")
        elif self.holds.get("driver"):
            self._set_hold("driver", None)

    def _set_hold(self, key: str, reason: str | None) -> None:
        """Set (``reason``) or release (None) the hold ``key`` (:mod:`.holds`); once nothing holds
        any more, the command that waited goes out."""
        if reason is not None:
            self.holds.set(key, reason)
            return
        self.holds.release(key)
        if not self._held() and self.state is self.PAUSED:
            self.state = None
            self.dispatch(self.pending)

    def on_pause(self, request: SetBool.Request, response: SetBool.Response) -> SetBool.Response:
        """``/sagg/pause`` (std_srvs/SetBool): true = pause (the micro-action in flight completes and
        is stored; no further command goes out), false = resume."""
        if request.data:
            self._set_hold(SERVICE, PAUSED_BY_SERVICE)
        else:
            self._set_hold("service", None)
        response.success = True
        response.message = "paused" if self.holds else "running"
        return response

    def publish_diagnostics(self) -> None:
        learner = self.learner
        state = {"state": self.state or "running", "micro_actions": str(learner.micro_actions),
                 "samples": str(len(learner.memory)), "holds": "; ".join(self.holds.values())}
        state.update({f"published {t}": str(n) for t, n in self.published.items()})
        state.update({"recorder waits": str(self.rec_waits), "recorder wait seconds": f"{self.rec_wait_seconds:.3f}",
                      "recorder acknowledged samples": str(self.rec_acks.largest()),
                      "recorders seen": str(self.rec_acks.recorders_seen)})
        state["rest-return commands"] = str(self.rest_moves.steps)
        state["compute_ik requests answered"] = str(self.ik_answered)
        for cause, n in sorted(self.learner.refused.items()):
            state[f"moves refused by the scene: {cause}"] = str(n)
        if self.stream is not None:
            state["arm stopped following (episodes)"] = str(self.stream.stops)
            state["probe setpoints"] = str(self.stream.probes)
        ignored = sum(self.js_intake.other_joints.values())
        if ignored:
            state["ignored /joint_states without the learner's joints"] = str(ignored)
            state["other joint lists on /joint_states"] = "; ".join(
                ", ".join(n) for n in list(self.js_intake.other_joints)[:4])
        state["sequence gaps (messages not taken)"] = str(self.js_intake.sources.gaps + self.tip_sources.gaps)
        state["second-source episodes"] = str(self.js_intake.sources.episodes + self.tip_sources.episodes)
        for topic in ("/joint_states",) + ((self.task_topic,) if self.task_fk is None else ()):
            state[f"publishers {topic}"] = "; ".join(
                describe(i) for i in self.get_publishers_info_by_topic(topic)) or "none"
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().to_msg(), NODE_NAME, self.guard, state,
                                               self.holds.faults()))

    def _ready(self) -> bool:
        if self.js_alpha is None or self.tip is None:
            missing = [w for w, v in (("/joint_states with joints " + ", ".join(self.robot.joint_names), self.js_alpha),
                                      (f"a task point on {self.params['task_topic']}" if self.task_fk is None else
                                       "a task point (from the joint states through task_model.file) within Y",
                                       self.tip)) if v is None]
            return self._waiting_for(" and ".join(missing))
        if self.trajectory:
            return self._peers_ready(self.traj_pub, self.traj_topic, match_reports=True)
        return self._peers_ready(self.cmd_pub, self.cmd_topic, match_reports=True)

    def advance(self, answer) -> None:
        """Send ``answer`` to the pending request and dispatch the next request."""
        self.state = None
        self.dispatch(self.coro.send(answer))

    def dispatch(self, req) -> None:
        """Act on the learner's requests until one waits for an answer (the state table of
        :class:`LearnerNode`): a command goes out (or waits: a hold, the recorder), a goal is asked
        for, an observation is answered at once, a reach ends; at the budget (or with a frozen
        model) the learner stops acting."""
        while True:
            if self.reach is None and (self.frozen or (self.max_micro_actions
                                                       and self.learner.micro_actions >= self.max_micro_actions)):
                self._stop(req)
                return
            kind = type(req)
            if kind is Command:
                self._send_command(req)
                return
            if kind is GoalRequest:
                self._request_goal(req)
                return
            if kind is Observe:
                req = self.coro.send((self.js_alpha.copy(), self.tip.copy()))
                continue
            if kind is ReachDone:
                self._finish_reach()
                return
            raise TypeError(f"unknown learner request {req!r}")

    def _stop(self, req) -> None:
        """STOPPED: the budget is reached (said with this segment's rate), or the model is frozen."""
        learner = self.learner
        self.pending = req
        self.state = self.STOPPED
        if self.frozen:
            self.pause_reason = f"a frozen model ({self.params['frozen_memory']}): reach goals on {ACTION}"
            self.get_logger().info(self.pause_reason)
            self.publish_status()
            return
        self.pause_reason = f"max_micro_actions ({self.max_micro_actions}) reached"
        secs = time.monotonic() - self.t_started
        done = learner.micro_actions - self.ma_start  # this segment's (since the start or resume)
        since = f", {done} since the resume at {self.ma_start}," if self.ma_start else ""
        self.get_logger().info(
            f"{self.pause_reason}: stopped acting ({learner.micro_actions} micro-actions{since} in "
            f"{secs:.3f} s: {done / secs if secs > 0 else 0.0:.1f}/s)")
        self.flush()
        self.publish_status()

    def _send_command(self, req: Command) -> None:
        """COMMAND: the checked target goes out and the answer is awaited; or PAUSED, the command
        kept, while a hold is set or the recorder is behind."""
        if self._held():
            self.pending = req
            self.state = self.PAUSED
            if self.outbox:
                self.flush()
            return
        if self.rec_max_lag and self._recorder_behind():
            self._wait_for_recorder(req)
            return
        target = self._safe_command(req)
        if target is None:
            self._set_hold("fault", "the learner produced an invalid command (see /diagnostics)")
            self.pending, self.state = req, self.PAUSED
            return
        if self.scene is not None and not self._checked(req, target):
            target = self._allowed(req, target)
            if target is None:
                self._not_sent(req)
                return
        self.pending = req  # (a stepped return to rest sends it again until the rest is reached)
        self.state = self.RUNNING_COMMAND
        self.streamed = self.stream is not None and not self._sim_only()
        if self.streamed:  # (the answer waits for the last setpoint: on_stream_tick)
            self.cmd_time = math.inf
            self.js_fresh = self.tip_fresh = False
            self.stream.begin(self.js_alpha, target, time.monotonic())
            if self.trajectory:
                self._publish_trajectory(self.js_alpha, target, self.stream.duration)
        else:
            self._await_answer()
            self._publish_setpoint(target)
        # while the driver works: publish the queued reports/samples in bursts
        if self.outbox and (len(self.outbox) >= self.publish_batch
                            or self.cmd_time - self.last_flush >= self.publish_period):
            self.flush()

    def _request_goal(self, req: GoalRequest) -> None:
        """GOAL: ``/sagg/next_goal`` is asked (answered in :meth:`on_goal`, asked again after ``goal_retry`` s)."""
        self.state = self.RUNNING_GOAL
        fut = self.goal_client.call_async(NextGoal.Request(after_report=req.after_report))
        self.goal_future, self.goal_time = fut, time.monotonic()
        fut.add_done_callback(self.on_goal)
        if self.outbox:
            self.flush()

    # ------------------------------------------------------------------ /sagg/reach
    def _frozen_memory(self, p: dict, m: int):
        """The sample memory of ``frozen_memory`` (None: learn) and its rest point when its files
        hold one (:func:`.ik.load_model`); ConfigError naming the parameter."""
        if not p["frozen_memory"]:
            return None
        try:
            mem, self.rest_point, _ = load_model(p["frozen_memory"])
        except (OSError, ValueError) as exc:
            raise ConfigError(f"parameter 'frozen_memory': {p['frozen_memory']!r}: {exc}") from exc
        if (mem.state_dim, mem.outcome_dim) != (self.robot.n, m):
            raise ConfigError(f"parameter 'frozen_memory': samples of {mem.state_dim} joints and {mem.outcome_dim} "
                              f"task dimensions; allowed: {self.robot.n} and {m} (this learner's)")
        return mem

    def _held(self) -> bool:
        """A hold stops the next command; during a reach its own hold does not."""
        return self.holds.blocking(self.reach is not None)

    def _poll_reach(self) -> None:
        """Start the next reach job once no command is in flight: learning pauses for it (the
        'reach' hold) and the learner's coroutine is kept aside (:meth:`_reach_requests`)."""
        if self.reach is not None or not self.reach_server.jobs or self.state is self.STARTING:
            return
        if "reach" not in self.holds:
            self._set_hold("reach", f"reaching a goal of {ACTION}")
        if self.state not in (self.PAUSED, self.STOPPED):
            return  # (a command or a goal request in flight: its answer comes first)
        job = self.reach = self.reach_server.take()
        if job is None:
            return
        back = self.js_alpha.copy() if self.state is self.PAUSED else None  # (learning goes on after)
        self.reach_saved = (self.coro, self.pending, self.state)
        self.coro = self._reach_requests(job, back)
        self.state = None
        self.dispatch(next(self.coro))

    def _reach_requests(self, job: ReachJob, back: np.ndarray | None):
        """The requests of one reach: back to rest first when asked (``from_rest``, as the
        evaluation's reaches start), the frozen model's steps (:func:`frozen_reach`); the result
        goes to the client then; then, when learning is to go on, back to the posture where it
        paused (in steps). The answer None to a command: canceled while it waited (a hold)."""
        y = self.tip.copy()
        result = None
        if job.from_rest and (yield Command(self.robot.rest.copy(), "reset")) is None:
            result = (y, float(np.linalg.norm(job.target - y)), 0, "canceled")
        if result is None:
            y = self.tip.copy()
            reach = frozen_reach(self.learner, self.js_alpha.copy(), y, job.target, job.tolerance, job.max_steps)
            job.distance = float(np.linalg.norm(job.target - y))
            try:
                target = next(reach)
                while not job.cancel:
                    answer = yield Command(target, "reach")
                    if answer is None:
                        break
                    alpha, y = answer
                    job.steps += 1
                    job.distance = float(np.linalg.norm(job.target - y))
                    target = reach.send((alpha, y))
                result = (y, float(np.linalg.norm(job.target - y)), job.steps, "canceled")
            except StopIteration as done:
                result = done.value
        self._answer_reach(job, result)
        if back is not None:
            yield Command(back, "return")
        yield ReachDone()

    def _answer_reach(self, job: ReachJob, result: tuple) -> None:
        """The result of one reach to its client: (reached point, error, steps, outcome) and the
        measured joint positions."""
        job.joints = self.js_alpha.copy()
        job.result = (np.array(result[0], float), *result[1:])
        job.done.set()
        self.get_logger().info(f"reach of {job.target.tolist()}: {result[3]}, error {result[1]:.6g} after "
                               f"{result[2]} steps")

    def _finish_reach(self) -> None:
        """The reach is over (and the arm back where learning paused): the learner's coroutine again."""
        self.reach = None
        self.coro, self.pending, self.state = self.reach_saved
        self.reach_saved = None
        if self.reach_server.jobs:
            self._poll_reach()  # (the next job: learning stays paused)
        else:
            self._set_hold("reach", None)

    def on_compute_ik(self, request: ComputeIK.Request, response: ComputeIK.Response) -> ComputeIK.Response:
        """``/sagg/compute_ik``: joint positions for a point of Y from the model as it is now
        (:mod:`.ik_service`); nothing moves, learning goes on after the answer."""
        self.ik_answered += 1
        return answer_ik(request, response, self.learner, self.rest_point, self.steps_limit, self.guard,
                         self.ik_points)

    # ------------------------------------------------------------------ recorder backpressure
    def _recorder_behind(self, lag: int | None = None) -> bool:
        """More than ``lag`` (default ``recorder_max_lag``) published samples not yet acknowledged by
        the slowest recorder alive (:class:`~sagg_low_level.recorder_acks.RecorderAcks`; none alive:
        no wait)."""
        lag = self.rec_max_lag if lag is None else lag
        if self.samples_published <= lag or self.rec_sub.get_publisher_count() == 0:
            return False  # (no recorder left on /sagg/recorded: none to wait for)
        now = time.monotonic()
        for count in self.rec_acks.newly_stale(now):
            self.get_logger().info(f"a recorder (acknowledged {count} samples) said nothing new for recorder_timeout "
                                   f"({self.rec_acks.timeout:g} s): no longer waited for")
        slowest = self.rec_acks.slowest(now)
        if slowest is None:
            return False
        self.rec_acked = slowest
        return self.samples_published - slowest > lag

    def _wait_for_recorder(self, req: Command) -> None:
        """Keep ``req`` until the recorder caught up (:meth:`on_recorded`); counted, logged at most every 10 s."""
        self.pending, self.state = req, self.PAUSED
        if self.outbox:
            self.flush()  # what is queued is published now, so that it can be acknowledged
        if self.rec_waiting:
            return  # (again after a hold was released)
        self.rec_waiting = True
        self.rec_waits += 1
        self.rec_wait_t0 = time.monotonic()
        self.get_logger().info(
            f"waiting for the recorder: {self.samples_published} samples published, {self.rec_acked} "
            f"acknowledged on /sagg/recorded by the slowest recorder (recorder_max_lag {self.rec_max_lag}); "
            f"{self.rec_waits} waits so far", throttle_duration_sec=10.0)

    def on_recorded(self, msg: UInt64, info: dict = sources.NO_INFO) -> None:
        """A recorder's acknowledgement: the number of samples it has recorded from index 0, per
        recorder (its publisher's sequence numbers). One larger than what was published is
        impossible: rejected (counted, logged)."""
        n = int(msg.data)
        if n > self.samples_published:
            self.guard.reject("recorded.ahead", f"/sagg/recorded: data = {n}; allowed: <= {self.samples_published} "
                                                "(the samples published so far)")
            return
        self.rec_acks.ack(info["publication_sequence_number"], n, time.monotonic())
        if self.rec_waiting and not self._recorder_behind(self.rec_max_lag // 2):
            self._recorder_caught_up()

    def _recorder_caught_up(self) -> None:
        self.rec_waiting = False
        self.rec_wait_seconds += time.monotonic() - self.rec_wait_t0
        if self.state is self.PAUSED and not self._held():
            self.state = None
            self.dispatch(self.pending)

    def _goal_retry_seconds(self) -> float:
        return self.params["goal_retry"]

    def _retry_goal_later(self) -> None:
        self.goal_future = None  # _retry_goal_request asks again
        self.goal_time = time.monotonic()

    # ------------------------------------------------------------------ outputs
    def flush(self) -> None:
        """Publish the queued reports (Report) and samples (memory index), in order. Encoding is
        skipped for a topic nobody subscribes to (the message would be dropped anyway)."""
        box = self.outbox
        samples = self.sample_pub.get_subscription_count() > 0
        reports = self.report_pub.get_subscription_count() > 0
        for item in box:
            if not isinstance(item, Report):
                if samples:
                    self.publish_sample(item)
            elif reports:
                self.publish_report(item)
        box.clear()
        self.last_flush = time.monotonic()
        if self.checkpointer is not None and self.checkpointer.maybe_save():  # (everything stored is published now)
            self._save_rest_point()

    # ------------------------------------------------------------------ checkpoint / resume
    def _setup_checkpoint(self, p: dict) -> None:
        """With ``checkpoint_dir``: resume from it if it holds a checkpoint, journal every sample
        and report before it is queued for publishing, and republish the journaled samples and
        reports of the last checkpoint intervals (receivers drop those they have)."""
        if not p["checkpoint_dir"]:
            return
        try:
            ck = LearnerCheckpointer(p["checkpoint_dir"], self.learner, p["checkpoint_every"], p["journal_fsync"])
            ck.check_resume(p["resume"])  # another run's checkpoint: refused unless asked to continue it
            replay = ck.resume(p["republish_from"])
        except (ValueError, OSError) as exc:
            raise ConfigError(f"parameter 'checkpoint_dir': {exc}") from exc
        self.checkpointer = ck
        if ck.resumed_from is not None:
            self.rest_point = rest_point_file(p["checkpoint_dir"])

        def on_report(r) -> None:
            ck.on_report(r)
            self.outbox.append(r)

        def on_sample(idx) -> None:
            ck.on_sample(idx)
            self.outbox.append(idx)

        self.learner.on_report = on_report
        self.learner.on_sample = on_sample
        self.outbox.extend(replay)
        if ck.resumed_from is not None:
            info = ck.resumed_from
            self.get_logger().info(
                f"resumed from {p['checkpoint_dir']} (generation {info['generation']}): {info['samples']} "
                f"samples, {info['reports']} reports, {info['journal_records_applied']} journal records "
                f"after the checkpoint, {info['torn_bytes']} torn bytes dropped; republishing "
                f"{info['republish']} samples/reports; the interrupted attempt is abandoned")

    def _retry_goal_request(self) -> None:
        fut = self.goal_future
        if (fut is not None and fut.done()) or time.monotonic() - self.goal_time < self.params["goal_retry"]:
            return
        if not self.goal_client.service_is_ready():
            return
        self.get_logger().warning(f"no answer to the goal request after {self.params['goal_retry']} s: "
                                  "sending it again", throttle_duration_sec=5.0)
        if fut is not None:
            self.goal_client.remove_pending_request(fut)
        new = self.goal_client.call_async(NextGoal.Request(after_report=self.learner.reports_sent))
        self.goal_future, self.goal_time = new, time.monotonic()
        new.add_done_callback(self.on_goal)

    def close(self) -> None:
        """At shutdown: publish what is queued, then the final checkpoint; the reach server last."""
        try:
            self._close_learning()
        finally:
            self.reach_server.close()

    def _close_learning(self) -> None:
        if self.rec_waits:
            self.get_logger().info(f"recorder backpressure: {self.rec_waits} waits, "
                                   f"{self.rec_wait_seconds:.3f} s in all (recorder_max_lag {self.rec_max_lag})")
        try:
            self.flush()  # (also without checkpoints: a params.yaml names none)
        finally:
            if self.checkpointer is not None:
                self.checkpointer.close()
                self._save_rest_point()
                self.checkpointer = None

    def _save_rest_point(self) -> None:
        """The rest point beside the checkpoint (``model.json``: what the model server reads)."""
        if self.rest_point is not None:
            write_rest_point(self.params["checkpoint_dir"], self.rest_point, "measured by the learner at rest")

    def now_ns(self) -> int:
        return self.get_clock().now().nanoseconds if self.sim_time else time.time_ns()

    def publish_report(self, r: Report) -> None:
        # exploration reports have no target (the message's convention); the generator uses reached
        target = r.target if r.kind != KIND_EXPLORATION else ()
        self.published["/sagg/competence"] += 1
        self.report_pub.publish(encode_report(
            self.now_ns(), r.seq, r.goal_seq, r.kind, target, r.reached, r.start, r.competence,
            r.micro_actions))

    def publish_sample(self, idx: int) -> None:
        mem = self.learner.memory
        self.published["/sagg/sample"] += 1
        self.samples_published = max(self.samples_published, idx + 1)
        self.sample_pub.publish(encode_sample(
            self.now_ns(), idx, mem.alpha[idx], mem.delta_alpha[idx], mem.delta_y[idx]))

    def publish_status(self) -> None:
        learner = self.learner
        now = time.monotonic()
        self.rate_window.append((now, learner.micro_actions))
        while len(self.rate_window) > 2 and now - self.rate_window[0][0] > 5.0:
            self.rate_window.pop(0)
        (t0, n0), (t1, n1) = self.rate_window[0], self.rate_window[-1]
        paused = self.state in (self.STARTING, self.STOPPED, self.PAUSED) or bool(self.holds)
        reason = self.pause_reason if self.state in (self.STARTING, self.STOPPED) else ""
        if self.rec_waiting:
            reason = (f"waiting for the recorder ({self.rec_acked} of {self.samples_published} samples "
                      "acknowledged on /sagg/recorded)")
        self._publish_status(learner.strategy.upper(), learner.micro_actions, len(learner.memory),
                             (n1 - n0) / (t1 - t0) if t1 > t0 else 0.0, paused,
                             "; ".join([r for r in [reason, *self.holds.values()] if r]) if paused else "",
                             self._refused_text())


def main(args: list[str] | None = None) -> int:
    sys.exit(run_node(NODE_NAME, LearnerNode, args, executor="events"))


if __name__ == "__main__":
    main()
