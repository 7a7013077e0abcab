"""Parameters of the synergy bridge (quadruped / fishing rod) and the simulator they describe. ROS-free."""
from __future__ import annotations

from sagg_common.params import Param, Schema

from . import fishing, quadruped

SETUPS = ("quadruped", "fishing")

SCHEMA: Schema = (
    Param("seed", "int", 0, "Run seed (the synergy simulators are deterministic: no noise stream).", low=0),
    Param("setup", "str", "quadruped",
          "Which synergy robot: 'quadruped' (Sec. 4) or 'fishing' (Sec. 5). Set it under '/**' so that "
          "`sagg run`/`sagg experiment` choose the fixed-context learner and synergy bridge.",
          choices=SETUPS),
) + quadruped.SCHEMA + fishing.SCHEMA

# Parameters of the synergy bridge node (ROS-free here so that `sagg experiment` accepts them too).
NODE_SCHEMA: Schema = (
    Param("controller", "str", "joint_trajectory_controller",
          "Trajectory controller name: trajectories are read from /<controller>/joint_trajectory."),
    Param("task_topic", "str", "/body_pose",
          "Outcome topic: PoseStamped (quadruped body: u, v and yaw φ; the quaternion's sign keeps "
          "φ in (-2π, 2π]) or PointStamped (fishing float x, y; NaN = no water contact)."),
    Param("frame_id", "str", "start",
          "frame_id of the published outcomes (the robot's start frame / the water plane)."),
)


def make_sim(params: dict):
    """The simulator of resolved bridge ``params`` (QuadrupedSim or FishingSim)."""
    if params["setup"] == "quadruped":
        return quadruped.QuadrupedSim(quadruped.spec_from_params(params))
    return fishing.FishingSim(fishing.spec_from_params(params))
