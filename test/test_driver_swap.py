"""Driver swap, proven: the unchanged learner and goal generator learn against a driver that is not
the MuJoCo bridge (test/fake_driver.py: a numpy planar arm publishing joint states at a fixed rate
with latency and noise, joints in reversed order under other names, no lockstep).

Only the parameter file changes (joints, limits, rest posture, observation timing), as it would for
a real arm; the learner's samples are collected from /sagg/sample and the frozen model is evaluated
on 30 reachable goals, before and after learning.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import yaml

from sagg_common.params import node_params, read_config
from sagg_low_level.evaluate import evaluate
from sagg_low_level.learner import EvolvingContextLearner, SCHEMA as LEARNER_CORE_SCHEMA
from sagg_low_level.node import robot_from_params, SCHEMA as LEARNER_SCHEMA
from sagg_sim_bridge.arm import forward_kinematics

import test_nodes_graph
from test_nodes_graph import RUN_TIMEOUT, STARTUP_TIMEOUT, Collector, logs, start, stop

ros_env = test_nodes_graph.ros_env  # the fixture: a private ROS domain per test

HERE = Path(__file__).resolve().parent
LENGTHS = [20.0, 15.0, 10.0]
REST = [0.3, 0.3, 0.3]
LIMIT = np.pi / 2
RATE, LATENCY = 250.0, 0.008
STEPS = 600
LEARNING_FACTOR = 0.35  # the mean test error must fall below this fraction of the initial one


class KinematicArm:
    """The driver's arm without timing or noise, for evaluating the frozen model."""

    def __init__(self):
        self.q = np.array(REST)

    def reset(self):
        self.q = np.array(REST)
        return self.q.copy(), forward_kinematics(self.q[None, :], np.array(LENGTHS))[0]

    def command(self, target):
        self.q = np.clip(np.asarray(target, dtype=float), -LIMIT, LIMIT)
        return self.q.copy(), forward_kinematics(self.q[None, :], np.array(LENGTHS))[0]


def params_file(path: Path) -> Path:
    data = {
        "/**": {"ros__parameters": {"seed": 3, "strategy": "sagg-riac",
                                    "task_space": {"lower": [-20.0, -50.0], "upper": [50.0, 50.0]}}},
        "sagg_goal_generator": {"ros__parameters": {"g_max": 30, "min_goal_subscribers": 0}},
        "sagg_learner": {"ros__parameters": {
            "joints": ["axis_0", "axis_1", "axis_2"],
            "joint_limits": {"lower": [-LIMIT] * 3, "upper": [LIMIT] * 3},
            "rest_posture": REST,
            "v": 2.0, "q": 10, "subgoals": 3,
            # a real-time driver: the state must be sampled after the command arrived (latency plus
            # one control period), and counts as settled once every joint velocity is ~0
            "observation_delay": LATENCY + 2.0 / RATE,
            "settle_velocity": 0.05,
            "max_micro_actions": STEPS,
            "min_sample_subscribers": 1,
        }},
    }
    path.write_text(yaml.safe_dump(data))
    return path


def test_learner_learns_against_a_non_mujoco_realtime_driver(ros_env, tmp_path):
    params = params_file(tmp_path / "params.yaml")
    log = open(tmp_path / "fake_driver.log", "w")
    driver = subprocess.Popen([sys.executable, str(HERE / "fake_driver.py"), "--dof", "3",
                               "--lengths", *map(str, LENGTHS), "--rest", *map(str, REST),
                               "--rate", str(RATE), "--latency", str(LATENCY), "--seed", "1"],
                              env=ros_env["env"], stdout=log, stderr=subprocess.STDOUT)
    ros_env["procs"].append(driver)
    col = Collector(ros_env["ctx"])
    procs = [start(ros_env, s, params, tmp_path) for s in ("goal_generator", "learner")] + [driver]
    ok = col.spin_until(lambda: col.stopped() and len(col.samples) >= STEPS, STARTUP_TIMEOUT + RUN_TIMEOUT, procs)
    assert ok, f"{len(col.samples)} samples\n{logs(tmp_path)}"
    stop(driver)
    assert "fake driver:" in (tmp_path / "fake_driver.log").read_text()

    # the frozen model, rebuilt from the published samples, before and after learning
    lp = node_params(read_config(params), "sagg_learner", LEARNER_SCHEMA)
    core = {p.name: lp[p.name] for p in LEARNER_CORE_SCHEMA}
    learner = EvolvingContextLearner(core, robot_from_params(lp), 2)
    rng = np.random.default_rng(7)
    goals = forward_kinematics(rng.uniform(-LIMIT, LIMIT, (30, 3)), np.array(LENGTHS))
    before = evaluate(learner, KinematicArm(), goals)
    for s in sorted(col.samples, key=lambda s: s.index):
        learner.memory.add(np.array(s.alpha), np.array(s.delta_alpha), np.array(s.delta_y))
    assert len(learner.memory) == STEPS
    after = evaluate(learner, KinematicArm(), goals)
    print(f"driver swap: mean test error {before.mean():.2f} before, {after.mean():.2f} after {STEPS} micro-actions")
    assert after.mean() < LEARNING_FACTOR * before.mean(), (before.mean(), after.mean())
    assert len(col.goals) >= 2  # the goal generator took part
