"""A second robot driver for the driver-swap test: a planar arm that is NOT MuJoCo and NOT lockstep.

It behaves like a real position-controlled arm behind ros2_control plus a tracking camera:

- a control loop at ``--rate`` Hz moves each joint toward its commanded position at most
  ``--max-velocity`` rad/s (the command is clipped to the joint limits first, as a controller does);
- every cycle it publishes ``/joint_states`` (positions and velocities, with reading noise
  ``--noise`` rad and rad/s, joints named ``--joint-prefix``0..n-1 in REVERSED order) and the tip on
  ``/tip_position`` (forward kinematics of the true posture plus camera noise ``--tip-noise``);
  both are sampled now but published ``--latency`` s later (a delay line), stamped with the
  sampling time;
- commands arrive on ``/<controller>/commands`` (std_msgs/Float64MultiArray, joint order = the
  learner's ``joints`` parameter, i.e. ``prefix0..prefix{n-1}``).

An arm known by its model instead (``task_source: model``): ``--joint-names`` (the
command order), ``--lower``/``--upper`` (per-joint limits) and ``--no-tip`` (no tracker: only
/joint_states, as most ros2_control drivers).

Forward kinematics: numpy only (``sagg_sim_bridge.arm.forward_kinematics`` of the link lengths).
Run: ``python test/fake_driver.py --dof 3 --lengths 20 15 10 --rate 250 --latency 0.008``.
"""
from __future__ import annotations

import argparse
import collections
import signal
import sys

import numpy as np
import rclpy
import rclpy.executors
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from sagg_sim_bridge.arm import forward_kinematics


class FakeArmDriver(Node):
    def __init__(self, a: argparse.Namespace):
        super().__init__("fake_arm_driver")
        self.n = a.dof
        self.lengths = np.asarray(a.lengths, dtype=float)
        self.lower = np.asarray(a.lower, dtype=float) if a.lower else np.full(self.n, -a.limit)
        self.upper = np.asarray(a.upper, dtype=float) if a.upper else np.full(self.n, a.limit)
        self.tip = not a.no_tip
        self.q = np.asarray(a.rest, dtype=float).copy()
        self.target = self.q.copy()
        self.vel = np.zeros(self.n)
        self.rate = a.rate
        self.max_step = a.max_velocity / a.rate
        self.noise, self.tip_noise = a.noise, a.tip_noise
        self.rng = np.random.default_rng(a.seed)
        self.names = (list(a.joint_names) or [f"{a.joint_prefix}{i}" for i in range(self.n)])[::-1]
        self.delay = collections.deque()
        self.latency_ns = int(a.latency * 1e9)
        self.commands = 0
        self.largest_jump = 0.0
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.js_pub = self.create_publisher(JointState, "/joint_states", qos)
        self.tip_pub = self.create_publisher(PointStamped, "/tip_position", qos) if self.tip else None
        self.create_subscription(Float64MultiArray, f"/{a.controller}/commands", self.on_command, qos)
        self.create_timer(1.0 / a.rate, self.on_cycle)

    def on_command(self, msg: Float64MultiArray) -> None:
        target = np.asarray(msg.data, dtype=float)
        if target.shape != (self.n,) or not np.all(np.isfinite(target)):
            self.get_logger().error(f"bad command of {len(msg.data)} values ignored")
            return
        self.commands += 1
        self.target = np.clip(target, self.lower, self.upper)
        # how far a command asks a joint to go from where the arm is when it arrives (a jump, if large)
        self.largest_jump = max(self.largest_jump, float(np.abs(self.target - self.q).max()))

    def on_cycle(self) -> None:
        step = np.clip(self.target - self.q, -self.max_step, self.max_step)
        self.q = self.q + step
        self.vel = step * self.rate  # rad/s over the last cycle
        now = self.get_clock().now()
        tip = forward_kinematics(self.q[None, :], self.lengths)[0] if self.tip else (0.0, 0.0)
        js = JointState()
        js.header.stamp = now.to_msg()
        js.name = self.names
        # reversed order on the wire: the learner must match joints by name
        js.position = (self.q + self.noise * self.rng.standard_normal(self.n))[::-1].tolist()
        js.velocity = (self.vel + self.noise * self.rng.standard_normal(self.n))[::-1].tolist()
        pt = PointStamped()
        pt.header.stamp = js.header.stamp
        pt.header.frame_id = "camera"
        pt.point.x = float(tip[0] + self.tip_noise * self.rng.standard_normal())
        pt.point.y = float(tip[1] + self.tip_noise * self.rng.standard_normal())
        self.delay.append((now.nanoseconds + self.latency_ns, js, pt))
        while self.delay and self.delay[0][0] <= now.nanoseconds:
            _, js_out, pt_out = self.delay.popleft()
            self.js_pub.publish(js_out)
            if self.tip:
                self.tip_pub.publish(pt_out)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dof", type=int, default=3)
    ap.add_argument("--lengths", type=float, nargs="+", default=[20.0, 15.0, 10.0])
    ap.add_argument("--rest", type=float, nargs="+", default=None)
    ap.add_argument("--limit", type=float, default=np.pi / 2)
    ap.add_argument("--rate", type=float, default=250.0)
    ap.add_argument("--latency", type=float, default=0.008)
    ap.add_argument("--max-velocity", type=float, default=4.0)
    ap.add_argument("--noise", type=float, default=1e-4)
    ap.add_argument("--tip-noise", type=float, default=0.01)
    ap.add_argument("--controller", default="forward_position_controller")
    ap.add_argument("--joint-prefix", default="axis_")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--joint-names", nargs="+", default=[], help="the joints, in command order")
    ap.add_argument("--lower", type=float, nargs="+", default=[], help="per-joint lower limits")
    ap.add_argument("--upper", type=float, nargs="+", default=[], help="per-joint upper limits")
    ap.add_argument("--no-tip", action="store_true", help="publish no /tip_position")
    a = ap.parse_args(argv)
    if a.rest is None:
        a.rest = [0.3] * a.dof
    per_joint = [a.rest] + ([] if a.no_tip else [a.lengths]) + [v for v in (a.joint_names, a.lower, a.upper) if v]
    if any(len(v) != a.dof for v in per_joint):
        ap.error("--lengths, --rest, --joint-names, --lower, --upper need one value per joint (--dof)")
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = FakeArmDriver(a)
    stop = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    ex = rclpy.executors.SingleThreadedExecutor()
    ex.add_node(node)
    while not stop and rclpy.ok():
        ex.spin_once(timeout_sec=0.05)
    print(f"fake driver: {node.commands} commands, largest jump {node.largest_jump:.6f} rad", flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
