"""Parameter files that work everywhere:

- the params.yaml a `sagg run` writes starts a learning graph with the three node executables alone
  (no `sagg run`, no recorder): it holds none of the waits only `sagg run`'s recorder satisfies;
- the launch file's expansion (sagg_bringup.graph.launch_params) fills every derived parameter for every
  installed config, for both drivers, and `config:=` defaults to arm8;
- shared '/**' parameters produce no "parameters not used" line in the nodes that do not declare them.
"""
from __future__ import annotations

import ast
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from sagg_bringup.inprocess.arm_params import graph_params, load_graph_config
from sagg_bringup.graph.params_files import RUN_KEYS, run_only_params, set_checkpoint_dirs, write_params_file
from sagg_bringup.graph.launch_params import installed_configs, launch_plan, resolve_config, write_plan
from sagg_common.params import read_config
from sagg_msgs.msg import CompetenceReport, LearnerStatus
from sagg_sim_bridge.params import arm_spec_from_params

import test_nodes_graph
from test_nodes_graph import STARTUP_TIMEOUT, logs, start, stop
from installed import SAGG

ros_env = test_nodes_graph.ros_env  # the fixture: a private ROS domain per test

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "src/sagg_bringup/launch/sagg.launch.py"


def run_params_file(out: Path, micro_actions: int) -> Path:
    """params.yaml exactly as `sagg run` writes it (run_graph: graph_params, checkpoint dirs, write)."""
    full = load_graph_config(ROOT / "config/arm8.yaml")
    params = graph_params(full, micro_actions, "lockstep")
    set_checkpoint_dirs(params, out)
    write_params_file(out / "params.yaml", params)
    return out / "params.yaml"


def test_run_params_file_has_no_recorder_waits(tmp_path):
    path = run_params_file(tmp_path, 100)
    doc = yaml.safe_load(path.read_text())
    assert doc["sagg_learner"]["ros__parameters"]["min_sample_subscribers"] == 0
    assert doc["sagg_goal_generator"]["ros__parameters"]["min_goal_subscribers"] == 0
    # ... `sagg run` gives them on its nodes' command lines instead
    assert run_only_params({k: v["ros__parameters"] for k, v in doc.items()}) == {
        "sagg_goal_generator": {"min_goal_subscribers": 1}, "sagg_learner": {"min_sample_subscribers": 1}}


def test_three_executables_learn_from_a_run_params_file(ros_env, tmp_path):
    steps = 150
    params = run_params_file(tmp_path, steps)
    node = Node("sagg_test_watcher", context=ros_env["ctx"])
    status: list[LearnerStatus] = []
    reports: list[CompetenceReport] = []
    qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    # (no /sagg/sample or /sagg/goal subscriber: nothing records here)
    node.create_subscription(LearnerStatus, "/sagg/status", status.append, qos)
    # transient_local as the learner offers it: on a loaded machine the learner can finish its 150
    # micro-actions before this subscription matches; the late-joiner still gets every report
    latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(CompetenceReport, "/sagg/competence", reports.append, latched)
    import rclpy.executors
    ex = rclpy.executors.SingleThreadedExecutor(context=ros_env["ctx"])
    ex.add_node(node)
    # (the budget is not in params.yaml, a configuration: given the ROS way)
    procs = [start(ros_env, s, params, tmp_path, ("-p", f"max_micro_actions:={steps}") if s == "learner" else ())
             for s in ("mujoco_bridge", "goal_generator", "learner")]
    end = time.monotonic() + STARTUP_TIMEOUT + 60
    while time.monotonic() < end and not (status and status[-1].micro_actions >= steps):
        for p in procs:
            assert p.poll() is None, logs(tmp_path)
        ex.spin_once(timeout_sec=0.05)
    assert status and status[-1].micro_actions >= steps, logs(tmp_path)
    # a watcher that matched late gets the reports from the learner's transient_local history, which
    # may arrive after the (volatile, periodic) status that ended the loop: spin until they are here
    settle = time.monotonic() + 20
    while time.monotonic() < settle and not (reports and reports[-1].micro_actions >= steps - 50 and len(reports) > 10):
        ex.spin_once(timeout_sec=0.05)
    assert "max_micro_actions" in status[-1].pause_reason
    assert len(reports) > 10 and reports[-1].micro_actions <= steps  # reports flow to the generator
    assert len({r.goal_seq for r in reports if r.goal_seq}) >= 2      # goals were answered
    # the bridge got only its own section: no "parameters not used" line
    assert "parameters not used" not in (tmp_path / "mujoco_bridge.log").read_text()
    ex.shutdown()
    node.destroy_node()


def test_shared_parameters_make_no_unused_warning(ros_env, tmp_path):
    """config/arm8.yaml as is (with its '/**' section) for the bridge, which declares none of
    strategy / task_space: no "parameters not used" line; a '-p' parameter nobody declares still is."""
    p = start(ros_env, "mujoco_bridge", ROOT / "config/arm8.yaml", tmp_path)
    log = tmp_path / "mujoco_bridge.log"
    end = time.monotonic() + STARTUP_TIMEOUT
    while time.monotonic() < end and "arm" not in log.read_text():
        assert p.poll() is None, log.read_text()
        time.sleep(0.2)
    time.sleep(0.5)
    text = log.read_text()
    assert "sagg_sim_bridge" in text and "parameters not used" not in text, text


@pytest.mark.parametrize("name", sorted(installed_configs()))
@pytest.mark.parametrize("driver", ["sim", "external"])
def test_launch_plan_fills_every_derived_parameter(name, driver, tmp_path):
    plan = launch_plan(name, driver)
    assert plan.config == resolve_config(name)
    names = [n for _, _, n in plan.nodes]
    assert names == (["sagg_sim_bridge"] if driver == "sim" else []) + ["sagg_goal_generator", "sagg_learner"] \
        or names == ["sagg_goal_generator", "sagg_learner"] + (["sagg_sim_bridge"] if driver == "sim" else [])
    lp, gp = plan.params["sagg_learner"], plan.params["sagg_goal_generator"]
    # no waits for a recorder; no stop unless asked
    assert lp["min_sample_subscribers"] == 0 and gp["min_goal_subscribers"] == 0
    # the task space is the config's, the same for both levels
    sections = read_config(plan.config)
    for key in ("task_space.lower", "task_space.upper"):
        want = sections.get("/**", {}).get(key, sections.get("sagg_learner", {}).get(key))
        if want is not None:
            assert lp[key] == [float(v) for v in want] == gp[key]
    if plan.setup == "arm":  # arm: joints / limits / rest from the config's arm (its DOF)
        spec = arm_spec_from_params(plan.params["sagg_sim_bridge"])
        assert lp["joints"] == spec.joint_names() and len(lp["joints"]) == len(spec.limits()[0])
        assert lp["rest_posture"] == spec.rest_posture().tolist()
        assert lp["joint_limits.lower"] == spec.limits()[0].tolist()
        assert [e for _, e, _ in plan.nodes if e != "goal_generator"] == (["learner", "mujoco_bridge"]
                                                                         if driver == "sim"
                                                                         else ["learner"]) or driver == "sim"
    else:  # synergy set-ups: their own learner and bridge
        assert ("sagg_low_level", "fixed_learner", "sagg_learner") in plan.nodes
    path = write_plan(plan, tmp_path / "params.yaml")
    assert set(yaml.safe_load(path.read_text())) == set(plan.params)


def test_launch_plan_uses_the_configs_own_joints_with_an_external_driver(tmp_path):
    cfg = tmp_path / "myarm.yaml"
    cfg.write_text(yaml.safe_dump({"sagg_learner": {"ros__parameters": {
        "joints": ["a", "b"], "joint_limits": {"lower": [-1.0, -1.0], "upper": [1.0, 1.0]},
        "rest_posture": [0.1, 0.2]}}}))
    plan = launch_plan(str(cfg), "external")
    assert plan.params["sagg_learner"]["joints"] == ["a", "b"]
    assert [n for _, _, n in plan.nodes] == ["sagg_goal_generator", "sagg_learner"]
    # with the simulated bridge, the bridge's arm wins (as in `sagg run`)
    assert len(launch_plan(str(cfg), "sim").params["sagg_learner"]["joints"]) == 8
    from sagg_common.params import ConfigError
    with pytest.raises(ConfigError, match="driver"):
        launch_plan(str(cfg), "robot")
    with pytest.raises(ConfigError, match="arm8"):
        launch_plan("no_such_config")


def test_launch_file_arguments():
    """The launch file's declared arguments and defaults (read from its source: no ros2 launch on PyPI)."""
    tree = ast.parse(LAUNCH.read_text())
    args = {}
    for call in ast.walk(tree):
        if isinstance(call, ast.Call) and getattr(call.func, "id", "") == "DeclareLaunchArgument":
            kw = {k.arg: ast.literal_eval(k.value) for k in call.keywords if k.arg in ("default_value", "choices")}
            args[ast.literal_eval(call.args[0])] = kw
    assert args["config"]["default_value"] == "arm8"
    assert args["driver"] == {"default_value": "sim", "choices": ["sim", "external"]}
    assert args["record"] == {"default_value": "false", "choices": ["true", "false"]}
    assert "launch_plan(" in LAUNCH.read_text()


# --------------------------------------------------------------- params.yaml: a configuration, not a run
def test_params_file_holds_no_run_specific_value_and_sagg_run_gives_them(tmp_path):
    full = load_graph_config(ROOT / "config/arm8.yaml")
    params = graph_params(full, 300, "lockstep")
    assert set_checkpoint_dirs(params, tmp_path) == []
    write_params_file(tmp_path / "params.yaml", params)
    doc = yaml.safe_load((tmp_path / "params.yaml").read_text())
    for section in doc.values():
        assert not set(section["ros__parameters"]) & set(RUN_KEYS)
    # ... on the nodes' command lines: the run's own checkpoint directory, its budget, no resume
    run = run_only_params(params)
    own = str((tmp_path / "checkpoint").resolve())
    assert run["sagg_learner"]["checkpoint_dir"] == own == run["sagg_goal_generator"]["checkpoint_dir"]
    assert run["sagg_learner"]["max_micro_actions"] == 300
    assert run["sagg_learner"]["resume"] is False and run["sagg_goal_generator"]["resume"] is False


def test_another_sagg_run_on_an_older_params_file_starts_a_new_run(tmp_path):
    """An older sagg run's params.yaml names its run's checkpoint_dir: a new run keeps its own
    (and says so); only --resume continues, from DIR/checkpoint."""
    old = tmp_path / "old" / "checkpoint"
    old.mkdir(parents=True)
    (old / "learner.json").write_text("{}")
    params = graph_params(load_graph_config(ROOT / "config/arm8.yaml"), 300, "lockstep")
    params["sagg_learner"]["checkpoint_dir"] = str(old)
    new = tmp_path / "new"
    notes = set_checkpoint_dirs(params, new)
    assert params["sagg_learner"]["checkpoint_dir"] == str((new / "checkpoint").resolve())
    assert params["sagg_learner"]["resume"] is False
    assert len(notes) == 1 and str(old) in notes[0]
    # --resume of the new run: its own checkpoint
    (new / "checkpoint").mkdir(parents=True)
    (new / "checkpoint" / "learner.json").write_text("{}")
    params["sagg_learner"]["checkpoint_dir"] = str(old)
    assert set_checkpoint_dirs(params, new, resume=True) == []
    assert params["sagg_learner"]["checkpoint_dir"] == str((new / "checkpoint").resolve())
    assert params["sagg_learner"]["resume"] is True


def test_launch_of_a_run_params_file_names_no_checkpoint(tmp_path):
    path = run_params_file(tmp_path, 100)
    plan = launch_plan(str(path))
    assert plan.params["sagg_learner"]["checkpoint_dir"] == "" and plan.params["sagg_learner"]["resume"] is False
    assert plan.params["sagg_goal_generator"]["checkpoint_dir"] == ""
    doc = yaml.safe_load(path.read_text())
    assert all("checkpoint_dir" not in v["ros__parameters"] for v in doc.values())


def _files(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(d.iterdir())}


def test_a_finished_runs_params_file_starts_a_new_run_and_leaves_that_run_alone(ros_env, tmp_path):
    """The three executables on a finished `sagg run`'s params.yaml learn a new
    run (micro-actions from 0 to their own budget), and the parameters an older sagg run wrote
    (with its checkpoint_dir) make the learner and generator refuse to start (exit 2, one line
    naming 'resume'); the old run's checkpoint files stay byte for byte as they were."""
    run = tmp_path / "run"
    proc = subprocess.run([SAGG, "run", str(ROOT / "config/arm8.yaml"), "--micro-actions", "100",
                           "--eval-every", "100", "--out", str(run), "--quiet", "--no-report"],
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ck = run / "checkpoint"
    before = _files(ck)
    assert "learner.json" in before and "generator.json" in before
    # the parameters an older `sagg run` wrote: its checkpoint_dir and budget in the file
    doc = yaml.safe_load((run / "params.yaml").read_text())
    doc["sagg_learner"]["ros__parameters"].update(checkpoint_dir=str(ck), max_micro_actions=100)
    doc["sagg_goal_generator"]["ros__parameters"]["checkpoint_dir"] = str(ck)
    old = tmp_path / "old_params.yaml"
    old.write_text(yaml.safe_dump(doc))
    logs_old = tmp_path / "old"
    logs_old.mkdir()
    refused = [start(ros_env, s, old, logs_old) for s in ("goal_generator", "learner")]
    for p in refused:
        p.wait(STARTUP_TIMEOUT)
    for p, script in zip(refused, ("goal_generator", "learner")):
        text = (logs_old / f"{script}.log").read_text()
        assert p.returncode == 2 and "parameter 'checkpoint_dir'" in text and "'resume' is false" in text, text
    assert _files(ck) == before
    # the run's own params.yaml: a new run, from 0 to the budget given here
    steps = 60
    node = Node("sagg_test_watcher", context=ros_env["ctx"])
    status: list[LearnerStatus] = []
    node.create_subscription(LearnerStatus, "/sagg/status", status.append, 100)
    import rclpy.executors
    ex = rclpy.executors.SingleThreadedExecutor(context=ros_env["ctx"])
    ex.add_node(node)
    procs = [start(ros_env, s, run / "params.yaml", tmp_path,
                   ("-p", f"max_micro_actions:={steps}") if s == "learner" else ())
             for s in ("mujoco_bridge", "goal_generator", "learner")]
    end = time.monotonic() + STARTUP_TIMEOUT + 60
    while time.monotonic() < end and not (status and "max_micro_actions" in status[-1].pause_reason):
        for p in procs:
            assert p.poll() is None, logs(tmp_path)
        ex.spin_once(timeout_sec=0.05)
    assert status and "max_micro_actions" in status[-1].pause_reason, logs(tmp_path)
    # a new run: from 0 (the old run's learner had 100 micro-actions and samples)
    assert status[-1].micro_actions == steps and status[-1].samples == steps
    for p in procs:
        stop(p)
    assert _files(ck) == before
    log = (tmp_path / "learner.log").read_text()
    assert "resumed from" not in log and f"stopped acting ({steps} micro-actions in" in log, log
    ex.shutdown()
    node.destroy_node()


def test_sagg_run_takes_a_config_by_name_like_the_launch_file(tmp_path):
    """`ros2 launch ... config:=arm8` took a name, `sagg run arm8` answered "cannot read":
    both resolve names the same way (launch_params.resolve_config), from any directory."""
    bad = subprocess.run([SAGG, "run", "arm99", "--micro-actions", "10"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 2 and "config 'arm99': no such file" in bad.stderr, bad.stderr
    assert "arm8" in bad.stderr.split("allowed:")[1]
    assert resolve_config("arm8") == resolve_config("arm8.yaml") and resolve_config("arm8").is_file()


def test_a_robot_config_runs_in_the_lockstep_simulation():
    """The same config drives the simulated bridge and the robot: the robot's observation_delay
    (a real-time driver's latency) does not apply to the lockstep bridge, which answers every
    command with the state after it (with it, the learner waited for ever)."""
    from sagg_bringup.inprocess.arm_params import graph_params, load_graph_config
    full = load_graph_config("config/arm7_urdf.yaml", {"observation_delay": 0.012})
    assert full["sagg_learner"]["observation_delay"] == 0.012
    assert graph_params(full, 100, "lockstep")["sagg_learner"]["observation_delay"] == 0.0
    assert graph_params(full, 100, "realtime")["sagg_learner"]["observation_delay"] == 0.012
    from sagg_bringup.graph.external import external_params
    assert external_params(full, 100, False)["sagg_learner"]["observation_delay"] == 0.012  # the robot's
