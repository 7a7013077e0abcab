"""`sagg run --driver external`: the goal generator and the learner against a driver that is not the
MuJoCo bridge (test/fake_driver.py: a numpy arm at 250 Hz with latency, reading noise and its joints
under other names in reversed order), recorded, reported and evaluated ON THE ROBOT (through the
driver, learning paused) and, since the config's simulated arm is the same arm, in simulation too.

Also: a missing driver is named (topic, type) and the run gives up after --driver-timeout."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from sagg_bringup.graph.processes import pick_domain_id
from sagg_sim_bridge.arm import ArmSpec
from installed import SAGG

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RATE, LATENCY = 250.0, 0.008
# The fake driver's arm = the config's simulated arm: 3 equal links, 45 units, kinematic.
SPEC = ArmSpec(dof=3, total_length=45.0, mode="kinematic")
JOINTS = ["axis_0", "axis_1", "axis_2"]
N, GOALS = 400, 5
# Stated factor: after N micro-actions the mean error ON THE ROBOT is below this share of the
# initial one (the empty model leaves the arm at rest). Measured: ~0.1-0.2 (see the final report).
ROBOT_FACTOR = 0.5


def config(path: Path) -> Path:
    lower, upper = SPEC.limits()
    data = {
        "/**": {"ros__parameters": {"seed": 2, "strategy": "sagg-riac",
                                    "task_space": {"lower": [-10.0, -50.0], "upper": [50.0, 50.0]}}},
        "sagg_goal_generator": {"ros__parameters": {"g_max": 30}},
        "sagg_learner": {"ros__parameters": {
            "joints": JOINTS, "joint_limits": {"lower": lower.tolist(), "upper": upper.tolist()},
            "rest_posture": SPEC.rest_posture().tolist(),
            "v": 2.0, "q": 10, "subgoals": 3, "eval.goals": 30,
            # a real-time driver: latency plus two control periods; settled when the velocities ~0
            "observation_delay": LATENCY + 2.0 / RATE, "settle_velocity": 0.05}},
        "sagg_sim_bridge": {"ros__parameters": {"arm": {"dof": 3, "total_length": 45.0, "mode": "kinematic"}}},
    }
    path.write_text(yaml.safe_dump(data))
    return path


def env_for(domain: int) -> dict:
    return dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")


def start_driver(env: dict, log: Path) -> subprocess.Popen:
    lengths = [SPEC.total_length / SPEC.dof] * SPEC.dof
    return subprocess.Popen([sys.executable, str(HERE / "fake_driver.py"), "--dof", "3",
                             "--lengths", *map(str, lengths), "--rest", *map(str, SPEC.rest_posture()),
                             "--rate", str(RATE), "--latency", str(LATENCY), "--seed", "1"],
                            env=env, stdout=open(log, "w"), stderr=subprocess.STDOUT)


def stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.send_signal(2)
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


# rad: a command is compared with where the driver's arm is when it arrives, which may have moved
# on a little since the reading the command was computed from (latency, a state taken unsettled)
MEASURE_SLACK = 0.1


def largest_jump(driver_log: Path) -> float:
    """The driver's largest command-to-posture distance (test/fake_driver.py's last line)."""
    m = re.search(r"largest jump ([0-9.]+) rad", driver_log.read_text())
    assert m, driver_log.read_text()[-2000:]
    return float(m.group(1))


def test_sagg_run_external_driver_learns_and_is_evaluated_on_the_robot(tmp_path):
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = config(tmp_path / "arm3.yaml")
    driver = start_driver(env, tmp_path / "driver.log")
    out = tmp_path / "run"
    try:
        proc = subprocess.run([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", str(N),
                               "--eval-every", str(N), "--robot-eval-goals", str(GOALS), "--out", str(out), "--quiet",
                               "--domain-id", str(domain), "--driver-timeout", "60"],
                              env=env, capture_output=True, text=True, timeout=240)
    finally:
        stop(driver)
    assert proc.returncode == 0, proc.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["driver"] == "external" and s["micro_actions"] == N and s["error"] is None
    # no bridge was started: only the generator and the learner
    assert set(s["nodes"]) == {"sagg_goal_generator", "sagg_learner"}
    r = s["robot_evaluation"]
    assert r["label"] == "on the robot" and len(r["goals"]) == GOALS
    assert r["curve"][-1]["micro_actions"] == N and len(r["curve"][-1]["errors"]) == GOALS
    # the evaluation's metrics (eval_metrics) from the errors measured on the robot
    e = np.array(r["curve"][-1]["errors"])
    assert r["final_median_error"] == float(np.median(e))
    assert r["final_within_share"] == float(np.mean(e <= r["eval_metrics"]["within"]))
    assert len(r["band_mean_errors"]) == 4 and sum(r["eval_metrics"]["band_counts"]) == GOALS
    print(f"on the robot: {r['initial_mean_error']:.2f} -> {r['final_mean_error']:.2f}; simulated: "
          f"{s['curve'][0]['mean_error']:.2f} -> {s['curve'][-1]['mean_error']:.2f}")
    assert r["final_mean_error"] < ROBOT_FACTOR * r["initial_mean_error"], r
    # the config's simulated arm is this arm: the offline simulated evaluation is given and labelled
    assert s["simulated_evaluation"] is True and s["curve_source"].startswith("simulated")
    assert [c["micro_actions"] for c in s["curve"]] == [0, N]
    assert s["curve"][-1]["mean_error"] < s["curve"][0]["mean_error"]
    # recorded: the learner's topics and the driver's; the evaluation's commands went through the driver
    topics = s["bag"]["topics"]
    assert topics["/sagg/sample"]["count"] == N
    assert topics["/forward_position_controller/commands"]["count"] >= N + r["steps"]
    assert topics["/joint_states"]["count"] > N and topics["/tip_position"]["count"] > N
    assert (out / "bag" / "metadata.yaml").is_file()
    report = (out / "report.md").read_text()
    assert "## Evaluation on the robot" in report and "simulated" in report
    assert "on the robot: mean error" in proc.stdout
    # the live view, recorded: region leaves, recent goals, the robot's test goals, the tip's path
    from sagg_bringup.graph.markers import marker_arrays_from_bag, render_markers
    arrays = marker_arrays_from_bag(out / "bag")
    assert topics["/sagg/markers"]["count"] == len(arrays) >= 1
    last = arrays[-1]
    ns = {m.ns for m in last.markers}
    assert {"regions", "region_edges", "goals", "test_goals", "tip_path"} <= ns
    assert last.markers[0].action == 3  # DELETEALL first: split leaves disappear
    assert sum(m.ns == "regions" for m in last.markers) == len(s["regions"])
    tg = next(m for m in last.markers if m.ns == "test_goals")
    assert [[p.x, p.y] for p in tg.points] == [g[:2] for g in r["goals"]]
    png = render_markers(last, tmp_path / "markers.png")
    assert png.stat().st_size > 10_000
    # params.yaml is reusable without `sagg run`: no waits for its recorder
    lp = yaml.safe_load((out / "params.yaml").read_text())["sagg_learner"]["ros__parameters"]
    assert lp["min_sample_subscribers"] == 0 and lp["joints"] == JOINTS


def test_missing_driver_is_named(tmp_path):
    domain = pick_domain_id()
    cfg = config(tmp_path / "arm3.yaml")
    proc = subprocess.run([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", "10",
                           "--out", str(tmp_path / "run"), "--domain-id", str(domain), "--driver-timeout", "4"],
                          env=env_for(domain), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr[-2000:]
    err = proc.stderr
    assert "the driver did not come up in 4 s" in err
    assert "/joint_states (sensor_msgs/msg/JointState): no publisher" in err
    assert "/tip_position (geometry_msgs/msg/PointStamped): no publisher" in err
    assert "/forward_position_controller/commands (std_msgs/msg/Float64MultiArray): no subscriber" in err
    # and nothing was started
    assert not (tmp_path / "run" / "logs" / "learner.log").exists()


def test_robot_test_goals_without_a_model_are_spread_over_reached_points():
    from sagg_bringup.graph.external import sim_model_matches
    from sagg_bringup.graph.robot_eval import spread_points
    pts = np.array([[0.0, 0.0], [0.1, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0], [0.05, 0.02]])
    chosen = spread_points(pts, 4, seed=0)
    # farthest-point selection: the four corners, never two of the clustered points near the origin
    assert len(chosen) == 4 and sum(np.linalg.norm(chosen, axis=1) < 1.0) == 1
    assert np.array_equal(spread_points(pts, 4, seed=0), chosen)
    lower, upper = SPEC.limits()
    lp = {"joints": JOINTS, "joint_limits.lower": lower.tolist(), "joint_limits.upper": upper.tolist(),
          "rest_posture": SPEC.rest_posture().tolist()}
    assert sim_model_matches(lp, SPEC)
    assert not sim_model_matches(dict(lp, rest_posture=[0.0, 0.0, 0.0]), SPEC)
    assert not sim_model_matches(lp, ArmSpec(dof=4, total_length=45.0))


def test_driver_with_other_joint_names_is_named(tmp_path):
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = config(tmp_path / "arm3.yaml")
    driver = subprocess.Popen([sys.executable, str(HERE / "fake_driver.py"), "--dof", "3", "--joint-prefix", "j"],
                              env=env, stdout=open(tmp_path / "driver.log", "w"), stderr=subprocess.STDOUT)
    try:
        proc = subprocess.run([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", "10",
                               "--out", str(tmp_path / "run"), "--domain-id", str(domain), "--driver-timeout", "6"],
                              env=env, capture_output=True, text=True, timeout=120)
    finally:
        stop(driver)
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert ("/joint_states lacks joint(s) axis_0, axis_1, axis_2 (it names j2, j1, j0; "
            "the learner's 'joints': axis_0, axis_1, axis_2)") in proc.stderr, proc.stderr[-2000:]
    assert "/tip_position" not in proc.stderr.split("missing:")[-1]  # the task point is there


def test_evaluation_on_the_robot_during_learning_pauses_and_resumes(tmp_path):
    """--robot-eval-every: learning pauses (/sagg/pause), the robot reaches the test goals, the arm
    goes back where it paused, learning resumes and completes."""
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = config(tmp_path / "arm3.yaml")
    driver = start_driver(env, tmp_path / "driver.log")
    out = tmp_path / "run"
    n = 150
    try:
        proc = subprocess.run([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", str(n),
                               "--eval-every", str(n), "--robot-eval-goals", "2", "--robot-eval-every", "60",
                               "--out", str(out), "--quiet", "--no-report", "--domain-id", str(domain)],
                              env=env, capture_output=True, text=True, timeout=240)
    finally:
        stop(driver)
    assert proc.returncode == 0, proc.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    r = s["robot_evaluation"]
    at = [c["micro_actions"] for c in r["curve"]]
    # (a mid-run evaluation at 60 and 120 of the samples recorded; a learner faster than this
    # process records, on a loaded machine, may be past 120 when the one at 60 ends: then only one)
    assert len(at) in (2, 3) and 60 <= at[0] < n and at == sorted(at) and at[-1] == n, at
    assert s["micro_actions"] == n and s["bag"]["topics"]["/sagg/sample"]["count"] == n
    log = (out / "logs" / "learner.log").read_text()
    # (counted per cause: on a loaded machine a stale joint state may also hold and release the
    # learner once, a "driver hold released: resuming" of its own)
    paused = len(at) - 1
    assert log.count("paused by the /sagg/pause service") == paused and log.count("service hold released") == paused
    # every goal of the evaluation went through the learner's /sagg/reach: the return to rest that
    # measures the initial error, then each goal at each evaluation, none cut by its time bound
    trace = json.loads((out / "robot_evaluation.json").read_text())["trace"]
    assert len(trace) == 1 + 2 * len(at) and sum(t["steps"] for t in trace[1:]) == r["steps"], trace
    assert not any(t["timed_out"] for t in trace) and r["goals_timed_out"] == 0
    assert {t["outcome"] for t in trace} <= {"reached", "budget", "no model"}, trace
    # no command, the learner's returns to rest and the evaluation's included, asks a joint to
    # move more than max_joint_step from where it is (measured by the driver at each command's arrival);
    # a return to rest in one command across the range was a jump of up to ~1.5 rad here
    lp = yaml.safe_load((out / "params.yaml").read_text())["sagg_learner"]["ros__parameters"]
    jump = largest_jump(tmp_path / "driver.log")
    assert lp["rest_return"] == "stepped" and jump <= lp["max_joint_step"] + MEASURE_SLACK, jump


def test_driver_with_only_joint_states_learns_through_its_model(tmp_path):
    """A 6-joint driver that publishes /joint_states only (no tracker), the learner's
    ``task_source: model`` computing the tool's (x, y, z) from the robot's MJCF: check-driver
    confirms the contract in model mode, sagg run learns on it and evaluates on the robot in 3-D."""
    from sagg_common.robot_model import RobotModel
    robot = RobotModel.load(str(ROOT / "config/robots/arm6.xml"), "tool")
    domain = pick_domain_id()
    env = env_for(domain)
    base = yaml.safe_load((ROOT / "config/arm6_mjcf.yaml").read_text())
    base["sagg_sim_bridge"]["ros__parameters"]["arm"]["model"] = str(ROOT / "config/robots/arm6.xml")
    base["sagg_learner"]["ros__parameters"].update({
        "task_source": "model", "eval.goals": 20,
        "observation_delay": LATENCY + 2.0 / RATE, "settle_velocity": 0.05})
    cfg = tmp_path / "arm6_robot.yaml"
    cfg.write_text(yaml.safe_dump(base))
    n = len(robot.joint_names)
    driver = subprocess.Popen([sys.executable, str(HERE / "fake_driver.py"), "--dof", str(n), "--no-tip",
                               "--joint-names", *robot.joint_names, "--rest", *map(str, robot.rest),
                               "--lower", *map(str, robot.lower), "--upper", *map(str, robot.upper),
                               "--rate", str(RATE), "--latency", str(LATENCY), "--seed", "3"],
                              env=env, stdout=open(tmp_path / "driver.log", "w"), stderr=subprocess.STDOUT)
    out = tmp_path / "run"
    steps = 400
    try:
        check = subprocess.run([SAGG, "check-driver", str(cfg), "--seconds", "1", "--domain-id", str(domain)],
                               env=env, capture_output=True, text=True, timeout=120)
        proc = subprocess.run([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", str(steps),
                               "--eval-every", str(steps), "--robot-eval-goals", "6", "--out", str(out), "--quiet",
                               "--no-report", "--domain-id", str(domain), "--driver-timeout", "60"],
                              env=env, capture_output=True, text=True, timeout=400)
    finally:
        stop(driver)
    assert check.returncode == 0, check.stdout + check.stderr
    assert "contract met" in check.stdout and "/tip_position" not in check.stdout.split("contract met")[0]
    assert "the task point from the joints through" in check.stdout, check.stdout
    assert proc.returncode == 0, proc.stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["micro_actions"] == steps and s["error"] is None
    # no tracker anywhere: the task point of every sample is the model's, in 3-D
    topics = s["bag"]["topics"]
    assert topics.get("/tip_position", {}).get("count", 0) == 0 and topics["/sagg/sample"]["count"] == steps
    r = s["robot_evaluation"]
    assert len(r["goals"]) == 6 and all(len(g) == 3 for g in r["goals"])
    # a 6-joint arm in 3-D learns more slowly than the 3-link planar one: at 400 micro-actions the
    # robot's error was ~0.5 of the empty model's (0.92 -> 0.47 m); stated bound: below 0.75 of it
    assert r["final_mean_error"] < 0.75 * r["initial_mean_error"], r
    jump = largest_jump(tmp_path / "driver.log")
    lp = yaml.safe_load((out / "params.yaml").read_text())["sagg_learner"]["ros__parameters"]
    assert lp["task_source"] == "model" and lp["task_model"]["file"].endswith("arm6.xml")
    assert jump <= lp["max_joint_step"] + MEASURE_SLACK, jump
