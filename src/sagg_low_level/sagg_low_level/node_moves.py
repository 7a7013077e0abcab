"""How the learner node's moves reach the arm (the ROS side of :mod:`.motion` and :mod:`.move_check`).

A mixin of :class:`~sagg_low_level.node.LearnerNode`, one job: a command of the learner's
coroutine, once it may go out, becomes a move on the wire. It is bounded by the joint limits and
``max_joint_step`` from the measured posture (:meth:`MoveSender._safe_command`; a return to rest in
steps, :mod:`.rest_return`), checked against the scene unless the learner checked this very move
itself (:meth:`MoveSender._checked`; refused: nothing is sent, the command is answered where the arm
is), then sent as one setpoint (the simulator alone listens, or no velocity limits are known),
setpoints streamed at ``command_rate`` within the scaled velocity limits, or one
``trajectory_msgs/JointTrajectory`` (:meth:`MoveSender.on_stream_tick`, :class:`.motion.MoveStream`);
an arm that stops following is held (``follow``) and probed. The answer (a fresh, settled
observation) is the node's (:meth:`LearnerNode._try_answer_command`)."""
from __future__ import annotations

import os
import time

import numpy as np

from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from sagg_common.cdr import encode_f64_array
from sagg_common.diagnostics import all_finite
from sagg_common.params import ConfigError
from sagg_common.publishers import UNKNOWN_NODE, describe
from sagg_common.ros_params import HW_DEPTH, params_dir, reliable

from .holds import FOLLOW
from .learner import Command
from .rest_return import detours
from .motion import RESUMED, SEND, SETTLE, STOPPED as NOT_FOLLOWING, MoveStream, velocity_limits
from .schema import command_topic

MICRO_ACTIONS = ("explore", "reach", "babble")  # the learner's Command kinds that are micro-actions
SIM_BRIDGE = "sagg_sim_bridge"       # the simulated bridge's node (rest_return 'direct' is for it only)
RECORDERS = ("sagg_run", "sagg_record")  # sagg's recorders: they subscribe to the commands, never act on them


def trajectory_message(joints, start: np.ndarray, target: np.ndarray, duration: float) -> JointTrajectory:
    """A joint_trajectory_controller's move: from ``start`` now to ``target`` at ``duration`` s, at
    rest at both ends (the controller interpolates between them)."""
    msg = JointTrajectory()
    msg.joint_names = list(joints)
    for t, q in ((0.0, start), (duration, target)):
        pt = JointTrajectoryPoint()
        pt.positions = [float(v) for v in q]
        pt.velocities = [0.0] * len(q)
        pt.time_from_start.sec, pt.time_from_start.nanosec = int(t), int(round((t - int(t)) * 1e9))
        msg.points.append(pt)
    return msg


class MoveSender:
    """The learner node's moves (the module docstring); state set by :meth:`_init_scene` and
    :meth:`_init_motion`, called from the node's ``__init__``."""

    def _init_scene(self, p: dict) -> None:
        """The scene (:mod:`.move_check`): every move is checked before it is sent; the learner's
        micro-actions by the learner itself, the other commands (return to rest, reaches) here."""
        # lazy (heavy): mujoco, only with a model or a declared scene
        from sagg_common.robot_model import in_learner_terms
        from .move_check import build_move_check
        self.scene, notices = build_move_check(p, self.robot.joint_names, params_dir() or os.getcwd(), self.learner)
        for line in notices:
            self.get_logger().info(in_learner_terms(line))
        self.learner.scene = self.scene
        self.learner.on_refusal = self._on_refusal

    def _on_refusal(self, refusal) -> None:
        """A move the scene refused (not sent): logged (at most every 10 s) and counted (/diagnostics,
        /sagg/status)."""
        self.get_logger().warning(f"move refused by the scene ({refusal.cause}: {refusal.detail}); refused so far: "
                                  f"{self._refused_text()}", throttle_duration_sec=10.0)

    def _refused_text(self) -> str:
        return ", ".join(f"{cause} {n}" for cause, n in sorted(self.learner.refused.items()))

    def _init_motion(self, p: dict) -> None:
        """How a move reaches the arm (:mod:`.motion`): streamed setpoints or a trajectory within the
        scaled velocity limits, watched for following; without limits, one setpoint per move."""
        model = p["task_model.file"]
        if model:
            model = os.path.normpath(os.path.join(params_dir() or os.getcwd(), model))
        vmax, source = velocity_limits(p, self.robot.joint_names, model)
        self.trajectory = p["command_interface"] == "trajectory"
        self.traj_pub = None
        if self.trajectory:
            if vmax is None:
                raise ConfigError("parameter 'command_interface': 'trajectory' needs velocity limits for its timing; "
                                  f"{source}: give joint_velocity_limits")
            self.traj_topic = command_topic(p)[0]
            self.traj_pub = self.create_publisher(JointTrajectory, self.traj_topic, reliable(HW_DEPTH))
            self.published[self.traj_topic] = 0
        self.stream = None if vmax is None else MoveStream(
            vmax, p["command_rate"], self.trajectory, self.learner.p["max_joint_step"], p["settle_tolerance"],
            p["follow_timeout"], p["follow_retry"], p["probe_step"], self.robot.lower, self.robot.upper)
        self.streamed = False  # the command in flight is a streamed move
        if vmax is None:
            self.get_logger().warning(f"joint velocity limits: {source}: every move goes out as one setpoint "
                                      "(fine for the simulator; a real arm needs joint_velocity_limits)")
        else:
            how = (f"as trajectories on {self.traj_topic}" if self.trajectory
                   else f"streamed at {p['command_rate']:g} Hz")
            self.get_logger().info(f"moves {how} within {[round(v, 3) for v in vmax.tolist()]} rad/s ({source})")
            self.create_timer(1.0 / p["command_rate"], self.on_stream_tick)

    def _settled_at(self, target: np.ndarray) -> bool:
        """A streamed move's end: every joint within ``settle_tolerance`` of the last setpoint and,
        when the driver publishes velocities, every one below ``settle_velocity``. (Slow alone is
        not enough: a stopped arm is slow; it never gets there and :class:`.motion.FollowWatch`
        tells it.)"""
        near = float(np.abs(self.js_alpha - target).max()) <= self.params["settle_tolerance"]
        return near and (self.js_intake.velocity is None or self.js_settled)

    def _checked(self, req, target: np.ndarray) -> bool:
        """Whether the learner itself checked this very move against the scene: one of its
        micro-actions, from the posture measured now, not clipped here (:meth:`_safe_command`).
        Every other command (a return to rest, a reach's step, a micro-action clipped because the
        arm is not where the learner believed) is checked here, from the measured posture."""
        return (req.kind in MICRO_ACTIONS and self.reach is None and np.array_equal(target, req.target)
                and np.array_equal(self.js_alpha, self.learner.alpha))

    def _allowed(self, req, target: np.ndarray) -> np.ndarray | None:
        """``target`` when the scene allows the move there from the measured posture; for a step of
        a return to rest it refuses, the first detour it allows (:func:`.rest_return.detours`: the
        return goes on from there); else None (the refusal counted and logged)."""
        refusal = self.scene.segment(self.js_alpha, target)
        if refusal is None:
            return target
        moves = self.rest_moves
        if req.kind in ("reset", "return") and moves.count < moves.limit:  # (a return ends within its limit)
            for t in detours(self.js_alpha, np.asarray(req.target, float), self.learner.p["max_joint_step"],
                             self.robot):
                if self.scene.segment(self.js_alpha, t) is None:
                    moves.final = False  # (a detour: the return steps on from where it ends)
                    return t
        self.learner.count_refusal(refusal)
        return None

    def _not_sent(self, req) -> None:
        """A command the scene refused: nothing goes out, and its answer is the posture where the
        arm is (the next fresh observation); a return to rest ends there."""
        self.pending, self.state = req, self.RUNNING_COMMAND
        self._answer_where_it_is()

    def _answer_where_it_is(self) -> None:
        """The command in flight is answered by the next observation, wherever the arm is (a move
        refused or abandoned); a return to rest ends there."""
        self.streamed = False
        self._set_hold(FOLLOW, None)  # (a next move that the arm does not follow sets it again)
        self.rest_moves.not_resting()
        self._await_answer()
        self.js_min, self.tip_min = self.js_stamp - 1, self.tip_stamp - 1  # (the newest observation answers it)

    def _await_answer(self) -> None:
        """The last setpoint of the command goes out now: its answer is the first observation
        stamped after it (``observation_delay``) that is settled, or the latest after ``settle_timeout``."""
        self.js_min = self.js_stamp + self.delay_ns
        self.tip_min = self.tip_stamp + self.delay_ns
        self.js_fresh = self.tip_fresh = False
        self.cmd_time = time.monotonic()

    def _publish_setpoint(self, target: np.ndarray) -> None:
        self.cmd_pub.publish(encode_f64_array(target))
        self.published[self.cmd_topic] += 1

    def _publish_trajectory(self, start: np.ndarray, target: np.ndarray, duration: float) -> None:
        """One JointTrajectory from ``start`` (now) to ``target`` in ``duration`` s (the velocity limits)."""
        self.traj_pub.publish(trajectory_message(self.robot.joint_names, start, target,
                                                 max(duration, 1.0 / self.params["command_rate"])))
        self.published[self.traj_topic] += 1

    def on_stream_tick(self) -> None:
        """At ``command_rate``: the streamed move in flight steps on (:class:`.motion.MoveStream`):
        the next setpoint; the wait for the settled end; a hold when the arm does not follow
        (``follow``), probes, and the move's end where the arm is once it follows again."""
        stream = self.stream
        if not self.streamed or stream.phase is None or self.state is not self.RUNNING_COMMAND:
            return
        was = stream.phase
        what, setpoint = stream.tick(self.js_alpha, time.monotonic())
        if what == SEND:
            if was in (stream.STOPPED, stream.PROBING):  # a probe
                self.get_logger().info(f"probing whether the arm follows: one setpoint {self.params['probe_step']:g} "
                                       "rad back toward where the stopped move began", throttle_duration_sec=30.0)
                if self.trajectory:
                    self._publish_trajectory(self.js_alpha, setpoint,
                                             float(np.max(np.abs(setpoint - self.js_alpha) / stream.vmax)))
                    return
            self._publish_setpoint(setpoint)
            if stream.phase is stream.SETTLING:
                self._await_answer()
        elif what == SETTLE:  # (a trajectory's time is over)
            self._await_answer()
        elif what == NOT_FOLLOWING:
            j, lag = stream.watch.lag(self.js_alpha, stream.sent)
            self._set_hold(FOLLOW, f"the arm does not follow its setpoints (protective stop or e-stop?): "
                                   f"{self.robot.joint_names[j]} {lag:.3f} rad from its setpoint, no motion for "
                                   f"follow_timeout ({self.params['follow_timeout']:g} s); probing every "
                                   f"follow_retry ({self.params['follow_retry']:g} s)")
        elif what == RESUMED:  # (the arm follows again: the move ends where it is, learning goes on)
            stream.done()
            self._answer_where_it_is()

    def _safe_command(self, req: Command) -> np.ndarray:
        """Last check before a command leaves: within the joint limits and at most
        ``max_joint_step`` from the newest MEASURED posture. The core guarantees both for a
        micro-action relative to the posture it believes (``safe_target``); they differ only if its
        belief came from a stale observation (e.g. ``observation_delay`` too short for a real-time
        driver), and then the measured posture wins: the arm never moves more than a step. Clipped
        micro-actions are counted on /diagnostics. A return to rest is sent in such steps too
        (``rest_return`` 'stepped'; :mod:`.rest_return`)."""
        target = np.asarray(req.target, dtype=float)
        robot = self.robot
        if target.shape != robot.lower.shape or not all_finite(target):
            self.guard.reject("command.invalid", f"the learner produced the command {target.tolist()}; "
                                                 f"allowed: {robot.n} finite values")
            return None
        if req.kind in ("reset", "return"):  # (a 'return' goes back where a reach paused learning)
            return self.rest_moves.command(self.js_alpha, target, req.kind == "reset" and self._direct_rest())
        self.rest_moves.not_resting()
        # (1e-9 rad: the core's own rounding of alpha + step)
        step = self.learner.p["max_joint_step"] + 1e-9
        lo, hi = np.maximum(robot.lower, self.js_alpha - step), np.minimum(robot.upper, self.js_alpha + step)
        if (target < lo).any() or (target > hi).any():
            self.guard.reject("command.clipped", f"command {target.tolist()} outside the joint limits or "
                                                 "max_joint_step from the current posture: clipped")
            return np.minimum(np.maximum(target, lo), hi)
        return target

    def _direct_rest(self) -> bool:
        """``rest_return`` 'direct' applies: only the simulator listens (:meth:`_sim_only`).
        Anything else (a real driver) gets the stepped return, logged once per change of listeners."""
        if self.rest_return != "direct":
            return False
        before = self._cmd_subs
        ok = self._sim_only()
        if not ok and self._cmd_subs != before:
            others = [i for i in self.get_subscriptions_info_by_topic(self.cmd_topic)
                      if i.node_name not in (SIM_BRIDGE,) + RECORDERS]
            self.get_logger().warning(
                f"rest_return 'direct' ignored: {self.cmd_topic} is subscribed by "
                f"{'; '.join(describe(i) for i in others) or 'no simulator'}, not only the simulator: returning "
                "to rest in steps of max_joint_step")
        return ok

    def _sim_only(self) -> bool:
        """The commands topic is listened to by the simulated bridge and otherwise only by sagg's
        recorders (re-read when its subscriber count changes): it gets a move as one setpoint."""
        if self.trajectory:
            return False
        n = self.cmd_pub.get_subscription_count()
        if n != self._cmd_subs[0]:
            infos = self.get_subscriptions_info_by_topic(self.cmd_topic)
            others = [i for i in infos if i.node_name not in (SIM_BRIDGE,) + RECORDERS]
            ok = any(i.node_name == SIM_BRIDGE for i in infos) and not others
            unknown = any(i.node_name == UNKNOWN_NODE for i in infos)
            self._cmd_subs = (-1 if unknown else n, ok)
        return self._cmd_subs[1]
