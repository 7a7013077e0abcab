"""The synergy bridge node (``synergy_bridge``): the simulated quadruped or fishing rod behind the
joint_trajectory_controller contract (paper Sec. 4-5).

Builds the simulator of parameter ``setup`` exactly as the in-process run does
(:func:`~sagg_sim_bridge.synergy_params.make_sim`) and:

- subscribes ``/<controller>/joint_trajectory`` (trajectory_msgs/JointTrajectory; joints matched by
  name; ``time_from_start`` read as whole nanoseconds); each trajectory is one experiment: the
  simulator restores its rest state, tracks the trajectory (positions for the quadruped, velocities
  for the fishing rod) and measures the outcome;
- publishes the outcome on ``task_topic`` with the trajectory's ``header.stamp`` echoed (the learner
  matches answers by it) and ``frame_id``: the quadruped's torso as ``geometry_msgs/PoseStamped``
  (position (u, v, 0) in the start frame, orientation = the yaw φ as an un-normalised quaternion
  (cos φ/2, 0, 0, sin φ/2), whose sign keeps φ in (-2π, 2π]); the fishing float as ``PointStamped``
  (x, y, 0) at its first water contact, NaN coordinates when it never touched the water.

An empty trajectory (no points) means "do nothing": the answer is the rest outcome (the learner asks
this once at start, for the competence's y_start). Experiments are run in the subscription callback,
one at a time, so the run is lockstep by construction: a deterministic function of the trajectories.
"""
from __future__ import annotations

import math
import sys
import time

import numpy as np
from rclpy.node import Node

from geometry_msgs.msg import PointStamped, PoseStamped
from trajectory_msgs.msg import JointTrajectory
from diagnostic_msgs.msg import DiagnosticArray

from sagg_common.diagnostics import InputGuard, diagnostic_array
from sagg_common.ros_params import HW_DEPTH, declare_schema, reliable, run_node
from sagg_common.synergy import Trajectory, duration_seconds, yaw_quaternion

from .schema import SYNERGY_BRIDGE_SCHEMA as SCHEMA
from .synergy_params import make_sim

NODE_NAME = "sagg_sim_bridge"


def trajectory_from_msg(msg) -> Trajectory | None:
    """A JointTrajectory message as a :class:`~sagg_common.synergy.Trajectory` (None when empty)."""
    if not msg.points:
        return None
    times = [duration_seconds(p.time_from_start.sec, p.time_from_start.nanosec) for p in msg.points]
    pos = [list(p.positions) for p in msg.points]
    vel = [list(p.velocities) for p in msg.points]
    has_pos = all(len(p) for p in pos)
    has_vel = all(len(v) for v in vel)
    return Trajectory(list(msg.joint_names), times, positions=np.array(pos) if has_pos else None,
                      velocities=np.array(vel) if has_vel else None)


class SynergyBridgeNode(Node):
    def __init__(self):
        super().__init__(NODE_NAME)
        p = self.params = declare_schema(self, SCHEMA)
        self.sim = make_sim(p)
        self.setup = p["setup"]
        self.pose = self.sim.task_dim == 3
        topic = f"/{p['controller'].strip('/')}/joint_trajectory"
        self.out_pub = self.create_publisher(PoseStamped if self.pose else PointStamped, p["task_topic"],
                                             reliable(HW_DEPTH))
        self.create_subscription(JointTrajectory, topic, self.on_trajectory, reliable(HW_DEPTH))
        self.published = {p["task_topic"]: 0}  # logged at shutdown (run_node): what a bag must hold
        self.experiments = 0
        self.busy_seconds = 0.0
        self.guard = InputGuard(self.get_logger().error)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable(10))
        self.create_timer(1.0, self.publish_diagnostics)
        self.get_logger().info(f"{self.setup}: trajectories from {topic}, outcomes on {p['task_topic']} "
                               f"({'PoseStamped' if self.pose else 'PointStamped'})")

    def on_trajectory(self, msg) -> None:
        t0 = time.perf_counter()
        traj = None
        try:
            traj = trajectory_from_msg(msg)  # Trajectory checks shapes, order and finiteness
            y = self.sim.rest_outcome if traj is None else self.sim.execute(traj)
        except (ValueError, IndexError, KeyError, TypeError) as exc:
            # answered with the "no outcome" value, so the learner does not wait for it
            self.guard.reject("trajectory.invalid", f"trajectory rejected: {exc}")
            traj, y = None, None
        if traj is not None:
            self.experiments += 1
        self.busy_seconds += time.perf_counter() - t0
        self.publish_outcome(msg.header.stamp, y)

    def publish_diagnostics(self) -> None:
        state = {"experiments": str(self.experiments), "setup": self.setup}
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().to_msg(), NODE_NAME, self.guard, state))

    def publish_outcome(self, stamp, y) -> None:
        if self.pose:
            out = PoseStamped()
            out.header.stamp = stamp
            out.header.frame_id = self.params["frame_id"]
            if y is None:
                out.pose.position.x = out.pose.position.y = math.nan
                out.pose.orientation.w = 1.0
            else:
                out.pose.position.x, out.pose.position.y = float(y[0]), float(y[1])
                w, x, yy, z = yaw_quaternion(float(y[2]))
                out.pose.orientation.w, out.pose.orientation.z = w, z
        else:
            out = PointStamped()
            out.header.stamp = stamp
            out.header.frame_id = self.params["frame_id"]
            if y is None:
                out.point.x = out.point.y = math.nan
            else:
                out.point.x, out.point.y = float(y[0]), float(y[1])
        self.out_pub.publish(out)
        self.published[self.params["task_topic"]] += 1


def main(args: list[str] | None = None) -> int:
    sys.exit(run_node(NODE_NAME, SynergyBridgeNode, args, executor="single"))


if __name__ == "__main__":
    main()
