"""A real arm, unattended: `sagg run --driver external` against test/arm_driver.py, which behaves as
a real ros2_control arm (velocity- and acceleration-limited tracking with lag and latency, positions
and velocities at 250 Hz, a calibration gap, a gripper on /joint_states, protective stops at the
table or on a setpoint jump, an e-stop on demand).

- with the table in the config's scene: no protective stop, no table contact, the setpoints
  streamed within the scaled velocity limits;
- the arm stopped mid-run (an e-stop for 8 s): the learner holds, named, sends probes only, and
  learning resumes by itself;
- the arm stopped during the evaluation on the robot: every goal ends at its time bound, the run ends.
"""
from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import yaml

from sagg_bringup.bags.bag_reader import bag_messages
from sagg_bringup.graph.processes import pick_domain_id
from installed import SAGG
from test_external_driver import env_for

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
REST = [0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4]  # config/arm7_urdf.yaml
CMD_TOPIC = "/forward_position_controller/commands"
VSCALED = 2.175 * 0.5   # the URDF's <limit velocity> x velocity_scale
RATE = 50.0             # command_rate


def table_config(path: Path) -> Path:
    """config/arm7_urdf.yaml on a table (scene.floor 0: the base's plane), the task point from the
    model, the driver's latency in observation_delay."""
    base = yaml.safe_load((ROOT / "config/arm7_urdf.yaml").read_text())
    base["/**"]["ros__parameters"]["scene"] = {"floor": 0.0}
    base["sagg_sim_bridge"]["ros__parameters"]["arm"]["model"] = str(ROOT / "config/robots/arm7.urdf")
    base["sagg_learner"]["ros__parameters"].update({"task_source": "model", "observation_delay": 0.012})
    path.write_text(yaml.safe_dump(base))
    return path


def start_arm(env: dict, out: Path, *extra: str) -> subprocess.Popen:
    out.mkdir(parents=True, exist_ok=True)
    return subprocess.Popen([sys.executable, str(HERE / "arm_driver.py"), "--model", "config/robots/arm7.urdf",
                             "--effector", "tool0", "--rest", *map(str, REST), "--table", "0.0", "--seed", "2",
                             "--stats", str(out / "driver.json"), *extra],
                            cwd=ROOT, env=env, stdout=open(out / "driver.log", "w"), stderr=subprocess.STDOUT)


def stop_arm(p: subprocess.Popen, out: Path) -> dict:
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(15)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    return json.loads((out / "driver.json").read_text())


def sagg_run(env: dict, cfg: Path, out: Path, domain: int, n: int, *extra: str, timeout: float = 400):
    return subprocess.run([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", str(n),
                           "--eval-every", str(n), "--out", str(out), "--quiet", "--no-report",
                           "--domain-id", str(domain), "--driver-timeout", "60", *extra],
                          env=env, capture_output=True, text=True, timeout=timeout)


def setpoint_steps(bag: Path) -> np.ndarray:
    """The largest joint change between consecutive commands on the commands topic, per command."""
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64MultiArray
    cmds = [np.array(deserialize_message(bytes(raw), Float64MultiArray).data)
            for _, _, _, raw in bag_messages([bag], [CMD_TOPIC])]
    return np.abs(np.diff(np.array(cmds), axis=0)).max(axis=1)


def test_a_real_arm_on_a_table_learns_without_a_stop_or_a_contact(tmp_path):
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = table_config(tmp_path / "arm7_table.yaml")
    arm = start_arm(env, tmp_path / "arm")
    n = 70
    try:
        r = sagg_run(env, cfg, tmp_path / "run", domain, n, "--robot-eval-goals", "2")
    finally:
        stats = stop_arm(arm, tmp_path / "arm")
    assert r.returncode == 0, r.stderr[-3000:]
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["micro_actions"] == n and s["robot_evaluation"]["goals_timed_out"] == 0
    # the arm never stopped, never touched the table (on its true, miscalibrated geometry)
    assert stats["protective_stops"] == 0 and stats["table_contacts"] == 0, stats
    assert stats["lowest_point"] > 0.0, stats
    # each move streamed: many setpoints per micro-action, each within the scaled velocity limit of
    # the previous one (a move's first setpoint: from the measured posture, which the arm settled
    # near the previous one's end, within settle_tolerance and reading noise)
    steps = setpoint_steps(tmp_path / "run" / "bag")
    assert len(steps) > 5 * n, len(steps)
    assert steps.max() <= VSCALED / RATE + 0.03, steps.max()
    assert stats["largest_setpoint_jump"] < 0.15, stats  # (the old single setpoints: up to max_joint_step 0.5)
    log = (tmp_path / "run" / "logs" / "learner.log").read_text()
    assert "moves streamed at 50 Hz" in log and "scene: floor at z=0.000 m" in log


def test_a_joint_trajectory_controller_gets_one_timed_trajectory_per_move(tmp_path):
    """command_interface 'trajectory': each move is one JointTrajectory on the trajectory
    controller's topic, timed by the scaled velocity limits; nothing on the commands topic."""
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = table_config(tmp_path / "arm7_table.yaml")
    arm = start_arm(env, tmp_path / "arm")
    n = 30
    try:
        r = sagg_run(env, cfg, tmp_path / "run", domain, n, "--robot-eval-goals", "1",
                     "--set", "command_interface=trajectory", "--set", "controller=joint_trajectory_controller")
    finally:
        stats = stop_arm(arm, tmp_path / "arm")
    assert r.returncode == 0, r.stderr[-3000:]
    # (the driver counts every command; all of them came as trajectories)
    assert stats["protective_stops"] == 0 and stats["commands"] == stats["trajectories"] >= n, stats
    log = (tmp_path / "run" / "logs" / "learner.log").read_text()
    assert "moves as trajectories on /joint_trajectory_controller/joint_trajectory" in log


def test_a_stopped_arm_is_held_and_learning_resumes_by_itself(tmp_path):
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = table_config(tmp_path / "arm7_table.yaml")
    # an e-stop 6 s after the first command, released 8 s later
    arm = start_arm(env, tmp_path / "arm", "--freeze-at", "6", "--freeze-for", "8")
    n = 100
    try:
        r = sagg_run(env, cfg, tmp_path / "run", domain, n, "--robot-eval-goals", "2")
    finally:
        stats = stop_arm(arm, tmp_path / "arm")
    assert r.returncode == 0, r.stderr[-3000:]
    assert stats["freezes"] == 1 and stats["protective_stops"] == 0, stats
    log = (tmp_path / "run" / "logs" / "learner.log").read_text()
    assert "the arm does not follow its setpoints (protective stop or e-stop?)" in log, log[-3000:]
    assert "follow hold released" in log and "probing whether the arm follows" in log
    # while stopped: the rest of the move in flight (at most 0.5 s of setpoints at 50 Hz) and then
    # only probes (one every follow_retry = 5 s), not a stream of commands
    assert stats["ignored_freeze"] <= 25 + 3, stats
    s = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert s["micro_actions"] == n and s["error"] is None


def test_the_evaluation_on_a_stopped_arm_ends_at_its_time_bound(tmp_path):
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = table_config(tmp_path / "arm7_table.yaml")
    arm = start_arm(env, tmp_path / "arm")
    out = tmp_path / "run"
    p = subprocess.Popen([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", "40", "--eval-every", "40",
                          "--out", str(out), "--no-report", "--domain-id", str(domain), "--driver-timeout", "60",
                          "--robot-eval-goals", "2", "--robot-eval-goal-seconds", "3"],
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    said: list[str] = []

    def read() -> None:  # the progress goes to stderr; the evaluation's start is said there
        for line in p.stderr:
            said.append(line)
            if "evaluating on the robot" in line:
                arm.send_signal(signal.SIGUSR1)  # the e-stop pressed, never released

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        p.wait(timeout=400)
    finally:
        if p.poll() is None:
            p.kill()
        stats = stop_arm(arm, tmp_path / "arm")
    reader.join(5)
    assert p.returncode == 0, "".join(said)[-3000:]
    assert stats["freezes"] == 1, stats
    r = json.loads((out / "summary.json").read_text())["robot_evaluation"]
    # every goal canceled at 3 s (the rest reach before them too), the whole evaluation bounded
    assert r["goals_timed_out"] == 2, r
    assert r["seconds"] < 3 * (3 + 10), r["seconds"]
    trace = json.loads((out / "robot_evaluation.json").read_text())["trace"]
    assert len(trace) == 3 and all(t["timed_out"] for t in trace), trace
    assert all(t["outcome"] == "canceled" and t["steps"] == 0 for t in trace[1:]), trace


def test_check_driver_probes_the_way_the_scene_allows():
    """sagg check-driver's probe move (one joint, a little) meets the scene as the learner's moves
    do: the other way when the first is refused, none when both are."""
    from sagg_bringup.graph.check_driver import probe_target

    class Scene:  # refuses any move of joint 1 upward (a box above it), or every move
        def __init__(self, all_moves=False):
            self.all_moves = all_moves

        def segment(self, a0, a1):
            from sagg_common.scene import Refusal
            if self.all_moves or a1[1] > a0[1]:
                return Refusal("box", "link2 in box 1", 1.0, -0.01)
            return None

    start, lo, hi = np.zeros(3), -np.ones(3), np.ones(3)
    target, refusal = probe_target(start, 1, 0.05, lo, hi, None)
    assert refusal is None and target[1] == 0.05
    target, refusal = probe_target(start, 1, 0.05, lo, hi, Scene())
    assert refusal is None and target[1] == -0.05 and target[0] == target[2] == 0.0
    target, refusal = probe_target(start, 1, 0.05, lo, hi, Scene(all_moves=True))
    assert target is None and refusal.cause == "box"
