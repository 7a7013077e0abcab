"""The driver as the external run and ``sagg check-driver`` see it (:class:`DriverMonitor`): what it
publishes, read by this process's own subscriptions with the learner's rules (the one joint-state
intake), and what of the hardware contract (docs/your-robot.md) it does not meet yet."""
from __future__ import annotations

import os
import time

import numpy as np

from sagg_common.joint_intake import AMBIGUOUS, OTHER, TAKEN
from sagg_common.ros_params import reliable
from sagg_common.sources import ACCEPT, AMBIGUOUS as SOURCES_AMBIGUOUS, NO_INFO, SourceChains, with_message_info
from sagg_low_level.schema import command_topic, joint_intake

JS_TYPE = "sensor_msgs/msg/JointState"
TIP_TYPE = "geometry_msgs/msg/PointStamped"


class DriverMonitor:
    """What the driver publishes, from this process's own subscriptions (:meth:`subscribe`): joint
    states read by the learners' one intake (:class:`~sagg_common.joint_intake.JointStateIntake`,
    with the learner parameters ``lp``: mapped by name, checked, one source, stamps), the newest
    task point and its stamp, receive times; and :meth:`missing`, the contract items not yet met,
    each naming topic, type or joints. A JointState naming none of the joints is another driver's
    and ignored (its name list is kept for the report), and while the joints (or the task points)
    come from two sources (:class:`~sagg_common.sources.SourceChains`) nothing of that stream is
    taken: the evaluation on the robot commands from these readings."""

    def __init__(self, lp: dict, task_topic: str, task_fk=None):
        self.joints = list(lp["joints"])
        self.task_topic = task_topic
        self.cmd_topic, self.cmd_type = command_topic(lp)  # (the learner's command_interface)
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
        from trajectory_msgs.msg import JointTrajectory
        node.create_subscription(JointState, "/joint_states", with_message_info(self.on_joint_state), reliable(100),
                                 raw=True)
        if self.task_fk is None:
            node.create_subscription(PointStamped, self.task_topic, with_message_info(self.on_task_point),
                                     reliable(100))
        cmd_class = JointTrajectory if self.cmd_type.startswith("trajectory_msgs") else Float64MultiArray
        node.create_subscription(cmd_class, self.cmd_topic, self.on_command, reliable(100))

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
        wrong = sorted({s.topic_type for s in subs if s.topic_type != self.cmd_type})
        if not subs:
            out.append(f"{self.cmd_topic} ({self.cmd_type}): no subscriber (the driver's controller)")
        elif wrong:
            out.append(f"{self.cmd_topic}: subscribed as {', '.join(wrong)}; expected {self.cmd_type}")
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
