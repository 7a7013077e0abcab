"""Safety on the command path.

- Property tests (hypothesis): ``safe_target`` and the learner coroutine never produce a command
  outside the joint limits, nor one that moves a joint more than ``max_joint_step`` from the current
  posture (a return to rest is not a micro-action and is only limit-checked).
- The learner node against a driver in this process: it pauses, and says so, when joint states go
  stale and resumes when they return; /sagg/pause pauses and resumes; bad joint states are counted
  on /diagnostics and never reach the samples; every command it sent respected the limits.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from hypothesis import given, settings, strategies as st
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import SetBool

from sagg_low_level.learner import SCHEMA, Command, EvolvingContextLearner, GoalRequest, Robot, safe_target
from sagg_sim_bridge.arm import forward_kinematics

import test_nodes_graph
from test_nodes_graph import STARTUP_TIMEOUT, Collector, logs, qos, start

ros_env = test_nodes_graph.ros_env  # the fixture: a private ROS domain per test

LIMIT = 1.2
LENGTHS = np.array([10.0, 8.0, 6.0])
finite = st.floats(-1e6, 1e6, allow_nan=False)


@settings(max_examples=500, deadline=None)
@given(n=st.integers(1, 6), data=st.data(), max_step=st.floats(1e-4, 3.0))
def test_safe_target_respects_limits_and_step(n, data, max_step):
    lower = np.array(data.draw(st.lists(st.floats(-3.0, 0.0), min_size=n, max_size=n)))
    upper = lower + np.array(data.draw(st.lists(st.floats(1e-3, 3.0), min_size=n, max_size=n)))
    robot = Robot([f"j{i}" for i in range(n)], lower, upper, (lower + upper) / 2)
    alpha = lower + (upper - lower) * np.array(data.draw(st.lists(st.floats(0.0, 1.0), min_size=n, max_size=n)))
    target = np.array(data.draw(st.lists(finite, min_size=n, max_size=n)))
    out = safe_target(alpha, target, max_step, robot)
    assert np.all(out >= lower) and np.all(out <= upper)
    assert np.all(np.abs(out - alpha) <= max_step * (1 + 1e-12) + 1e-12)


def core_params(**over) -> dict:
    p = {q.name: q.default for q in SCHEMA}
    p.update({"task_space.lower": [-30.0, -30.0], "task_space.upper": [30.0, 30.0]})
    p.update(over)
    return p


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), strategy=st.sampled_from(["sagg-riac", "actuator-random", "actuator-riac"]),
       max_step=st.floats(0.01, 1.0), noise=st.floats(0.0, 0.5), sensor=st.floats(0.0, 0.05))
def test_learner_commands_stay_within_limits_and_step(seed, strategy, max_step, noise, sensor):
    """Drive the coroutine for 150 commands with an arm that executes commands badly (motor noise,
    clipped to its limits, sensor noise) and random goals: every command obeys the limits and, for
    a micro-action, the step from the posture the learner believes it is at."""
    rng = np.random.default_rng(seed)
    lower, upper = np.full(3, -LIMIT), np.full(3, LIMIT)
    robot = Robot(["a", "b", "c"], lower, upper, np.array([0.2, -0.1, 0.3]))
    learner = EvolvingContextLearner(core_params(strategy=strategy, seed=seed, max_joint_step=max_step), robot, 2)
    coro = learner.run()
    q = robot.rest.copy()
    req = next(coro)
    commands = 0
    while commands < 150:
        if isinstance(req, GoalRequest):
            req = coro.send((commands + 1, rng.uniform(-30.0, 30.0, 2)))
            continue
        if isinstance(req, Command):
            target = np.asarray(req.target)
            assert np.all(target >= lower) and np.all(target <= upper), target
            if req.kind != "reset":
                assert np.all(np.abs(target - learner.alpha) <= max_step + 1e-9)
            q = np.clip(q + (target - q) * (1 + noise * rng.standard_normal(3)), lower, upper)
            commands += 1
        obs = np.clip(q + sensor * rng.standard_normal(3), lower, upper)
        req = coro.send((obs, forward_kinematics(obs[None, :], LENGTHS)[0]))


# ------------------------------------------------------------------------------ node level
class StepDriver:
    """A position-controlled arm in the test process: executes each command at once, publishes the
    state after it (stamped then) and re-publishes it every 0.2 s with the same stamp, like the
    lockstep bridge (unless ``silent``); records every command it received with the posture it
    started from."""

    def __init__(self, node: Node):
        self.node = node
        self.q = np.array([0.2, -0.1, 0.3])
        self.silent = False
        self.stamp = node.get_clock().now().to_msg()
        self.log: list[tuple[np.ndarray, np.ndarray]] = []
        self.js_pub = node.create_publisher(JointState, "/joint_states", qos(100))
        self.tip_pub = node.create_publisher(PointStamped, "/tip_position", qos(100))
        node.create_subscription(Float64MultiArray, "/forward_position_controller/commands", self.on_cmd, qos(100))
        node.create_timer(0.2, self.publish)

    def on_cmd(self, msg) -> None:
        target = np.array(msg.data)
        self.log.append((self.q.copy(), target))
        self.q = np.clip(target, -LIMIT, LIMIT)
        self.stamp = self.node.get_clock().now().to_msg()
        self.publish()

    def publish(self, names=None, position=None) -> None:
        if self.silent and names is None:
            return
        stamp = self.stamp if names is None else self.node.get_clock().now().to_msg()
        js = JointState()
        js.header.stamp = stamp
        js.name = names if names is not None else ["a", "b", "c"]
        js.position = position if position is not None else self.q.tolist()
        pt = PointStamped()
        pt.header.stamp = stamp
        tip = forward_kinematics(self.q[None, :], LENGTHS)[0]
        pt.point.x, pt.point.y = float(tip[0]), float(tip[1])
        self.js_pub.publish(js)
        if names is None:
            self.tip_pub.publish(pt)


def params_file(path: Path, max_step: float) -> Path:
    data = {
        "/**": {"ros__parameters": {"seed": 1, "strategy": "actuator-random",
                                    "task_space": {"lower": [-30.0, -30.0], "upper": [30.0, 30.0]}}},
        "sagg_learner": {"ros__parameters": {
            "joints": ["a", "b", "c"], "joint_limits": {"lower": [-LIMIT] * 3, "upper": [LIMIT] * 3},
            "rest_posture": [0.2, -0.1, 0.3], "max_joint_step": max_step, "joint_state_timeout": 0.6,
            "min_sample_subscribers": 1, "publish_batch": 1}},
    }
    path.write_text(yaml.safe_dump(data))
    return path


def test_learner_pauses_on_stale_driver_and_pause_service_and_rejects_bad_states(ros_env, tmp_path):
    max_step = 0.05
    params = params_file(tmp_path / "params.yaml", max_step)
    col = Collector(ros_env["ctx"])
    driver = StepDriver(col.node)
    diags: list[DiagnosticArray] = []
    col.node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, qos(100))
    pause = col.node.create_client(SetBool, "/sagg/pause")
    learner = start(ros_env, "learner", params, tmp_path)
    assert col.spin_until(lambda: len(driver.log) >= 40, STARTUP_TIMEOUT, [learner]), logs(tmp_path)

    def paused_for(text: str) -> bool:
        return col.status is not None and col.status.paused and text in col.status.pause_reason

    # 1. the driver goes silent: the learner pauses and says why; no command while paused
    driver.silent = True
    assert col.spin_until(lambda: paused_for("no valid joint_states"), 10.0, [learner]), logs(tmp_path)
    n = len(driver.log)
    col.spin_for(1.0)
    assert len(driver.log) <= n + 1
    driver.silent = False  # it comes back: the learner resumes
    assert col.spin_until(lambda: len(driver.log) >= n + 20, 20.0, [learner]), logs(tmp_path)

    # 2. the pause service
    fut = pause.call_async(SetBool.Request(data=True))
    assert col.spin_until(lambda: fut.done(), 10.0, [learner]) and fut.result().success
    assert col.spin_until(lambda: paused_for("/sagg/pause"), 10.0, [learner])
    n = len(driver.log)
    col.spin_for(1.0)
    assert len(driver.log) <= n + 1
    fut = pause.call_async(SetBool.Request(data=False))
    assert col.spin_until(lambda: fut.done(), 10.0, [learner])
    assert col.spin_until(lambda: len(driver.log) >= n + 20, 20.0, [learner]), logs(tmp_path)

    # 3. bad joint states between good ones: counted on /diagnostics, never in a sample
    for _ in range(5):
        driver.publish(names=["a", "b", "c"], position=[float("nan"), 0.0, 0.0])
        driver.publish(names=["a", "b"], position=[0.0, 0.0])
        col.spin_for(0.05)
    n = len(driver.log)
    assert col.spin_until(lambda: len(driver.log) >= n + 20, 20.0, [learner]), logs(tmp_path)

    def rejected(kind: str) -> int:
        for d in reversed(diags):
            for s in d.status:
                if s.hardware_id == "sagg_learner":
                    return int({v.key: v.value for v in s.values}.get(f"rejected.{kind}", 0))
        return 0

    assert col.spin_until(lambda: rejected("joint_states.non_finite") >= 5 and rejected("joint_states.names") >= 5,
                          10.0, [learner]), [d.status for d in diags[-1:]]
    assert learner.poll() is None  # never crashed
    for s in col.samples:
        assert np.all(np.isfinite(s.alpha)) and np.all(np.isfinite(s.delta_alpha)) and np.all(np.isfinite(s.delta_y))
    # 4. every command the learner sent: within the limits; a micro-action within max_joint_step of
    # the posture the arm was at (returns to rest are the only larger moves, and go to rest)
    rest = np.array([0.2, -0.1, 0.3])
    for q0, target in driver.log:
        assert np.all(np.abs(target) <= LIMIT)
        assert np.all(np.abs(target - q0) <= max_step + 1e-9) or np.array_equal(target, rest)
