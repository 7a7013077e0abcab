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

from sagg_common.cdr import JointStateDecoder, decode_point_stamped, encode_f64_array
from sagg_common.diagnostics import all_finite
from sagg_common.ros_params import HW_DEPTH, reliable


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
        node.create_subscription(JointState, "/joint_states", self.on_joint_state, reliable(10), raw=True)
        node.create_subscription(PointStamped, self.task_topic, self.on_task_point, reliable(10), raw=True)
        self.decoder = JointStateDecoder()
        self.settle_velocity = p["settle_velocity"]
        self.settle_timeout = p["settle_timeout"]
        self.response_timeout = p["response_timeout"]
        self._names = None
        self._idx = None
        self.other_joints = 0  # /joint_states messages naming none of our joints (ignored)
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
        published = getattr(self.node, "published", None)  # (what a bag must hold; issue 11)
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
    def on_joint_state(self, data: bytes) -> None:
        guard = self.node.guard
        try:
            st, names, pos, vel = self.decoder.decode(data)
        except (ValueError, IndexError, struct.error, UnicodeDecodeError) as exc:
            guard.reject("joint_states.undecodable", f"/joint_states: undecodable message ({exc})")
            return
        if len(pos) != len(names) or (len(vel) and len(vel) != len(names)):
            guard.reject("joint_states.length", f"/joint_states: {len(names)} names but {len(pos)} positions and "
                                                f"{len(vel)} velocities; allowed: one position (and none or one "
                                                "velocity) per name")
            return
        if names is not self._names:
            where = {n: i for i, n in enumerate(names)}
            missing = [j for j in self.synergy.joint_names if j not in where]
            if len(missing) == len(self.synergy.joint_names):
                self.other_joints += 1  # another driver's joints (e.g. a gripper's): not ours, ignored
                return
            if missing or len(where) != len(names):
                guard.reject("joint_states.names", f"/joint_states lacks or repeats joints ({', '.join(missing)}); "
                                                   f"allowed: every joint of 'joints' once")
                return
            self._names, self._idx = names, np.array([where[j] for j in self.synergy.joint_names], dtype=np.intp)
        if st < self.js_stamp:
            guard.reject("joint_states.out_of_order", f"/joint_states: stamp {st} ns is older than the newest "
                                                      f"({self.js_stamp} ns); kept the newest")
            return
        alpha = pos[self._idx]
        v = vel[self._idx] if len(vel) else None
        if not (all_finite(alpha) and (v is None or all_finite(v))):
            guard.reject("joint_states.non_finite", "/joint_states: NaN/inf position or velocity; allowed: finite")
            return
        sv = self.settle_velocity
        self.alpha, self.js_stamp = alpha, st
        self.js_settled = v is None or bool(-sv < v.min() and v.max() < sv)
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
