"""The MuJoCo bridge node (``mujoco_bridge``): a simulated arm behind the hardware contract.

Builds ``ArmSim(spec, seed=substream_seed(seed, "sim"))`` from the ``arm.*`` parameters, exactly as
the in-process run does, and speaks like a ros2_control position-controlled arm plus a tracker:

- subscribes ``/<controller>/commands`` (std_msgs/Float64MultiArray, joint order = the arm's joint
  order: ``joint_0..joint_{n-1}`` for the planar arm, the commanded joints of a model arm, i.e. the
  controller's ``joints``);
- publishes ``/joint_states`` (positions, velocities; the arm's joint names) and the tip on
  ``task_topic`` (geometry_msgs/PointStamped: x, y (, z) in task units).

Timing (parameter ``timing``):

- ``lockstep``: physics advances only on a command (``ArmSim.command``: one micro-action, settled);
  then joint_states and the tip are published once, stamped with the simulation time (dynamic
  mode: MuJoCo time; kinematic mode has no physics time, so a virtual clock advancing by
  ``arm.timestep`` per command). The current state is also re-published every
  ``idle_publish_period`` s with its unchanged stamp, so late subscribers get an initial
  observation; a listener can tell a re-publication from a new state by the stamp.
  The run is then a deterministic function of the seeds (docs/graph.md).
- ``realtime``: physics runs at real-time rate (dynamic mode; a command sets the position targets
  with the same motor noise as ``ArmSim.command``, then the actuators move the arm over the next
  steps; kinematic mode applies a command at once), joint_states + tip are published at
  ``publish_rate`` Hz and the simulation time on ``/clock``.

Diagnostics (``/diagnostics``, every second): the commands received and the timing; with a scene
(a model arm whose config declares a floor or boxes, ``scene.*``) also ``contacts`` and
``contacts.self`` / ``contacts.floor`` / ``contacts.box``: the commands whose motion met an
obstacle or the arm itself (:attr:`.model_arm.ModelArmSim.contacts`; in real-time dynamic mode the
motion between two commands).
"""
from __future__ import annotations

import struct
import sys
import time

import mujoco
import numpy as np
from rclpy.node import Node

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PointStamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from diagnostic_msgs.msg import DiagnosticArray

from sagg_common.cdr import JointStateEncoder, PointStampedEncoder, decode_f64_array
from sagg_common.diagnostics import InputGuard, all_finite, diagnostic_array
from sagg_common.ros_params import HW_DEPTH, declare_schema, params_dir, reliable, run_node
from sagg_common.rng import substream_seed

from .arms import arm_spec_from_params, make_arm_sim
from .schema import BRIDGE_SCHEMA as SCHEMA

NODE_NAME = "sagg_sim_bridge"



def to_time(ns: int) -> Time:
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


class BridgeNode(Node):
    def __init__(self):
        super().__init__(NODE_NAME)
        p = self.params = declare_schema(self, SCHEMA)
        # (a relative arm.model is relative to the parameter file, as in a config)
        self.spec = arm_spec_from_params(p, params_dir())  # ConfigError names the bad arm.* parameter
        self.sim = make_arm_sim(self.spec, seed=substream_seed(p["seed"], "sim"))
        self.n = self.sim.n_joints
        self.lockstep = p["timing"] == "lockstep"
        self.dynamic = self.spec.mode == "dynamic"
        self.dt_ns = int(round(self.spec.timestep * 1e9))
        self.exit_code = 0

        self.cmd_topic = f"/{p['controller'].strip('/')}/commands"
        self.guard = InputGuard(self.get_logger().error)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable(10))
        self.create_timer(1.0, self.publish_diagnostics)
        self.js_pub = self.create_publisher(JointState, "/joint_states", reliable(HW_DEPTH))
        self.tip_pub = self.create_publisher(PointStamped, p["task_topic"], reliable(HW_DEPTH))
        self.task_topic = p["task_topic"]
        self.published = {"/joint_states": 0, self.task_topic: 0}  # logged at shutdown (run_node)
        # hot path: raw CDR in and out (sagg_common.cdr), no message objects
        self.create_subscription(Float64MultiArray, self.cmd_topic, self.on_command, reliable(HW_DEPTH), raw=True)
        self.js_encoder = JointStateEncoder(list(self.sim.joint_names), p["frame_id"])
        self.tip_encoder = PointStampedEncoder(p["frame_id"])
        self.zeros = np.zeros(self.n)
        self.commands = 0
        self.scene = getattr(self.sim, "scene", None)  # a model arm's scene checker (None: no scene)
        self.last_q = self.sim.observe()[0]  # real-time dynamic mode: the posture at the last command
        self.virtual_ns = 0   # lockstep + kinematic: simulation clock (no physics time)

        if self.lockstep:
            self.create_timer(p["idle_publish_period"], self.publish_state)
        else:
            self.clock_pub = self.create_publisher(Clock, "/clock", reliable(10))
            self.t_start = time.monotonic()
            self.steps_done = 0
            period = self.spec.timestep if self.dynamic else 1.0 / p["publish_rate"]
            self.create_timer(min(period, 1.0 / p["publish_rate"]), self.on_physics)
            self.create_timer(1.0 / p["publish_rate"], self.publish_state)
        self.publish_state()
        self.get_logger().info(
            f"{self.n}-DOF {self.spec.mode} arm, {p['timing']}: commands on {self.cmd_topic}, "
            f"tip on {p['task_topic']}")

    # ------------------------------------------------------------------ time
    def sim_ns(self) -> int:
        if self.lockstep:
            return int(round(self.sim.data.time * 1e9)) if self.dynamic else self.virtual_ns
        if self.dynamic:
            return int(round(self.sim.data.time * 1e9))
        return int((time.monotonic() - self.t_start) * 1e9)

    # ------------------------------------------------------------------ commands
    def on_command(self, raw: bytes) -> None:
        try:
            target = decode_f64_array(raw)
        except (ValueError, IndexError, struct.error, UnicodeDecodeError) as exc:
            self.guard.reject("command.undecodable", f"{self.cmd_topic}: undecodable message ({exc})")
            return
        if len(target) != self.n:
            self.guard.reject("command.length", f"{self.cmd_topic}: got {len(target)} values; allowed: "
                                                f"{self.n} (one per joint: {', '.join(self.sim.joint_names)})")
            return
        if not all_finite(target):
            self.guard.reject("command.non_finite", f"{self.cmd_topic}: NaN/inf in {target.tolist()}; "
                                                    "allowed: finite values")
            return
        self.commands += 1
        if self.lockstep:
            self.sim.command(target)
            if not self.dynamic:
                self.virtual_ns += self.dt_ns
            self.publish_state()
        elif self.dynamic:
            self._set_realtime_target(target)
        else:
            self.sim.command(target)

    def _set_realtime_target(self, target: np.ndarray) -> None:
        """Real-time dynamic mode: the motor-noise model of ``ArmSim.command`` (realised
        Δ = Δ·(1 + noise·N(0,1)), clipped to the limits), but the actuators then move the arm over
        the following physics steps instead of settling at once."""
        sim = self.sim
        q = sim.observe()[0]
        if self.scene is not None:  # the arm moved since the last command: that motion met the scene?
            sim.note_motion(self.last_q, q)
            self.last_q = q
        delta = target - q
        if sim.spec.motor_noise > 0.0:
            delta *= 1.0 + sim.spec.motor_noise * sim.rng.standard_normal(self.n)
        sim.set_targets(np.clip(q + delta, sim.lower, sim.upper))

    # ------------------------------------------------------------------ real time
    def on_physics(self) -> None:
        ns = int((time.monotonic() - self.t_start) * 1e9)
        if self.dynamic:
            due = ns // self.dt_ns - self.steps_done
            if due > 0:
                due = min(due, 1000)  # if we fell far behind, do not try to catch up at once
                mujoco.mj_step(self.sim.model, self.sim.data, nstep=int(due))
                mujoco.mj_kinematics(self.sim.model, self.sim.data)
                self.steps_done += int(due)
                if ns // self.dt_ns - self.steps_done > 1000:
                    self.steps_done = ns // self.dt_ns
        self.clock_pub.publish(Clock(clock=to_time(self.sim_ns())))

    # ------------------------------------------------------------------ output
    def publish_diagnostics(self) -> None:
        state = {"commands": str(self.commands), "timing": self.params["timing"]}
        if self.scene is not None:
            state["contacts"] = str(self.sim.contacts)
            state.update({f"contacts.{cause}": str(n) for cause, n in self.sim.contacts_by_cause.items()})
        self.diag_pub.publish(diagnostic_array(to_time(time.time_ns()), NODE_NAME, self.guard, state))

    def publish_state(self) -> None:
        ns = self.sim_ns()
        alpha, tip = self.sim.observe()
        self.js_pub.publish(self.js_encoder.encode(ns, alpha,
                                                   self.sim.joint_velocities() if self.dynamic else self.zeros))
        # the task point's coordinates in x, y (and z), in the order of the task axes
        self.tip_pub.publish(self.tip_encoder.encode(ns, *map(float, tip)))
        if self.commands:
            # counted from the first command on (what a recorder that the learner waited for must
            # hold; the idle re-publications before it may precede any recorder's match)
            self.published["/joint_states"] += 1
            self.published[self.task_topic] += 1


def main(args: list[str] | None = None) -> int:
    sys.exit(run_node(NODE_NAME, BridgeNode, args, executor="events"))


if __name__ == "__main__":
    main()
