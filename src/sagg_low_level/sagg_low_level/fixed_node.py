"""The synergy learner node (``fixed_learner``): the fixed-context low level (paper Sec. 4-5, Alg. 4)
on ROS 2, speaking the joint_trajectory_controller contract.

It drives the :class:`~sagg_low_level.fixed_context.FixedContextLearner` coroutine from callbacks:

- ``Observe`` (the rest outcome y_rest): publishes an EMPTY ``trajectory_msgs/JointTrajectory`` (no
  points: "do nothing") and takes the outcome the driver answers with;
- ``Execute(θ)``: turns θ into a trajectory with the configured synergy
  (:mod:`sagg_common.synergy`) and publishes it on ``/<controller>/joint_trajectory``; the header
  stamp is a per-trial counter (1, 2, ... ns) that the driver echoes in the outcome's header, which
  is how the answer is matched. The outcome arrives on ``task_topic``: ``geometry_msgs/PoseStamped``
  for a 3-D task space (u = position.x, v = position.y, φ = 2·atan2(q.z, q.w), the unwrapped yaw)
  or ``PointStamped`` for 2-D (x, y); NaN coordinates mean "no outcome" (a cast whose float never
  touched the water), which the learner discards and counts;
- ``GoalRequest``: calls ``/sagg/next_goal`` (answered once the reports 1..after_report are processed).

With ``synergy.kind`` 'posture' (the arm with ``context: fixed``) the node speaks the arm's position
contract instead of the trajectory controller's: :class:`~sagg_low_level.position_link.PositionLink`
(a rest command then θ on ``/<controller>/commands``, the settled tip back with ``/joint_states``).

Every report goes to ``/sagg/competence``; every stored experiment to ``/sagg/sample`` as
``alpha = θ``, ``delta_alpha = []``, ``delta_y = y`` (the outcome itself: the context is fixed);
``/sagg/status`` at 2 Hz (``micro_actions`` = stored experiments). At ``max_experiments`` it stops
acting, exactly where the in-process run stops.
"""
from __future__ import annotations

import sys
import time

import numpy as np
from builtin_interfaces.msg import Duration, Time
from geometry_msgs.msg import PointStamped, PoseStamped
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from sagg_common.diagnostics import InputGuard, diagnostic_array
from sagg_common.msg_codecs import encode_report, encode_sample
from sagg_common.ros_params import HW_DEPTH, reliable, run_node
from sagg_common.synergy import quaternion_yaw
from sagg_msgs.srv import NextGoal

from .fixed_context import Execute, FixedContextLearner, ThetaSpace, synergy_from_params
from .learner_shared import GoalRequest, Observe, Report
from .node_base import NODE_NAME, LearnerNodeBase
from .position_link import PositionLink
from .schema import FIXED_CORE_SCHEMA as CORE_SCHEMA, FIXED_LEARNER_SCHEMA as SCHEMA


def trajectory_msg(traj, stamp_ns: int) -> JointTrajectory:
    """A :class:`~sagg_common.synergy.Trajectory` as a JointTrajectory (time_from_start from the
    canonical whole-nanosecond times, positions and/or velocities per point)."""
    msg = JointTrajectory()
    msg.header.stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    msg.joint_names = list(traj.joint_names)
    points = []
    for k, t in enumerate(traj.times):
        ns = int(round(float(t) * 1e9))
        pt = JointTrajectoryPoint()
        pt.time_from_start = Duration(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
        if traj.positions is not None:
            pt.positions = traj.positions[k].tolist()
        if traj.velocities is not None:
            pt.velocities = traj.velocities[k].tolist()
        points.append(pt)
    msg.points = points
    return msg


def outcome_of(msg) -> np.ndarray | None:
    """The outcome carried by a PoseStamped (u, v, φ) or PointStamped (x, y); None when it holds NaN."""
    if isinstance(msg, PoseStamped):
        q = msg.pose.orientation
        y = np.array([msg.pose.position.x, msg.pose.position.y, quaternion_yaw(q.w, q.z)])
    else:
        y = np.array([msg.point.x, msg.point.y])
    return y if np.all(np.isfinite(y)) else None


class SynergyLearnerNode(LearnerNodeBase):
    def __init__(self):
        super().__init__(SCHEMA)
        p = self.params
        self.synergy = synergy_from_params(p)
        core = self._build_learner(
            CORE_SCHEMA, "2 (PointStamped outcome) or 3 (PoseStamped: u, v, yaw)",
            lambda core, m: FixedContextLearner(core, ThetaSpace(self.synergy.lower, self.synergy.upper), m))
        self.max_experiments = p["max_experiments"]
        self.exit_code = 0
        self.done = False

        self.guard = InputGuard(self.get_logger().error)
        self.link = None  # synergy.kind 'posture': the arm's position contract (PositionLink)
        if p["synergy.kind"] == "posture":
            self.link = PositionLink(self, self.synergy, self.advance, self._fail)
            self.traj_topic = self.link.topic
        else:
            self.traj_topic = f"/{p['controller'].strip('/')}/joint_trajectory"
            self.traj_pub = self.create_publisher(JointTrajectory, self.traj_topic, reliable(HW_DEPTH))
            out_type = PoseStamped if self.m == 3 else PointStamped
            self.create_subscription(out_type, p["task_topic"], self.on_outcome, reliable(HW_DEPTH))
        # messages published per topic (logged at shutdown: what a bag must hold)
        self.published = {self.traj_topic: 0, "/sagg/sample": 0, "/sagg/competence": 0}
        self._create_sagg_endpoints()  # /sagg/competence, /sagg/sample, /sagg/status, /diagnostics, goals
        self.goal_retry_at: float | None = None
        self.create_timer(1.0, self.publish_diagnostics)

        self.learner.on_report = self.publish_report
        self.learner.on_sample = self.publish_sample
        self.coro = self.learner.run()
        self.pending = next(self.coro)  # Observe
        self.waiting_stamp: int | None = None
        self.trial_counter = 0
        self.sent_time = 0.0
        self.started = False
        self.goals_received = 0
        self.t_started = time.monotonic()
        self.create_timer(0.5, self.publish_status)
        self.create_timer(0.05, self.on_poll)
        self.get_logger().info(
            f"strategy {core['strategy']}, synergy {p['synergy.kind']} (θ in R^{self.synergy.dim}), "
            f"{'position commands' if self.link else 'trajectories'} on {self.traj_topic}, "
            f"outcomes on {p['task_topic']}"
            + (f", stops at {self.max_experiments} experiments" if self.max_experiments else ""))

    # ------------------------------------------------------------------ driving
    def _fail(self, text: str) -> None:
        self.get_logger().error(text)
        self.exit_code = 1
        self.done = True

    def _ready(self) -> bool:
        if self.link is not None:
            return self.link.ready() and self._peers_ready(self.link.pub, self.link.topic, match_reports=False)
        # the driver must be there: it publishes the outcome topic and listens to the trajectories
        # (a recorder subscribing to the trajectories alone does not count)
        if self.count_publishers(self.params["task_topic"]) < 1:
            return False
        # reports are published as they come (no queue): the goal generator's reader is enough
        return self._peers_ready(self.traj_pub, self.traj_topic, match_reports=False)

    def on_poll(self) -> None:
        if self.goal_retry_at is not None and time.monotonic() >= self.goal_retry_at:
            self.goal_retry_at = None
            self.dispatch(self.pending)  # the GoalRequest whose answer was rejected
        if not self.started:
            if self._ready():
                self.started = True
                self.t_started = time.monotonic()
                self.get_logger().info("graph ready: starting")
                self.dispatch(self.pending)
            return
        if self.link is not None:
            self.link.poll()
            return
        if (self.waiting_stamp is not None and type(self.pending) is Observe
                and time.monotonic() - self.sent_time > 1.0):
            # the rest-outcome query is harmless to repeat (it runs nothing): resend it once a second
            # in case the driver's subscription was not matched yet
            self.sent_time = time.monotonic()
            stamp = self.waiting_stamp
            msg = JointTrajectory()
            msg.header.stamp = Time(sec=0, nanosec=stamp)
            msg.joint_names = list(self.synergy.joint_names)
            self.traj_pub.publish(msg)
            self.published[self.traj_topic] += 1
        if self.waiting_stamp is not None and time.monotonic() - self.sent_time > self.params["response_timeout"]:
            self.get_logger().error(f"no outcome on {self.params['task_topic']} {self.params['response_timeout']} s "
                                    f"after a trajectory on {self.traj_topic}: is the driver running?")
            self.exit_code = 1
            self.done = True

    def _send(self, traj_msg_fn) -> None:
        self.trial_counter += 1
        self.waiting_stamp = self.trial_counter
        self.sent_time = time.monotonic()
        self.traj_pub.publish(traj_msg_fn(self.trial_counter))
        self.published[self.traj_topic] += 1

    def dispatch(self, req) -> None:
        if self.max_experiments and self.learner.experiments >= self.max_experiments:
            self.pending = req
            self.waiting_stamp = None
            secs = time.monotonic() - self.t_started
            self.get_logger().info(
                f"max_experiments ({self.max_experiments}) reached: stopped acting ({self.learner.experiments} "
                f"experiments, {self.learner.discarded} discarded, in {secs:.3f} s)")
            self.publish_status()
            return
        self.pending = req
        if self.link is not None and type(req) is not GoalRequest:
            if type(req) is Observe:
                self.link.observe()
            elif type(req) is Execute:
                self.link.execute(req.theta)
            else:
                raise TypeError(f"unknown learner request {req!r}")
            return
        if type(req) is Observe:
            def empty(stamp):
                msg = JointTrajectory()
                msg.header.stamp = Time(sec=0, nanosec=stamp)
                msg.joint_names = list(self.synergy.joint_names)
                return msg
            self._send(empty)
        elif type(req) is Execute:
            traj = self.synergy.trajectory(req.theta)
            self._send(lambda stamp: trajectory_msg(traj, stamp))
        elif type(req) is GoalRequest:
            fut = self.goal_future = self.goal_client.call_async(NextGoal.Request(after_report=req.after_report))
            fut.add_done_callback(self.on_goal)
        else:
            raise TypeError(f"unknown learner request {req!r}")

    def on_outcome(self, msg) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if self.waiting_stamp is None or stamp != self.waiting_stamp:
            return  # not the answer we wait for (an older trial, another learner)
        self.waiting_stamp = None
        y = outcome_of(msg)
        if type(self.pending) is Observe:
            if y is None:
                self.get_logger().error("the rest outcome (answer to the empty trajectory) holds NaN")
                self.exit_code = 1
                self.done = True
                return
        self.advance(y)

    def advance(self, answer) -> None:
        """Send ``answer`` to the pending request and dispatch the next request."""
        self.dispatch(self.coro.send(answer))

    def _goal_retry_seconds(self) -> int:
        return 1

    def _retry_goal_later(self) -> None:
        self.goal_retry_at = time.monotonic() + 1.0  # on_poll dispatches the GoalRequest again

    # ------------------------------------------------------------------ outputs
    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def publish_report(self, r: Report) -> None:
        self.published["/sagg/competence"] += 1
        self.report_pub.publish(encode_report(self._now_ns(), r.seq, r.goal_seq, r.kind, r.target, r.reached,
                                              r.start, r.competence, r.micro_actions))

    def publish_sample(self, idx: int) -> None:
        lr = self.learner
        self.published["/sagg/sample"] += 1
        self.sample_pub.publish(encode_sample(self._now_ns(), idx, lr.thetas[idx], np.zeros(0), lr.outcomes[idx]))

    def publish_diagnostics(self) -> None:
        lr = self.learner
        state = {"experiments": str(lr.experiments), "discarded": str(lr.discarded)}
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().to_msg(), NODE_NAME, self.guard, state))

    def publish_status(self) -> None:
        lr = self.learner
        secs = time.monotonic() - self.t_started
        stopped = bool(self.max_experiments and lr.experiments >= self.max_experiments)
        self._publish_status(self.params["strategy"], lr.experiments, len(lr),
                             lr.experiments / secs if self.started and secs > 0 else 0.0, stopped or not self.started,
                             "max_experiments reached" if stopped else
                             "" if self.started else "waiting for the trajectory controller and goal generator")


def main(args: list[str] | None = None) -> int:
    sys.exit(run_node(NODE_NAME, SynergyLearnerNode, args, executor="events"))


if __name__ == "__main__":
    main()

