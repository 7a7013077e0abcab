"""test/arm_driver.py, the driver that behaves like a real ros2_control arm: started as a process on
a private ROS domain, commanded from this process. It moves no faster than its velocity limits; a
setpoint jump beyond --jump-limit is a protective stop (commands ignored for --stop-ignore s, then
accepted); bending the elbow toward the table stops the arm at first contact, above the table (true
geometry); the gripper's joint comes in messages of its own; the statistics (line and JSON) count
it all. Plus its ROS-free parts: the models' velocity limits and an e-stop (--freeze-at)."""
from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import rclpy.executors
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from sagg_bringup.graph.processes import pick_domain_id

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import arm_driver  # noqa: E402

MODEL = "config/robots/arm7.urdf"
REST = [0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4]  # config/arm7_urdf.yaml
JOINTS = [f"arm7_joint{i}" for i in range(1, 8)]
VMAX = 2.175            # the URDF's <limit velocity> of every joint
JUMP, STOP_IGNORE = 0.5, 1.5
NOISE = 1e-4
GRIPPER = "gripper_finger_joint"
ARGS = ["--model", MODEL, "--effector", "tool0", "--rest", *map(str, REST), "--table", "0.0",
        "--jump-limit", str(JUMP), "--stop-ignore", str(STOP_IGNORE), "--noise", str(NOISE), "--seed", "1"]
STARTUP = 60.0


class Client:
    """This process's node: publishes commands, records /joint_states (arm and gripper apart)."""

    def __init__(self, ctx):
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.node = Node("arm_driver_test", context=ctx)
        self.cmd = self.node.create_publisher(Float64MultiArray, "/forward_position_controller/commands", qos)
        self.traj = self.node.create_publisher(JointTrajectory, "/joint_trajectory_controller/joint_trajectory", qos)
        self.arm: list[tuple[float, np.ndarray, np.ndarray]] = []  # (stamp s, positions, velocities)
        self.gripper: list[JointState] = []
        self.other: list[list[str]] = []
        self.node.create_subscription(JointState, "/joint_states", self.on_state,
                                      QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                                                 reliability=ReliabilityPolicy.RELIABLE))
        self.sent = 0
        self.ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self.ex.spin, daemon=True)
        self.thread.start()

    def on_state(self, msg: JointState) -> None:
        names = list(msg.name)
        if names == JOINTS:
            t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            self.arm.append((t, np.array(msg.position), np.array(msg.velocity)))
        elif names == [GRIPPER]:
            self.gripper.append(msg)
        else:
            self.other.append(names)

    def q(self) -> np.ndarray:
        return self.arm[-1][1].copy()

    def send(self, q) -> None:
        self.cmd.publish(Float64MultiArray(data=[float(x) for x in q]))
        self.sent += 1

    def send_trajectory(self, q, seconds: float) -> None:
        p = JointTrajectoryPoint(positions=[float(x) for x in q])
        p.time_from_start.sec, p.time_from_start.nanosec = int(seconds), int((seconds % 1) * 1e9)
        self.traj.publish(JointTrajectory(joint_names=JOINTS, points=[p]))
        self.sent += 1

    def since(self, k: int):
        return self.arm[k:]

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()


def wait(cond, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.01)


def still(states, tol: float = 0.01) -> bool:
    """Every joint velocity of these readings below ``tol`` rad/s (beyond the noise)."""
    return all(np.abs(v).max() < tol for _, _, v in states)


def stream(c: Client, joint: int, goal: float, ahead: float, seconds: float, stopped=None) -> None:
    """Forward commands at ~100 Hz, each ``ahead`` rad beyond the measured ``joint`` toward ``goal``,
    until the arm is there (or ``stopped()``, or ``seconds`` passed): the arm runs at its limit."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        q = c.q()
        d = goal - q[joint]
        if abs(d) < 0.01 or (stopped is not None and stopped()):
            return
        q[joint] += math.copysign(min(ahead, abs(d)), d)
        c.send(q)
        time.sleep(0.01)


@pytest.fixture
def ros(monkeypatch, tmp_path):
    domain = pick_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    log = tmp_path / "driver.log"
    stats = tmp_path / "stats.json"
    proc = subprocess.Popen([sys.executable, str(HERE / "arm_driver.py"), *ARGS, "--stats", str(stats)],
                            env=dict(os.environ, PYTHONUNBUFFERED="1"), stdout=open(log, "w"), stderr=subprocess.STDOUT)
    client = Client(ctx)
    yield {"proc": proc, "client": client, "log": log, "stats": stats}
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    client.close()
    ctx.try_shutdown()


def test_arm_driver_limits_stops_and_statistics(ros):
    c, proc = ros["client"], ros["proc"]
    wait(lambda: len(c.arm) > 20 and len(c.gripper) > 3 or proc.poll() is not None, STARTUP, "the driver's states")
    assert proc.poll() is None, ros["log"].read_text()[-3000:]
    np.testing.assert_allclose(c.q(), REST, atol=10 * NOISE)

    # ---- speed: commands always 0.45 rad ahead of joint 1 (inside the jump limit): it runs at its limit
    k = len(c.arm)
    stream(c, 0, 1.2, 0.45, 5.0)
    c.send(np.r_[1.2, c.q()[1:]])
    wait(lambda: still(c.arm[-5:]) and abs(c.q()[0] - 1.2) < 0.005, 5.0, "joint 1 at 1.2")
    run = c.since(k)
    t = np.array([s[0] for s in run])
    pos = np.array([s[1] for s in run])
    vel = np.array([s[2] for s in run])
    reported = np.abs(vel).max()
    # position differences over 20 readings (80 ms: the reading noise is ~0.002 rad/s there)
    diff = (np.abs(pos[20:] - pos[:-20]) / (t[20:] - t[:-20])[:, None]).max()
    print(f"speed: reported velocity max {reported:.4f}, from positions {diff:.4f} rad/s (limit {VMAX})")
    assert reported <= VMAX + 5 * NOISE and diff <= VMAX + 0.02
    assert reported > 0.95 * VMAX  # it did run at the limit: the limit is what held it
    assert np.all(np.diff(t) > 0)  # stamped with the sampling time, in order

    # ---- a jump beyond --jump-limit: protective stop; commands ignored for STOP_IGNORE s, then accepted
    here = c.q()
    c.send(np.r_[here[0] + 0.8, here[1:]])
    t_stop = time.monotonic()
    time.sleep(0.3)
    c.send(np.r_[here[0] + 0.1, here[1:]])   # ignored: the stop is not cleared yet
    time.sleep(0.6)
    assert abs(c.q()[0] - here[0]) < 0.002 and still(c.arm[-50:]), "the arm moved during the protective stop"
    time.sleep(max(0.0, t_stop + STOP_IGNORE + 0.3 - time.monotonic()))
    c.send(np.r_[here[0] + 0.1, here[1:]])   # accepted
    wait(lambda: abs(c.q()[0] - here[0] - 0.1) < 0.005, 3.0, "the command after the stop was cleared")
    assert "PROTECTIVE STOP (jump)" in ros["log"].read_text()

    # ---- the table: a trajectory to a posture above it, then the elbow bent down toward it
    over = c.q()
    over[1], over[3] = 0.9, -0.8
    c.send_trajectory(over, 2.0)
    wait(lambda: np.abs(c.q() - over).max() < 0.005 and still(c.arm[-5:]), 6.0, "the trajectory's end")
    k = len(c.arm)
    stream(c, 3, -2.3, 0.25, 4.0, stopped=lambda: len(c.arm) > k + 30 and still(c.arm[-15:]))
    time.sleep(0.3)
    held = c.q()
    assert held[3] > -2.0, "the elbow was not stopped"
    _, core, _ = arm_driver.build(arm_driver.parser().parse_args(ARGS))
    low, where = core.geometry.lowest(held)
    print(f"table: stopped at elbow {held[3]:.4f} rad, lowest point {low:.5f} m ({where}) over the table at 0")
    assert -2e-3 < low < 5e-3  # at first contact: on the table, not through it, not far above
    time.sleep(0.3)
    assert np.abs(c.q() - held).max() < 10 * NOISE and still(c.arm[-50:])  # held there

    # ---- the gripper: its own messages (~50 Hz), never mixed with the arm's
    assert not c.other, c.other[:3]
    g = c.gripper
    assert all(list(m.position) == [0.04] for m in g)
    rate = (len(g) - 1) / (g[-1].header.stamp.sec + g[-1].header.stamp.nanosec * 1e-9
                           - g[0].header.stamp.sec - g[0].header.stamp.nanosec * 1e-9)
    assert 30 < rate < 60, rate

    # ---- statistics: written while running, then at exit (line and JSON)
    s = json.loads(ros["stats"].read_text())
    assert s["running"] is True
    proc.send_signal(signal.SIGINT)
    proc.wait(15)
    out = ros["log"].read_text()
    s = json.loads(ros["stats"].read_text())
    print(json.dumps({k: s[k] for k in ("commands", "protective_stops", "ignored", "largest_speed", "max_speed")}))
    assert s["running"] is False
    assert s["commands"] == c.sent and s["trajectories"] == 1 and s["rejected"] == 0
    assert s["stops_jump"] == 1 and s["stops_table"] == 1 and s["protective_stops"] == 2
    assert s["table_contacts"] == 1 and -1e-3 < s["lowest_point"] < 1e-3
    assert 1 <= s["ignored_stop"] == s["ignored"] and s["freezes"] == 0
    assert s["speed_limit"] == VMAX and 0.95 * VMAX < s["largest_speed"] <= VMAX + 1e-9
    assert max(s["max_speed"]) == s["largest_speed"] and s["velocity_limits"] == [VMAX] * 7
    assert 0.7 < s["largest_setpoint_jump"] < 0.85
    m = re.search(r"real arm driver: (\d+) commands, 2 protective stops \(table 1, jump 1\), ignored (\d+), "
                  r"largest setpoint jump ([0-9.]+) rad, largest speed ([0-9.]+) rad/s \(limit 2.175\), "
                  r"table contacts 1", out)
    assert m, out[-2000:]
    assert int(m.group(1)) == c.sent and int(m.group(2)) == s["ignored"]
    assert out.count("PROTECTIVE STOP") == 2 and "PROTECTIVE STOP (table)" in out


def test_models_velocity_limits_and_rest():
    """URDF: the <limit velocity>; MJCF: pi rad/s each (or --velocity-limits), rest = keyframe home."""
    assert arm_driver.urdf_velocity_limits(MODEL) == {j: VMAX for j in JOINTS}
    _, core, info = arm_driver.build(arm_driver.parser().parse_args(
        ["--model", "config/robots/arm6.xml", "--effector", "tool"]))
    assert core.n == 6 and np.all(core.vmax == math.pi)
    np.testing.assert_allclose(core.q, [0, -2.0, 1.6, -1.1707963267948966, -1.5707963267948966, 0])
    assert 0.003 < info["calibration_gap_m"] < 0.03  # the true arm is not the model file's
    _, core, _ = arm_driver.build(arm_driver.parser().parse_args(
        ["--model", "config/robots/arm6.xml", "--effector", "tool", "--velocity-limits", "1", "2", "3", "3", "3", "3"]))
    assert core.vmax.tolist() == [1, 2, 3, 3, 3, 3]


def test_freeze_is_an_estop_not_a_protective_stop():
    """--freeze-at 0.2 --freeze-for 0.3: the arm stops 0.2 s after the first command, ignores commands
    for 0.3 s, then holds until the next command (ROS-free: the controller stepped by hand)."""
    _, core, _ = arm_driver.build(arm_driver.parser().parse_args(
        ARGS + ["--freeze-at", "0.2", "--freeze-for", "0.3"]))
    dt = 1 / 250
    goal = core.q.copy()
    goal[0] += 0.4
    core.command(goal, 0.0)
    for i in range(1, 50):       # 0.2 s: moving
        core.step(i * dt)
    moving = core.q[0]
    assert 0.05 < moving - REST[0] < 0.4
    for i in range(50, 60):
        core.step(i * dt)
    assert core.was_frozen and np.all(core.v == 0) and core.q[0] == pytest.approx(moving, abs=0.02)
    core.command(goal, 0.3)       # ignored: frozen
    at = core.q.copy()
    for i in range(60, 150):      # frozen until 0.5 s, then holding (no new command)
        core.step(i * dt)
    assert np.all(core.q == at) and not core.was_frozen
    core.command(goal, 150 * dt)
    for i in range(150, 400):
        core.step(i * dt)
    assert core.q[0] == pytest.approx(goal[0], abs=1e-3)
    s = core.stats()
    assert s["freezes"] == 1 and s["ignored_freeze"] == 1 and s["protective_stops"] == 0 and s["commands"] == 3
