"""The three nodes as processes: the lockstep graph reproduces the in-process run bit for bit,
bad parameters exit with code 2, joint states are matched by name.

Processes are the venv's console scripts, started with subprocess on a private ROS_DOMAIN_ID with
localhost-only discovery, stopped with SIGINT then SIGKILL. The test process itself joins the graph
(to collect samples/goals, or to act as a fake driver).
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

import rclpy
import rclpy.executors
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from sagg_bringup.inprocess.experiment import InProcessRun
from sagg_bringup.graph.setups import load_experiment_config
from sagg_bringup.graph.processes import pick_domain_id
from sagg_common.params import node_params, read_config
from sagg_common.rng import substream_seed
from sagg_low_level.memory import SampleMemory
from sagg_msgs.msg import CompetenceReport, Goal, LearnerStatus, RegionTree, Sample
from sagg_sim_bridge.arm import ArmSim
from sagg_sim_bridge.params import SCHEMA as BRIDGE_SCHEMA, arm_spec_from_params
from installed import executable

ROOT = Path(__file__).resolve().parents[1]
STARTUP_TIMEOUT = 90.0   # generous: discovery + imports on a loaded 2-core machine
RUN_TIMEOUT = 180.0


def qos(depth: int) -> QoSProfile:
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE)


# ---------------------------------------------------------------------------------- helpers
@pytest.fixture
def ros_env(monkeypatch):
    """A private ROS domain for this test (also for the test process's own rclpy context)."""
    domain = pick_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env = dict(os.environ)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    procs: list[subprocess.Popen] = []
    yield {"env": env, "ctx": ctx, "procs": procs, "domain": domain}
    for p in procs:
        stop(p)
    ctx.try_shutdown()


def start(ros_env, script: str, params: Path, tmp_path: Path, args: tuple = ()) -> subprocess.Popen:
    """The console script ``script`` on ``params`` (``args``: more ROS arguments, e.g. ``-p x:=1``)."""
    exe = Path(executable(script))
    assert exe.exists(), f"console script {exe} missing (run make setup)"
    log = open(tmp_path / f"{script}.log", "w")
    p = subprocess.Popen([str(exe), "--ros-args", "--params-file", str(params), *args], env=ros_env["env"],
                         stdout=log, stderr=subprocess.STDOUT)
    ros_env["procs"].append(p)
    return p


def stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(10)


def graph_params(base: Path, out: Path, arm: dict, learner: dict | None = None,
                 generator: dict | None = None, everyone: dict | None = None) -> Path:
    """A ROS parameter file for the graph: ``base`` + arm overrides, with the learner's joints,
    limits and rest posture filled from the arm spec (as ``sagg run`` does for MuJoCo configs)."""
    data = yaml.safe_load(base.read_text())
    data.setdefault("sagg_sim_bridge", {"ros__parameters": {}})["ros__parameters"].setdefault("arm", {}).update(arm)
    sections = read_config(base)
    sections["sagg_sim_bridge"].update({f"arm.{k}": v for k, v in arm.items()})
    spec = arm_spec_from_params(node_params(sections, "sagg_sim_bridge", BRIDGE_SCHEMA))
    lower, upper = spec.limits()
    lp = data.setdefault("sagg_learner", {"ros__parameters": {}})["ros__parameters"]
    lp.update({"joints": spec.joint_names(), "joint_limits": {"lower": lower.tolist(), "upper": upper.tolist()},
               "rest_posture": spec.rest_posture().tolist(),
               "rest_return": "direct"})  # (the lockstep simulator's one-command return to rest, as sagg run sets it)
    lp.update(learner or {})
    data.setdefault("sagg_goal_generator", {"ros__parameters": {}})["ros__parameters"].update(generator or {})
    data["/**"]["ros__parameters"].update(everyone or {})
    out.write_text(yaml.safe_dump(data))
    return out


class Collector:
    """Test-side node recording samples, goals, reports and the learner's status."""

    def __init__(self, ctx):
        self.node = Node("sagg_test_collector", context=ctx)
        self.samples: list[Sample] = []
        self.goals: list[Goal] = []
        self.reports: list[CompetenceReport] = []
        self.status: LearnerStatus | None = None
        self.regions: RegionTree | None = None
        n = self.node
        n.create_subscription(RegionTree, "/sagg/regions", self._on_regions,
                              QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                         durability=DurabilityPolicy.TRANSIENT_LOCAL))
        n.create_subscription(Sample, "/sagg/sample", self.samples.append, qos(10000))
        n.create_subscription(Goal, "/sagg/goal", self.goals.append, qos(10000))
        n.create_subscription(CompetenceReport, "/sagg/competence", self.reports.append, qos(10000))
        n.create_subscription(LearnerStatus, "/sagg/status", self._on_status, qos(10))
        self.executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
        self.executor.add_node(n)

    def _on_status(self, msg):
        self.status = msg

    def _on_regions(self, msg):
        self.regions = msg

    def stopped(self) -> bool:
        return self.status is not None and self.status.paused and "max_micro_actions" in self.status.pause_reason

    def spin_until(self, cond, timeout: float, procs=()) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            for p in procs:
                assert p.poll() is None, f"{p.args[0]} exited early with code {p.returncode}"
            self.executor.spin_once(timeout_sec=0.05)
        return cond()

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.05)


def memory_from_samples(samples: list[Sample], n: int, m: int) -> SampleMemory:
    samples = sorted(samples, key=lambda s: s.index)
    assert [s.index for s in samples] == list(range(len(samples))), "samples missing or duplicated"
    mem = SampleMemory(n, n, m)
    for s in samples:
        mem.add(np.array(s.alpha), np.array(s.delta_alpha), np.array(s.delta_y))
    return mem


def same_bits(a, b) -> bool:
    return np.asarray(a, dtype=np.float64).tobytes() == np.asarray(b, dtype=np.float64).tobytes()


def in_process(base: Path, overrides: dict, micro_actions: int):
    run = InProcessRun(load_experiment_config(base, overrides))
    reports = []
    forward = run.learner.on_report

    def record(r):
        reports.append(r)
        forward(r)

    run.learner.on_report = record
    run.step_until(micro_actions)
    return run, reports


def logs(tmp_path: Path) -> str:
    return "\n".join(f"--- {f.name}\n{f.read_text()[-3000:]}" for f in sorted(tmp_path.glob("*.log")))


# ---------------------------------------------------------------------------------- tests
@pytest.mark.parametrize("config,arm,steps", [
    # 7-DOF kinematic, a mostly reachable Y: ~26 goals of every mode, ~38 splits
    ("arm15_y50.yaml", {"dof": 7, "mode": "kinematic"}, 1000),
    # the default setup: 8-DOF MuJoCo physics with 20% motor noise
    ("arm8.yaml", {}, 300),
])
def test_lockstep_graph_equals_in_process_run(ros_env, tmp_path, config, arm, steps):
    """Same seeds -> the graph's samples (bit-exact), goals and reports equal InProcessRun's."""
    base = ROOT / "config" / config
    params = graph_params(base, tmp_path / "params.yaml", arm,
                          learner={"max_micro_actions": steps, "min_sample_subscribers": 1},
                          generator={"min_goal_subscribers": 1})
    col = Collector(ros_env["ctx"])
    procs = [start(ros_env, s, params, tmp_path) for s in ("mujoco_bridge", "goal_generator", "learner")]
    ok = col.spin_until(lambda: col.stopped() and len(col.samples) >= steps, STARTUP_TIMEOUT + RUN_TIMEOUT, procs)
    assert ok, f"graph did not finish: {len(col.samples)} samples\n{logs(tmp_path)}"
    run, reports = in_process(base, {f"arm.{k}": v for k, v in arm.items()}, steps)
    # Reports travel on their own topic and may still be in flight when the last sample is in; the
    # generator's tree counts the reports it has folded in. Wait for both to reach the in-process
    # count (a count the graph never reaches times out and fails the comparisons below), then a
    # little longer so that extra messages, if any, show up in the comparisons too.
    col.spin_until(lambda: len(col.reports) >= len(reports) and col.regions is not None
                   and col.regions.reports >= len(reports), 30.0)
    col.spin_for(0.5)
    assert run.learner.micro_actions == steps == len(col.samples)
    mem = memory_from_samples(col.samples, run.sim.n_joints, 2)
    assert len(run.generator.goals) >= 2 and len(run.generator.tree.splits) >= 1  # not a trivial run
    assert mem.digest() == run.learner.memory.digest()
    graph_goals = [(g.seq, g.mode, g.after_report, np.array(g.position).tobytes()) for g in col.goals]
    inproc_goals = [(g.seq, g.mode, g.after_report, g.position.tobytes()) for g in run.generator.goals]
    assert graph_goals == inproc_goals
    graph_reports = [(r.seq, r.kind, r.goal_seq, r.competence, r.micro_actions) for r in col.reports]
    inproc_reports = [(r.seq, r.kind, r.goal_seq, r.competence, r.micro_actions) for r in reports]
    assert graph_reports == inproc_reports
    assert col.status.micro_actions == steps and col.status.samples == steps
    # the generator's region tree (/sagg/regions, transient_local) is the in-process one
    tree = col.regions
    assert (tree.reports, tree.goals, tree.splits) == (len(reports), len(run.generator.goals),
                                                         len(run.generator.tree.splits))
    snap = run.generator.region_snapshot()
    assert [r.id for r in tree.regions] == [r["id"] for r in snap]
    for r, s in zip(tree.regions, snap):
        assert same_bits(r.lower, s["lower"]) and same_bits(r.upper, s["upper"]) and r.count == s["count"]
        assert same_bits([r.interest], [s["interest"]])


@pytest.mark.parametrize("script,section,name,value,allowed", [
    ("learner", "sagg_learner", "v", -1.0, "(0.0, "),
    ("goal_generator", "sagg_goal_generator", "strategy", "curious", "one of 'sagg-riac'"),
    ("mujoco_bridge", "sagg_sim_bridge", "timing", "sometimes", "one of 'lockstep', 'realtime'"),
    ("mujoco_bridge", "sagg_sim_bridge", "arm.dof", 0, "[1, 100]"),
    ("learner", "sagg_learner", "max_micro_actions", 1.5, "an integer"),
    ("learner", "sagg_learner", "settle_velocty", 0.1, "allowed: "),  # a typo in the node's section
])
def test_bad_parameter_exits_2_naming_it(ros_env, tmp_path, script, section, name, value, allowed):
    data = yaml.safe_load((ROOT / "config" / "arm15.yaml").read_text())
    node = data.setdefault(section, {"ros__parameters": {}})["ros__parameters"]
    node[name] = value
    params = tmp_path / "bad.yaml"
    params.write_text(yaml.safe_dump(data))
    out = subprocess.run([executable(script), "--ros-args", "--params-file", str(params)],
                         env=ros_env["env"], capture_output=True, text=True, timeout=STARTUP_TIMEOUT)
    text = out.stdout + out.stderr
    assert out.returncode == 2, text
    assert "Traceback" not in text
    errors = [ln for ln in text.splitlines() if "ERROR" in ln]
    assert len(errors) == 1, text
    assert name in errors[0] and allowed in errors[0], errors[0]


def test_int_where_float_expected_is_accepted(ros_env, tmp_path):
    """ROS parameter files give ints for floats (``v: 2``, ``lower: [0, -150]``): coerced, as
    in-process. The learner must start, not exit 2."""
    data = yaml.safe_load((ROOT / "config" / "arm15.yaml").read_text())
    data["/**"]["ros__parameters"]["task_space"] = {"lower": [0, -150], "upper": [150, 150]}
    data["sagg_learner"]["ros__parameters"]["v"] = 2
    params = tmp_path / "ints.yaml"
    params.write_text(yaml.safe_dump(data))
    p = start(ros_env, "learner", params, tmp_path)
    col = Collector(ros_env["ctx"])
    # the learner publishes its status at 2 Hz from the start (paused: no driver here)
    assert col.spin_until(lambda: col.status is not None, STARTUP_TIMEOUT, [p]), logs(tmp_path)
    assert col.status.paused and col.status.micro_actions == 0


class ShuffledDriver:
    """A fake position-controlled arm in the test process: an ArmSim (same seed as the in-process
    run) whose joint_states list the joints in a shuffled order, with an extra joint."""

    def __init__(self, node: Node, spec, seed: int):
        self.sim = ArmSim(spec, seed=substream_seed(seed, "sim"))
        n = self.sim.n_joints
        self.perm = np.random.default_rng(123).permutation(n)
        assert not np.array_equal(self.perm, np.arange(n))
        self.names = [self.sim.joint_names[i] for i in self.perm] + ["gripper_joint"]
        self.commands = 0
        self.stamp_ns = 0
        self.js_pub = node.create_publisher(JointState, "/joint_states", qos(10))
        self.tip_pub = node.create_publisher(PointStamped, "/tip_position", qos(10))
        node.create_subscription(Float64MultiArray, "/forward_position_controller/commands", self.on_command, qos(10))
        node.create_timer(0.5, self.publish)

    def on_command(self, msg):
        self.sim.command(np.array(msg.data))
        self.commands += 1
        self.stamp_ns += 1_000_000
        self.publish()

    def publish(self):
        alpha, tip = self.sim.observe()
        js = JointState()
        js.header.stamp.sec, js.header.stamp.nanosec = divmod(self.stamp_ns, 1_000_000_000)
        js.name = self.names
        js.position = alpha[self.perm].tolist() + [0.7]
        js.velocity = [0.0] * (len(self.names))
        pt = PointStamped()
        pt.header.stamp = js.header.stamp
        pt.point.x, pt.point.y = float(tip[0]), float(tip[1])
        self.js_pub.publish(js)
        self.tip_pub.publish(pt)


def test_joints_matched_by_name(ros_env, tmp_path):
    """A driver listing joints in another order (plus an unknown joint) gives the same samples as
    the in-process run (actuator-random: learner + driver only)."""
    base = ROOT / "config" / "arm15.yaml"
    arm = {"dof": 7, "mode": "kinematic", "motor_noise": 0.2}
    steps = 120
    params = graph_params(base, tmp_path / "params.yaml", arm,
                          learner={"max_micro_actions": steps, "min_sample_subscribers": 1},
                          everyone={"strategy": "actuator-random"})
    col = Collector(ros_env["ctx"])
    sections = read_config(params)
    spec = arm_spec_from_params(node_params(sections, "sagg_sim_bridge", BRIDGE_SCHEMA))
    driver = ShuffledDriver(col.node, spec, seed=0)
    learner = start(ros_env, "learner", params, tmp_path)
    ok = col.spin_until(lambda: col.stopped() and len(col.samples) >= steps, STARTUP_TIMEOUT + RUN_TIMEOUT, [learner])
    assert ok, f"{len(col.samples)} samples\n{logs(tmp_path)}"
    assert driver.commands >= steps  # micro-actions + returns to rest
    run, _ = in_process(base, {"strategy": "actuator-random", **{f"arm.{k}": v for k, v in arm.items()}}, steps)
    mem = memory_from_samples(col.samples, 7, 2)
    assert mem.digest() == run.learner.memory.digest()
