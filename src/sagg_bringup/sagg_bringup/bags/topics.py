"""The topics a graph run records: the /sagg topics of every set-up, and each set-up's hardware
topics (the names follow the learner's ``controller`` and ``task_topic``)."""
from __future__ import annotations

from sagg_low_level.schema import command_topic

from .recorder import TopicSpec

# the hardware contract's command types (docs/your-robot.md): position commands on /<controller>/commands,
# trajectories on /<controller>/joint_trajectory; whatever subscribes to them moves the robot
COMMAND_TYPES = frozenset({"std_msgs/msg/Float64MultiArray", "trajectory_msgs/msg/JointTrajectory"})
# the learner's and the goal generator's streams: they stop when the nodes stop (what a stopping
# recorder waits for), unlike the periodic topics (status, regions, joint states at rest, ...)
STREAM_TOPICS = ("/sagg/sample", "/sagg/competence", "/sagg/goal")
# sagg's simulator node (every set-up's bridge): the only node that sagg's commands may reach
# without moving a robot
SIM_BRIDGE_NODE = "sagg_sim_bridge"


def command_topics(types: dict[str, str]) -> list[str]:
    """The topics of ``types`` (topic -> ROS type) that carry commands (:data:`COMMAND_TYPES`)."""
    return sorted(t for t, ty in types.items() if ty in COMMAND_TYPES)


def robot_endpoints(node, topics: list[TopicSpec], ours: set[str]) -> dict[str, tuple[str, list]]:
    """Topic -> (how, endpoints) on the hardware topics of ``topics``: the endpoints
    (``TopicEndpointInfo``) that show a node not in ``ours`` to be a robot's driver or sensor, a
    subscriber of a command topic (:data:`COMMAND_TYPES`: it would move its robot; how =
    'subscribed') or a publisher of the others (joint states, a tracker's task point; how =
    'published'). An endpoint whose node discovery has not named yet counts too."""
    out = {}
    for t in topics:
        if t.name.startswith("/sagg/") or t.name == "/clock":
            continue
        command = t.msgtype in COMMAND_TYPES
        infos = node.get_subscriptions_info_by_topic(t.name) if command else node.get_publishers_info_by_topic(t.name)
        found = [i for i in infos if i.node_name not in ours]
        if found:
            out[t.name] = ("subscribed" if command else "published", found)
    return out


def sagg_topics() -> list[TopicSpec]:
    """The /sagg topics every graph run records (the hardware topics depend on the set-up)."""
    return [
        TopicSpec("/sagg/goal", "sagg_msgs/msg/Goal", publisher="sagg_goal_generator"),
        TopicSpec("/sagg/competence", "sagg_msgs/msg/CompetenceReport", publisher="sagg_learner"),
        TopicSpec("/sagg/regions", "sagg_msgs/msg/RegionTree", depth=1000, transient_local=True,
                  publisher="sagg_goal_generator"),
        TopicSpec("/sagg/sample", "sagg_msgs/msg/Sample", publisher="sagg_learner"),
        TopicSpec("/sagg/status", "sagg_msgs/msg/LearnerStatus", depth=100, publisher="sagg_learner"),
        TopicSpec("/sagg/evaluation", "sagg_msgs/msg/Evaluation", depth=100),
        TopicSpec("/sagg/markers", "visualization_msgs/msg/MarkerArray", depth=1, transient_local=True),
    ]


def graph_topics(learner_params: dict, timing: str = "lockstep") -> list[TopicSpec]:
    """The arm's topics (the position contract: joint states, position commands, the tip), and
    /clock in real time. With ``task_source: model`` the tip is recorded when something publishes
    it (the simulated bridge does) but is no part of the contract (:func:`awaited_topics`)."""
    cmd_topic, cmd_type = command_topic(learner_params)
    task_topic = learner_params.get("task_topic", "/tip_position")
    if not task_topic.startswith("/"):
        task_topic = "/" + task_topic
    return sagg_topics() + [
        TopicSpec("/joint_states", "sensor_msgs/msg/JointState"),
        TopicSpec(cmd_topic, cmd_type),
        TopicSpec(task_topic, "geometry_msgs/msg/PointStamped",
                  optional=learner_params.get("task_source") == "model"),
    ] + ([TopicSpec("/clock", "rosgraph_msgs/msg/Clock", depth=100)] if timing == "realtime" else [])


def trajectory_topics(lp: dict) -> list[TopicSpec]:
    """The synergy set-ups' topics: trajectories on ``/<controller>/joint_trajectory`` and the outcome
    (PoseStamped for a 3-D task space (u, v, φ), else PointStamped) on ``task_topic``."""
    task = lp["task_topic"] if lp["task_topic"].startswith("/") else "/" + lp["task_topic"]
    out_type = "geometry_msgs/msg/PoseStamped" if len(lp["task_space.lower"]) == 3 else "geometry_msgs/msg/PointStamped"
    return sagg_topics() + [
        TopicSpec(f"/{lp['controller'].strip('/')}/joint_trajectory", "trajectory_msgs/msg/JointTrajectory"),
        TopicSpec(task, out_type),
    ]


def awaited_topics(topics: list[TopicSpec]) -> tuple[str, ...]:
    """The topics a recorder waits for before the learner may start: the hardware topics of the
    contract (not /clock, not an optional one) and /sagg/competence (the learner's first
    command and its answer must not be published before the recorder can take them)."""
    hw = tuple(t.name for t in topics if not t.name.startswith("/sagg/") and t.name != "/clock" and not t.optional)
    return hw + ("/sagg/competence",)


def watched_topics(learner_params: dict) -> list[TopicSpec]:
    """Every topic a graph's nodes or recorders read (the recorded ones and the recorders'
    acknowledgements): where a stray publisher may appear (an idle one changes nothing)."""
    return graph_topics(learner_params) + [TopicSpec("/sagg/recorded", "std_msgs/msg/UInt64")]
