"""The learner nodes' parameter schemas (ROS-free, so that ``sagg experiment`` and ``sagg params``
read them without rclpy): each node's schema is its core's parameters (:data:`.learner.SCHEMA`,
:data:`.fixed_context.SCHEMA` + :data:`.fixed_context.SYNERGY_SCHEMA`) and the node's own (hardware
contract topics, waits, plausibility envelope)."""
from __future__ import annotations

import math

from sagg_common.joint_intake import JointStateIntake
from sagg_common.params import Param, Schema
from sagg_common.scene_params import SCENE_PARAMS

from .fixed_context import SCHEMA as FIXED_CORE_SCHEMA, SYNERGY_SCHEMA
from .learner import CONTEXT, SCHEMA as LEARNER_CORE_SCHEMA

HALF_PI = math.pi / 2
# Defaults = the default simulated arm (sagg_sim_bridge ArmSpec(): 8 DOF, limits ±π/2, rest bent by
# π/3 with the tip on +x); test_nodes_params checks they agree. A real arm sets its own.
DEFAULT_JOINTS = [f"joint_{i}" for i in range(8)]
DEFAULT_REST = [-0.5235987755982987] + [0.1495996501709425] * 7

LEARNER_NODE_SCHEMA: Schema = (
    Param("joints", "str_list", DEFAULT_JOINTS,
          "Joint names, in the order of the controller's commands; joint_states are matched by name."),
    Param("joint_limits.lower", "float_list", [-HALF_PI] * 8, "Lower joint limits (rad), one per joint."),
    Param("joint_limits.upper", "float_list", [HALF_PI] * 8, "Upper joint limits (rad), one per joint."),
    Param("rest_posture", "float_list", DEFAULT_REST, "Rest posture α_rest (rad), one per joint."),
    Param("controller", "str", "forward_position_controller",
          "Position controller name: commands go to /<controller>/commands."),
    Param("task_topic", "str", "/tip_position",
          "geometry_msgs/PointStamped topic of the effector position in Y (the paper's camera)."),
    Param("task_source", "str", "topic",
          "Where the task point comes from: 'topic' = task_topic (a tracker, the paper's camera, or the "
          "MuJoCo bridge); 'model' = computed from every accepted /joint_states with the robot's model "
          "(task_model.*: MuJoCo forward kinematics of the measured posture, the other model joints at "
          "rest), for a driver that publishes only joint states. `sagg run` / the launch file fill "
          "task_model.* from the config's simulated arm (arm.model) when they are not given.",
          choices=("topic", "model")),
    Param("task_model.file", "str", "",
          "task_source 'model': the robot's MJCF (.xml) or URDF (.urdf) file (relative: to the parameter "
          "file's directory); its joints named as in 'joints'."),
    Param("task_model.effector", "str", "",
          "task_source 'model': the body / link / site whose world position is the effector (tool0)."),
    Param("task_model.task_axes", "str", "xyz",
          "task_source 'model': the world coordinates forming the task point ('xyz', 'xy', 'xz', 'yz'), "
          "one per task_space dimension.", choices=("xyz", "xy", "xz", "yz")),
    Param("task_model.package_paths", "str_list", ["."],
          "task_source 'model': directories holding the packages of the model's package:// files (relative: "
          "to the parameter file's directory), before AMENT_PREFIX_PATH's share/. Meshes not found are not "
          "needed for kinematics (dropped, said once)."),
    Param("settle_velocity", "float", 0.05,
          "An observation counts as settled when every |joint velocity| is below this (rad/s). "
          "Joint states without velocities count as settled.", low=0.0, high=1e6, low_open=True),
    Param("settle_timeout", "float", 2.0,
          "Seconds after a command after which the latest fresh observation is taken even if not "
          "settled.", low=0.0, high=3600.0, low_open=True),
    Param("observation_delay", "float", 0.0,
          "An observation answers a command only if its stamp is later than the newest one received "
          "before the command by more than this (s). 0 for a lockstep bridge; about two publish "
          "periods for real-time drivers, so that a state sampled before the command arrived is "
          "not taken for the settled result.", low=0.0, high=3600.0),
    # how a move reaches the arm (motion.py; docs/safety.md)
    Param("command_interface", "str", "position",
          "How a move is sent: 'position' = setpoints (std_msgs/Float64MultiArray on "
          "/<controller>/commands, a forward position controller) streamed at command_rate along the "
          "straight joint-space line within the velocity limits; 'trajectory' = one "
          "trajectory_msgs/JointTrajectory on /<controller>/joint_trajectory (a joint_trajectory_controller) "
          "whose time_from_start comes from the same limits. The simulated bridge, when it alone listens, "
          "gets each move as one setpoint (it simulates the servo itself).", choices=("position", "trajectory")),
    Param("command_rate", "float", 50.0,
          "Setpoints per second of a streamed move (command_interface 'position'). Our choice: 50 Hz, "
          "finer than a micro-action's motion and well under a ros2_control loop's 100-1000 Hz.",
          low=0.0, high=10000.0, low_open=True),
    Param("joint_velocity_limits", "float_list", [],
          "Velocity limit of each joint (rad/s, m/s for a slide joint), in the order of 'joints'. Empty = "
          "from the model: the URDF's <limit velocity> (an MJCF has none: give them here). Without any, "
          "a move is one setpoint (said at start): give them for a real arm.", empty_ok=True),
    Param("velocity_scale", "float", 0.5,
          "The fraction of the velocity limits a move may use. Our choice: 0.5, the usual first-run "
          "speed of an arm beside people and furniture; lower it for a first run.",
          low=0.0, high=1.0, low_open=True),
    Param("settle_tolerance", "float", 0.01,
          "rad: a streamed move is settled when every joint is within this of the last setpoint (and, when "
          "the driver publishes velocities, every one is below settle_velocity: a stopped arm is slow too); "
          "also the motion that counts as following (follow_timeout).", low=0.0, high=10.0, low_open=True),
    Param("follow_timeout", "float", 1.0,
          "Seconds without progress toward the setpoints (no joint moved by settle_tolerance and the "
          "arm farther than settle_tolerance from its setpoint) after which the arm is taken as stopped "
          "(protective stop, e-stop): the learner stops commanding and holds, named ('follow').",
          low=0.0, high=3600.0, low_open=True),
    Param("follow_retry", "float", 5.0,
          "While the arm does not follow: every this many seconds one probe setpoint (probe_step) is "
          "sent; when the arm follows it, the move goes on from the measured posture and learning "
          "resumes by itself. Our choice: above the 3 s many safety controllers ignore commands after "
          "a protective stop.", low=0.0, high=3600.0, low_open=True),
    Param("probe_step", "float", 0.02,
          "rad: the largest joint motion of a probe setpoint (follow_retry), toward the stopped move's "
          "target.", low=0.0, high=1.0, low_open=True),
    Param("max_micro_actions", "int", 0,
          "Stop acting after this many micro-actions (0 = unlimited).", low=0),
    Param("frozen_memory", "str", "",
          "A learned model to use without learning: a sample memory file (.npz, as `sagg relearn` "
          "writes DIR/memory.npz), a run directory with its learner checkpoint, or a model directory of "
          "`sagg serve` (its rest point too, from model.json). The learner then never learns (no goal "
          "requests, no samples) and serves /sagg/reach and /sagg/compute_ik (`sagg reach`, `sagg serve "
          "--driver`). Empty = learn."),
    Param("publish_batch", "int", 64,
          "Reports and samples are queued and published in bursts: when this many are queued, "
          "before every goal request (the generator needs the reports so far), at a stop, and at "
          "least every publish_period. Bursts cost the receivers one wake-up instead of one per "
          "message; 1 = publish after every micro-action. Our choice (transport only: the run is "
          "the same).", low=1, high=1_000_000),
    Param("publish_period", "float", 0.1,
          "Longest time (s) a queued report or sample waits before it is published (live views).",
          low=0.0, high=3600.0, low_open=True),
    Param("min_sample_subscribers", "int", 0,
          "Start only once /sagg/sample has at least this many matched subscribers (e.g. 1 when a "
          "recorder must see every sample). 0 = do not wait.", low=0, high=1000),
    # checkpoint / resume (sagg_low_level.checkpoint)
    Param("checkpoint_dir", "str", "",
          "Directory of the learner's checkpoints and write-ahead journal (learner_*). Empty = off. "
          "With resume true the learner resumes from the checkpoint in it (memory, counters, random "
          "state; the interrupted reaching attempt is abandoned). `sagg run` uses DIR/checkpoint and "
          "gives it on the command line (never in DIR/params.yaml: a configuration, not a run)."),
    Param("resume", "bool", False,
          "Continue the run whose checkpoint is in checkpoint_dir. false: a checkpoint_dir that holds "
          "a checkpoint is refused (exit 2, one line; nothing written), so parameters reused from "
          "another run never continue or overwrite it. `sagg run --resume DIR` sets true."),
    Param("checkpoint_every", "int", 10000,
          "Checkpoint every this many micro-actions (and at shutdown). Every sample and report is "
          "journaled before it is published, so nothing is lost between checkpoints; this only "
          "bounds the journal's length. Our choice.", low=1, high=1_000_000_000),
    Param("journal_fsync", "bool", False,
          "fsync the journal after every record: survives a power cut, not only a killed process "
          "(one disk flush per micro-action)."),
    Param("republish_from", "int", -1,
          "At a resume from checkpoint_dir: republish the stored samples from this index on too (from "
          "the memory, before the journaled ones of the last two checkpoint intervals), for a recorder "
          "whose bag lost more than those (killed with the graph: its unwritten tail). `sagg run "
          "--resume` sets it to the samples its bags hold. -1 = the journaled samples only.",
          low=-1, high=1_000_000_000),
    Param("joint_state_timeout", "float", 2.0,
          "Safety: pause (and say so in /sagg/status and /diagnostics) when no valid joint_states or "
          "task point arrived for this long, or when /joint_states has no publisher; resume when they "
          "return. Above the driver's publish period (the lockstep bridge re-publishes every 0.5 s "
          "when idle).", low=0.0, high=3600.0, low_open=True),
    Param("goal_retry", "float", 5.0,
          "Seconds without an answer after which a goal request is sent again (e.g. the goal "
          "generator was restarted and lost it). The generator answers a repeated request "
          "(same after_report) with the same goal, so a retry never changes the run. Our choice.",
          low=0.0, high=3600.0, low_open=True),
    Param("rest_return", "str", "stepped",
          "How the learner returns to rest_posture (after every reset_every attempts): 'stepped' = a "
          "sequence of position commands, each at most max_joint_step from the newest measured posture "
          "(not micro-actions: nothing is stored; counted on /diagnostics as rest-return commands), the safe "
          "default for a real arm; 'direct' = one command to the rest posture, as the paper's "
          "simulation does: only for the simulated lockstep bridge (`sagg run` sets it there, so the "
          "graph equals the in-process run bit for bit). 'direct' is refused with --driver external and "
          "ignored (stepped instead, logged) whenever a node other than sagg_sim_bridge subscribes to "
          "the commands.", choices=("stepped", "direct")),
    Param("recorder_max_lag", "int", 500,
          "Backpressure for a recorder that acknowledges on /sagg/recorded (std_msgs/UInt64: how many "
          "samples, from index 0, it has recorded; `sagg run` does): before a command the learner waits "
          "while more than this many published samples are unacknowledged, so a recorder that falls "
          "behind on a loaded machine never lets its queues overflow (the bag holds every message). "
          "Each recorder is told apart by its publisher's sequence numbers; the learner waits for the "
          "slowest one that acknowledged, and moved its count, within recorder_timeout. 0 = never "
          "wait. Our choice: 500 micro-actions are ~2,000 hardware messages, far below the "
          "publishers' and the recorder's history depths (10,000 and more).", low=0, high=1_000_000_000),
    Param("recorder_timeout", "float", 10.0,
          "A recorder that sent no acknowledgement on /sagg/recorded, or did not move its count, for "
          "this long (s) is no longer waited for (logged): a recorder that stopped or died never "
          "stalls learning. Our choice: recorders acknowledge at least every 0.5 s.",
          low=0.0, high=86400.0, low_open=True),
    # the plausibility envelope of the measurements (docs/safety.md; sagg_common.envelope)
    Param("plausibility.joint_tolerance", "float", 0.1,
          "A joint state is rejected when a position lies outside the joint limits by more than this "
          "(rad): encoders may read slightly past a limit, never far. Our choice.", low=0.0, high=100.0),
    Param("plausibility.task_margin", "float", 1.0,
          "A task point is rejected when it lies outside Y enlarged on every side by this fraction of "
          "Y's extent (1 = a box 3x Y per axis: the paper's camera field is ~3x the reachable area). "
          "Our choice.", low=0.0, high=1e6),
    Param("plausibility.max_joint_velocity", "float", 1000.0,
          "A joint state is rejected when a |velocity| exceeds this (rad/s): a sanity bound, far above "
          "any motor (the simulated arm's fastest return to rest stays below ~150 rad/s).",
          low=0.0, high=1e12, low_open=True),
    Param("plausibility.hold_after", "int", 10,
          "After this many rejected joint states (or task points) in a row the learner holds (no "
          "command goes out) naming the last rejection; it resumes at the next valid one.",
          low=1, high=1_000_000),
    Param("plausibility.future_tolerance", "float", 30.0,
          "A stamp further ahead of the newest accepted one than the receive time elapsed since it "
          "arrived plus this (s) is rejected as 'in the future' (the newest stamp stays). Above the "
          "longest settle in simulation time of a lockstep bridge (1000 steps x 0.01 s).",
          low=0.0, high=1e9, low_open=True),
    Param("plausibility.source_grace", "float", 2.0,
          "One source per input (docs/safety.md): the messages of /joint_states that carry the learner's "
          "joints, and those of the task topic, must come from one publisher (told apart by the "
          "publishers' sequence numbers; sagg_common.sources). While a second source sends them, every "
          "such message is rejected and the learner holds, naming the topic's publishers; the hold "
          "ends this many seconds (s) after the second source's last message. Messages without any "
          "of the learner's joints (a gripper driver's) are ignored, and a publisher that sends "
          "nothing changes nothing. Our choice: above the publish period of real-time drivers, short "
          "enough for a restarted driver to be taken again quickly.", low=0.0, high=3600.0,
          low_open=True),
    Param("plausibility.check_sources", "bool", True,
          "Apply the one-source rule above. False only to test the other checks with a second "
          "publisher (sagg bench hostile's content phase); never on a robot."),
    Param("plausibility.single_publisher", "bool", True,
          "Deprecated: ignored. It held learning while a second publisher merely existed "
          "on a watched topic; the learner now judges messages (plausibility.source_grace).",
          deprecated="ignored: a second publisher is judged by its messages "
                     "(plausibility.source_grace), not by its existence"),
    Param("plausibility.resync_after", "int", 5,
          "This many messages in a row older than the newest accepted stamp are a clock jump back "
          "(driver or sim-time restart): logged, and the stream re-synchronised on them.",
          low=1, high=1_000_000),
)
def command_topic(p: dict) -> tuple[str, str]:
    """The learner's command topic and its type for its ``command_interface``: position setpoints on
    ``/<controller>/commands`` (std_msgs/Float64MultiArray) or trajectories on
    ``/<controller>/joint_trajectory`` (trajectory_msgs/JointTrajectory)."""
    controller = p.get("controller", "forward_position_controller").strip("/")
    if p.get("command_interface", "position") == "trajectory":
        return f"/{controller}/joint_trajectory", "trajectory_msgs/msg/JointTrajectory"
    return f"/{controller}/commands", "std_msgs/msg/Float64MultiArray"


# the node `learner` (evolving context); the scene (config's /** section) is checked before every move
LEARNER_SCHEMA: Schema = LEARNER_CORE_SCHEMA + LEARNER_NODE_SCHEMA + SCENE_PARAMS
# what the joint-state intake reads (joint_intake), with the learner's defaults for a reader whose
# parameters lack them (the fixed-context learner's position link)
_INTAKE_DEFAULTS = {q.name: q.default for q in LEARNER_NODE_SCHEMA if q.name.startswith("plausibility.")}


def joint_intake(p: dict, joints, lower, upper) -> JointStateIntake:
    """The one /joint_states reader for the joints ``joints`` with limits ``lower`` / ``upper``,
    its rules from the learner parameters ``p`` (``settle_velocity`` and the joint-state part of
    the plausibility envelope above; a key ``p`` lacks: the learner's default)."""
    def get(key):
        return p[key] if key in p else _INTAKE_DEFAULTS[key]
    return JointStateIntake(joints, lower, upper, tolerance=get("plausibility.joint_tolerance"),
                            max_velocity=get("plausibility.max_joint_velocity"),
                            settle_velocity=p["settle_velocity"], source_grace=get("plausibility.source_grace"),
                            check_sources=get("plausibility.check_sources"),
                            future_tolerance=get("plausibility.future_tolerance"),
                            resync_after=get("plausibility.resync_after"))


FIXED_NODE_SCHEMA: Schema = (
    Param("controller", "str", "joint_trajectory_controller",
          "Trajectory controller name: synergies go to /<controller>/joint_trajectory "
          "(trajectory_msgs/JointTrajectory, the joint_trajectory_controller contract)."),
    Param("task_topic", "str", "/body_pose",
          "Outcome topic: geometry_msgs/PoseStamped (3-D task space: u, v and the yaw φ) or "
          "PointStamped (2-D: x, y; NaN coordinates = no outcome, e.g. the float missed the water). "
          "Its header.stamp echoes the trajectory's header.stamp."),
    Param("response_timeout", "float", 60.0,
          "Seconds to wait for the outcome of one trajectory before the node gives up with an error.",
          low=0.0, high=86400.0, low_open=True),
    Param("max_experiments", "int", 0,
          "Stop after this many stored experiments (0 = unlimited).", low=0),
    Param("min_sample_subscribers", "int", 0,
          "Start only once /sagg/sample has at least this many matched subscribers. 0 = do not wait.",
          low=0, high=1000),
    Param("settle_timeout", "float", 2.0,
          "synergy.kind 'posture': seconds after a command after which the latest fresh joint state is "
          "taken even if not settled.", low=0.0, high=3600.0, low_open=True),
    Param("settle_velocity", "float", 0.05,
          "synergy.kind 'posture': a joint state answers a position command once every |velocity| is "
          "below this (rad/s); joint states without velocities count as settled.",
          low=0.0, high=1e6, low_open=True),
    CONTEXT,
)
# the node `fixed_learner` (fixed context: quadruped, fishing rod, the arm with context: fixed)
FIXED_LEARNER_SCHEMA: Schema = FIXED_CORE_SCHEMA + SYNERGY_SCHEMA + FIXED_NODE_SCHEMA

# the node `model_server` (sagg_low_level.model_server): a finished run's model, learning off
MODEL_SERVER_SCHEMA: Schema = (
    Param("run", "str", "",
          "The learned model: a run directory (its params.yaml and learner checkpoint, checkpoint/), or the "
          "model directory `sagg serve` writes (params.yaml, memory.npz, model.json). Required."),
    Param("rest_point", "float_list", [],
          "The effector's point at the rest posture (task units), /sagg/compute_ik's default start point, "
          "when the run's files hold none (a learner measures it at its returns to rest and keeps it beside "
          "its checkpoint, in model.json). Empty: the files' (none there: a request must give start and "
          "start_point).", empty_ok=True),
)
