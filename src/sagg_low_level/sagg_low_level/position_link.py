"""The arm's hardware contract for the fixed-context learner node (``fixed_learner`` with
``synergy.kind`` 'posture', i.e. the arm with ``context: fixed``): how θ becomes commands and how
the outcome is read. The same contract as the evolving-context learner node (:mod:`.node`):

- out: ``std_msgs/Float64MultiArray`` on ``/<controller>/commands`` (joint order = ``joints``);
- in: ``/joint_states`` (sensor_msgs/JointState, joints matched by name) and the tip on
  ``task_topic`` (geometry_msgs/PointStamped).

One experiment is two position commands: the rest posture (the fixed context: every experiment
starts from rest, as the synergy set-ups' bridges restore theirs), then θ; the outcome is the tip
of the answer to θ. The rest outcome (the learner's ``Observe``) is the tip after a rest command.
A command is answered by a *fresh, settled* observation: a joint state and a tip both stamped later
than the newest ones received before the command went out, every |velocity| below
``settle_velocity`` (or, ``settle_timeout`` s after the command, the latest fresh one). A lockstep
bridge publishes exactly one such state per command, so the run equals the in-process one
(:func:`sagg_bringup.inprocess.fixed_experiment.posture_outcome`). Bad input is rejected through the node's
InputGuard (field, value, allowed range; counted on /diagnostics) and changes no state.
"""
from __future__ import annotations

import math
import struct
import time
from typing import Callable

import numpy as np

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from sagg_common import sources
from sagg_common.cdr import decode_point_stamped, encode_f64_array
from sagg_common.joint_intake import AMBIGUOUS, TAKEN
from sagg_common.ros_params import HW_DEPTH, reliable

from .schema import joint_intake


class PositionLink:
    """Position commands out, settled joint states and tip in, for ``node`` (a synergy learner node
    with ``guard``, ``params`` and ``get_logger``); ``synergy`` is a PostureSynergy. ``answer(y)`` is
    called with the outcome of each :meth:`observe` / :meth:`execute`; ``fail(text)`` on a timeout."""

    def __init__(self, node, synergy, answer: Callable, fail: Callable):
        p = node.params
        self.node, self.synergy, self.answer, self.fail = node, synergy, answer, fail
        self.topic = f"/{p['controller'].strip('/')}/commands"
        self.task_topic = p["task_topic"]
        self.pub = node.create_publisher(Float64MultiArray, self.topic, reliable(HW_DEPTH))
        node.create_subscription(JointState, "/joint_states", sources.with_message_info(self.on_joint_state),
                                 reliable(10), raw=True)
        node.create_subscription(PointStamped, self.task_topic, self.on_task_point, reliable(10), raw=True)
        self.intake = joint_intake(p, synergy.joint_names, synergy.lower, synergy.upper)
        self.settle_timeout = p["settle_timeout"]
        self.response_timeout = p["response_timeout"]
        self.alpha = None
        self.js_stamp = self.tip_stamp = -1
        self.js_settled = False
        self.tip = None
        self.queue: list[np.ndarray] = []  # commands still to send for the pending request
        self.waiting = False
        self.js_min = self.tip_min = 0
        self.js_fresh = self.tip_fresh = False
        self.sent_time = 0.0

    # ------------------------------------------------------------------ requests
    def ready(self) -> bool:
        """A joint state and a tip were received (the node checks that the commands are listened to)."""
        return self.alpha is not None and self.tip is not None

    def observe(self) -> None:
        """The rest outcome: a rest command, answered with the settled tip."""
        self._start([self.synergy.rest])

    def execute(self, theta) -> None:
        """One experiment: back to rest, then θ; answered with the settled tip."""
        self._start([self.synergy.rest, self.synergy.command(theta)])

    def _start(self, commands: list[np.ndarray]) -> None:
        self.queue = list(commands)
        self._send_next()

    def _send_next(self) -> None:
        target = self.queue.pop(0)
        self.js_min, self.tip_min = self.js_stamp, self.tip_stamp
        self.js_fresh = self.tip_fresh = False
        self.waiting = True
        self.sent_time = time.monotonic()
        self.pub.publish(encode_f64_array(np.asarray(target, dtype=float)))
        published = getattr(self.node, "published", None)  # (what a bag must hold)
        if published is not None:
            published[self.topic] = published.get(self.topic, 0) + 1

    def poll(self) -> None:
        """Settle and response timeouts of the command in flight."""
        if not self.waiting:
            return
        waited = time.monotonic() - self.sent_time
        if self.js_fresh and self.tip_fresh and waited > self.settle_timeout:
            self.node.get_logger().warning(f"no settled joint state {self.settle_timeout} s after a command: "
                                           "taking the latest", throttle_duration_sec=5.0)
            self._answered()
        elif waited > self.response_timeout:
            self.waiting = False
            self.fail(f"no fresh joint_states / tip on {self.task_topic} {self.response_timeout} s after a "
                      f"command on {self.topic}: is the driver running?")

    # ------------------------------------------------------------------ observations
    def on_joint_state(self, data: bytes, info: dict = sources.NO_INFO) -> None:
        """A JointState, read by the learners' one intake (:class:`~sagg_common.joint_intake.JointStateIntake`):
        what it does not take is counted and logged through the node's guard (another driver's
        joints are ignored); what it takes is the newest posture."""
        intake = self.intake
        verdict = intake.take(data, info["publication_sequence_number"])
        code = verdict.code
        if code is AMBIGUOUS:
            self.node.guard.reject("joint_states.second_source",
                                   f"/joint_states: the joints {', '.join(intake.joints)} from two sources; "
                                   f"message dropped until one has been quiet for {intake.sources.grace:g} s")
        elif verdict.kind:  # a rejection, or a clock jump back (taken: logged)
            self.node.guard.reject(verdict.kind, verdict.message)
        if code is not TAKEN:
            return
        st = intake.stamp
        self.alpha, self.js_stamp, self.js_settled = intake.position, st, intake.settled
        if self.waiting and st > self.js_min:
            self.js_fresh = True
            self._try_answer()

    def on_task_point(self, data: bytes) -> None:
        guard = self.node.guard
        try:
            st, xyz = decode_point_stamped(data)
        except (ValueError, IndexError, struct.error) as exc:
            guard.reject("task_point.undecodable", f"{self.task_topic}: undecodable message ({exc})")
            return
        if st < self.tip_stamp:
            guard.reject("task_point.out_of_order", f"{self.task_topic}: stamp {st} ns is older than the newest "
                                                    f"({self.tip_stamp} ns); kept the newest")
            return
        xy = xyz[:2]
        if not all(map(math.isfinite, xy)):
            guard.reject("task_point.non_finite", f"{self.task_topic}: NaN/inf coordinate {list(xy)}; "
                                                  "allowed: finite values")
            return
        self.tip, self.tip_stamp = np.array(xy), st
        if self.waiting and st > self.tip_min:
            self.tip_fresh = True
            self._try_answer()

    def _try_answer(self) -> None:
        if self.js_fresh and self.tip_fresh and self.js_settled:
            self._answered()

    def _answered(self) -> None:
        self.waiting = False
        if self.queue:
            self._send_next()
        else:
            self.answer(self.tip.copy())
