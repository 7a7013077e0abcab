"""The learner's ``/sagg/reach`` action (sagg_msgs/action/Reach): use what was learned.

A client sends a point of the task space Y; the learner reaches it with its frozen model from the
current posture (:func:`~sagg_low_level.evaluate.frozen_reach`: reaching steps only, nothing
stored) under the rules of learning: joint limits, ``max_joint_step`` from the measured posture,
fresh and settled observations, the safety holds. Feedback after every step: the distance to the
target; result: the reached point, its error, the steps and why it stopped; cancelable. While
the learner is learning, learning pauses for the reach (the micro-action in flight completes
first) and the arm goes back, in steps, to where learning paused before it resumes.

As the goal generator's :class:`~sagg_goal_generator.node.GoalServer` does for its service, the
action server lives on a node of its own spun by an executor in a thread of the learner's
process: the goal callback must wait for the reach, which the learner node drives from its own
callbacks (commands out, joint states in). The two threads share only :class:`ReachJob` objects
(a queue the learner takes them from, plain attributes, a ``threading.Event``).
"""
from __future__ import annotations

import collections
import math
import threading

import numpy as np
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

from sagg_common.diagnostics import goal_problem
from sagg_msgs.action import Reach

ACTION = "/sagg/reach"


class ReachJob:
    """One reach request, shared between the action's thread and the learner node."""

    def __init__(self, target: np.ndarray, tolerance: float, max_steps: int, from_rest: bool = False):
        self.target, self.tolerance, self.max_steps = target, float(tolerance), int(max_steps)
        self.from_rest = bool(from_rest)
        self.cancel = False          # set by the action's thread (cancel request)
        self.steps = 0               # set by the learner node, read for feedback
        self.distance = math.nan
        self.result: tuple | None = None   # (reached point, error, steps, outcome)
        self.joints: np.ndarray | None = None  # the measured joint positions at the end
        self.done = threading.Event()


class ReachServer:
    """``/sagg/reach`` on a node of its own (``<learner>_reach``) in a thread; jobs go to
    ``jobs`` (the learner takes them). One goal at a time: a goal sent while another is active
    is rejected (its client is told; the two executor threads stay free for cancel and result
    requests). Rejected goals go to ``rejections`` as ``(kind, message)``: the learner node
    counts and logs them in its own thread (its input guard is not shared between threads).
    ``max_steps_limit``: the largest ``max_steps`` a goal may ask for; ``joint_names``: the
    learner's joints (the order of a result's ``joints``)."""

    def __init__(self, owner, task_lower, task_upper, max_steps_limit: int, joint_names=()):
        self.lower, self.upper = np.asarray(task_lower, float), np.asarray(task_upper, float)
        self.joint_names = [str(j) for j in joint_names]
        self.max_steps_limit = int(max_steps_limit)
        self.jobs: collections.deque[ReachJob] = collections.deque()
        self.rejections: collections.deque[tuple[str, str]] = collections.deque(maxlen=1000)
        self._lock = threading.Lock()
        self._active = 0  # goals accepted and not finished
        self.node = Node(owner.get_name() + "_reach", context=owner.context, use_global_arguments=False,
                         start_parameter_services=False)
        self.server = ActionServer(self.node, Reach, ACTION, execute_callback=self._execute,
                                   goal_callback=self._on_goal, cancel_callback=lambda _gh: CancelResponse.ACCEPT)
        self.stopping = threading.Event()
        # two threads: one waits in a goal's execute callback while the other takes cancel
        # requests, result requests and further goals
        self.executor = MultiThreadedExecutor(num_threads=2, context=owner.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, name="reach_server", daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        try:
            while not self.stopping.is_set() and self.node.context.ok():
                self.executor.spin_once(timeout_sec=0.1)
        except Exception:  # noqa: BLE001 - the context was shut down under the thread
            if self.node.context.ok():
                raise

    def _on_goal(self, goal) -> GoalResponse:
        """A target must have one finite value per task dimension, within Y; tolerance >= 0;
        max_steps at most ``max_steps_limit``; no other goal active."""
        _, why = goal_problem(goal.target, self.lower, self.upper)
        kind = "reach.invalid"
        if not why and not (math.isfinite(goal.tolerance) and goal.tolerance >= 0.0):
            why = f"tolerance {goal.tolerance}; allowed: a finite number >= 0 (0 = eval.tolerance)"
        if not why and goal.max_steps > self.max_steps_limit:
            why = (f"max_steps {goal.max_steps}; allowed: 0 (the evaluation's budget) to {self.max_steps_limit} "
                   "(10x the evaluation's budget across Y)")
        with self._lock:
            if not why and self._active:
                kind, why = "reach.busy", "while another reach is active; allowed: one at a time (cancel it first)"
            if why:
                self.rejections.append((kind, f"{ACTION}: target {list(goal.target)} {why}; goal rejected"))
                return GoalResponse.REJECT
            self._active += 1
        return GoalResponse.ACCEPT

    def _execute(self, goal_handle):
        try:
            return self._run(goal_handle)
        finally:
            with self._lock:
                self._active -= 1

    def _run(self, goal_handle):
        g = goal_handle.request
        job = ReachJob(np.array(g.target, dtype=float), g.tolerance, g.max_steps, g.from_rest)
        with self._lock:
            self.jobs.append(job)
        sent = -1
        while not job.done.wait(0.05):
            if goal_handle.is_cancel_requested:
                job.cancel = True
            if job.steps != sent and math.isfinite(job.distance):
                sent = job.steps
                goal_handle.publish_feedback(Reach.Feedback(distance=job.distance, steps=job.steps))
            if self.stopping.is_set():
                job.cancel = True
                break
        result = Reach.Result()
        if job.result is None:
            goal_handle.abort()
            result.outcome = "the learner stopped"
            return result
        reached, error, steps, outcome = job.result
        result.reached, result.error, result.steps, result.outcome = [float(v) for v in reached], error, steps, outcome
        if job.joints is not None:
            result.joint_names, result.joints = self.joint_names, [float(v) for v in job.joints]
        if outcome == "canceled":
            goal_handle.canceled()
        elif outcome in ("reached", "budget"):
            goal_handle.succeed()
        else:
            goal_handle.abort()
        return result

    def take(self) -> ReachJob | None:
        """The next job for the learner (None: none waiting)."""
        with self._lock:
            return self.jobs.popleft() if self.jobs else None

    def take_canceled(self) -> list[ReachJob]:
        """The jobs canceled before the learner took them (e.g. while a hold kept the previous
        reach's return waiting): the learner answers them at once, nothing moved."""
        with self._lock:
            gone = [j for j in self.jobs if j.cancel]
            for j in gone:
                self.jobs.remove(j)
        return gone

    def close(self) -> None:
        self.stopping.set()
        self.thread.join(timeout=5.0)
        self.server.destroy()
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
