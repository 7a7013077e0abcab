"""The one client of the learned model's ROS interface: the action ``/sagg/reach``
(sagg_msgs/action/Reach) and the service ``/sagg/compute_ik`` (sagg_msgs/srv/ComputeIK).

:class:`ReachClient` works on any node of this process, spun by the caller's ``spin`` (the
evaluation on the robot: the run's own node and session); :class:`OwnReachClient` brings its own
rclpy context, node and executor on a ROS domain (``sagg reach``, ``sagg serve``, a script)."""
from __future__ import annotations

import time
from typing import Callable

from .processes import GraphError

# how long the learner may take to accept a goal, and to answer once one is canceled (its last
# step completes and the arm settles first)
ACCEPT_SECONDS, CANCEL_SECONDS = 30.0, 60.0


class ReachClient:
    """``/sagg/reach`` and ``/sagg/compute_ik`` from ``node``, one request at a time; ``spin()``
    spins the node's executor once, briefly (and may check what the caller watches meanwhile, e.g.
    that the graph's nodes are alive, raising GraphError). Every reach and its result are kept in
    ``trace``; ``distance``: the last feedback's distance to the goal."""

    def __init__(self, node, spin: Callable[[], None]):
        # lazy (heavy): ROS
        from rclpy.action import ActionClient
        from sagg_msgs.action import Reach
        self.node, self.spin, self.Reach = node, spin, Reach
        self.client = ActionClient(node, Reach, "/sagg/reach")
        self.ik = None  # the /sagg/compute_ik client (made at the first use)
        self.distance = float("nan")
        self.trace: list[dict] = []

    def wait(self, done: Callable[[], bool], seconds: float) -> bool:
        """Spin until ``done()`` (True) or ``seconds`` s have passed (False)."""
        t_end = time.monotonic() + seconds
        while not done():
            self.spin()
            if time.monotonic() > t_end:
                return False
        return True

    def wait_until(self, done: Callable[[], bool], seconds: float, what: str) -> None:
        """:meth:`wait`, GraphError naming ``what`` when ``seconds`` s pass first."""
        if not self.wait(done, seconds):
            raise GraphError(f"{what} within {seconds:.0f} s")

    def wait_for_server(self, seconds: float) -> None:
        """Until ``/sagg/reach`` is served (GraphError after ``seconds`` s)."""
        self.wait_until(self.client.server_is_ready, seconds, "no /sagg/reach server (the learner)")

    def wait_for_ik(self, seconds: float) -> None:
        """Until ``/sagg/compute_ik`` is served (GraphError after ``seconds`` s)."""
        # lazy (heavy): ROS
        from sagg_msgs.srv import ComputeIK
        if self.ik is None:
            self.ik = self.node.create_client(ComputeIK, "/sagg/compute_ik")
        self.wait_until(self.ik.service_is_ready, seconds, "no /sagg/compute_ik server")

    def reach(self, goal, seconds: float, from_rest: bool = False, tolerance: float = 0.0,
              cancel: bool = True) -> dict:
        """Reach ``goal`` (from rest when ``from_rest``) within ``seconds``: the result as a dict
        (``goal``, ``reached``, ``error``, ``steps``, ``outcome``, the measured final ``joints``,
        ``seconds``, ``timed_out``, ``from_rest``). A goal still running after ``seconds`` is
        canceled when ``cancel`` (the learner completes its step and answers 'canceled' with where
        the arm is; ``timed_out`` True), else GraphError. GraphError when no server answers, the
        goal is not accepted, or a canceled goal is not answered."""
        self.wait_for_server(ACCEPT_SECONDS)
        t0 = time.monotonic()
        self.distance = float("nan")
        fut = self.client.send_goal_async(
            self.Reach.Goal(target=[float(v) for v in goal], tolerance=float(tolerance), from_rest=from_rest),
            feedback_callback=self._feedback)
        if not self.wait(fut.done, ACCEPT_SECONDS) or not fut.result().accepted:
            raise GraphError(f"/sagg/reach: goal {list(map(float, goal))} not accepted by the learner (see its log)")
        handle = fut.result()
        res = handle.get_result_async()
        timed_out = not self.wait(res.done, seconds)
        if timed_out:
            if not cancel:
                raise GraphError(f"/sagg/reach: no result within {seconds:.0f} s")
            handle.cancel_goal_async()
            if not self.wait(res.done, CANCEL_SECONDS):
                raise GraphError(f"/sagg/reach: no answer {CANCEL_SECONDS:g} s after a goal was canceled (its "
                                 "time was up): the learner or the driver stopped")
        r = res.result().result
        out = {"goal": [float(v) for v in goal], "reached": list(r.reached), "error": float(r.error),
               "steps": int(r.steps), "outcome": r.outcome, "joints": list(r.joints),
               "seconds": time.monotonic() - t0, "timed_out": timed_out, "from_rest": from_rest}
        self.trace.append(out)
        return out

    def _feedback(self, msg) -> None:
        self.distance = float(msg.feedback.distance)

    def compute_ik(self, target, start=(), start_point=(), tolerance: float = 0.0, max_steps: int = 0,
                   timeout: float = 30.0):
        """One ``/sagg/compute_ik`` call: its response and the seconds it took (request sent to
        response received)."""
        # lazy (heavy): ROS
        from sagg_msgs.srv import ComputeIK
        self.wait_for_ik(timeout)
        req = ComputeIK.Request(target=[float(v) for v in target], start=[float(v) for v in start],
                                start_point=[float(v) for v in start_point], tolerance=float(tolerance),
                                max_steps=int(max_steps))
        t0 = time.perf_counter()
        fut = self.ik.call_async(req)
        self.wait_until(fut.done, timeout, "no answer from /sagg/compute_ik")
        return fut.result(), time.perf_counter() - t0


class OwnReachClient(ReachClient):
    """A :class:`ReachClient` on a node of its own rclpy context on ROS domain ``domain``;
    ``check()``, if given, runs at every spin (e.g. ``NodeGroup.check``: GraphError when a node of
    the graph exits). :meth:`close` when done."""

    def __init__(self, domain: int, check: Callable[[], None] | None = None, name: str = "sagg_reach"):
        # lazy (heavy): ROS
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        self.rclpy, self.check = rclpy, check
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node(name, context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(node)
        super().__init__(node, self._spin_once)

    def _spin_once(self) -> None:
        self.ex.spin_once(timeout_sec=0.05)
        if self.check is not None:
            self.check()

    def close(self) -> None:
        self.client.destroy()
        self.ex.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.ctx)
