"""The bridge nodes' parameter schemas (ROS-free, so that ``sagg experiment`` and ``sagg params`` read
them without rclpy): each node's schema is its simulator's parameters (:data:`.params.SCHEMA` for the
arm, :data:`.synergy_params.SCHEMA` for the quadruped and the fishing rod) and the node's own
(timing, topics, frames)."""
from __future__ import annotations

from sagg_common.params import Param, Schema

from .params import SCHEMA as ARM_SCHEMA
from .synergy_params import SCHEMA as SYNERGY_SIM_SCHEMA

BRIDGE_NODE_SCHEMA: Schema = (
    Param("timing", "str", "lockstep",
          "'lockstep': physics advances only on a command, state published once settled (deterministic); "
          "'realtime': physics at real-time rate, state published at publish_rate Hz, /clock.",
          choices=("lockstep", "realtime")),
    Param("publish_rate", "float", 100.0, "Real-time mode: joint_states + tip publication rate (Hz).",
          low=0.0, high=10_000.0, low_open=True),
    Param("controller", "str", "forward_position_controller",
          "Position controller name: commands are read from /<controller>/commands."),
    Param("task_topic", "str", "/tip_position", "Topic of the tip position (geometry_msgs/PointStamped)."),
    Param("frame_id", "str", "world", "frame_id of the published tip position and joint states."),
    Param("idle_publish_period", "float", 0.5,
          "Lockstep mode: re-publish the current state (same stamp) this often (s).",
          low=0.01, high=3600.0),
)
# the node `mujoco_bridge` (the arm)
BRIDGE_SCHEMA: Schema = ARM_SCHEMA + BRIDGE_NODE_SCHEMA


SYNERGY_BRIDGE_NODE_SCHEMA: Schema = (
    Param("controller", "str", "joint_trajectory_controller",
          "Trajectory controller name: trajectories are read from /<controller>/joint_trajectory."),
    Param("task_topic", "str", "/body_pose",
          "Outcome topic: PoseStamped (quadruped body: u, v and yaw φ; the quaternion's sign keeps "
          "φ in (-2π, 2π]) or PointStamped (fishing float x, y; NaN = no water contact)."),
    Param("frame_id", "str", "start",
          "frame_id of the published outcomes (the robot's start frame / the water plane)."),
)
# the node `synergy_bridge` (quadruped, fishing rod)
SYNERGY_BRIDGE_SCHEMA: Schema = SYNERGY_SIM_SCHEMA + SYNERGY_BRIDGE_NODE_SCHEMA
