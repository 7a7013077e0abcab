"""Tests of the kinematic robot model in sagg_common: sagg_common.robot_model's
RobotModel (what the bridge's model arm is built on) and TaskFromJoints, the learner's task point
of a measured posture (``task_source: model``): joint-order mapping, the error for a joint that is
not the model's, and agreement with the simulated arm's observe() on the example arms."""
from __future__ import annotations

import math

import numpy as np
import pytest

from sagg_common.params import ConfigError
from sagg_common.robot_model import RobotModel, TaskFromJoints
from sagg_sim_bridge.arms import arm_spec_from_params, make_arm_sim
from test_model_arm import CONFIG, params, write_urdf

REST7 = [0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4]
# (model file, effector, rest_posture) of the example arms (config/arm7_urdf.yaml, config/arm6_mjcf.yaml)
EXAMPLES = {"arm7": ("robots/arm7.urdf", "tool0", REST7), "arm6": ("robots/arm6.xml", "tool", [])}


def robot(name: str) -> RobotModel:
    path, effector, rest = EXAMPLES[name]
    return RobotModel.load(str(CONFIG / path), effector, rest=tuple(rest))


def sim(name: str):
    path, effector, rest = EXAMPLES[name]
    kw = {"rest_posture": rest} if rest else {}
    return make_arm_sim(arm_spec_from_params(params(model=path, effector=effector, **kw), str(CONFIG)), 0)


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_task_point_equals_the_simulated_arms_observation(name):
    """For random postures commanded to the bridge's simulator, the learner's point of the measured
    joints (in a shuffled order) is the simulator's observed effector, bit for bit; so are
    RobotModel.task_point and, to float rounding, the batched task_points."""
    s, r = sim(name), robot(name)
    assert r.joint_names == tuple(s.joint_names)
    rng = np.random.default_rng(7)
    order = rng.permutation(len(r.joint_names))
    assert not np.array_equal(order, np.arange(len(order)))
    task = TaskFromJoints(r, [r.joint_names[i] for i in order])
    alphas, ys = [], []
    for q in rng.uniform(s.lower, s.upper, (20, len(s.lower))):
        alpha, y = s.command(q)
        assert y.shape == (3,)
        np.testing.assert_array_equal(task.point(alpha[order]), y)
        np.testing.assert_array_equal(r.task_point(alpha), y)
        alphas.append(alpha)
        ys.append(y)
    np.testing.assert_allclose(r.task_points(np.array(alphas)), np.array(ys), rtol=0, atol=1e-12)


def test_learner_order_maps_to_the_model_joints():
    """The same posture given in the model's order and in a reversed learner order gives the same
    point; the reversed values read in the model's order give another point (the order matters)."""
    r = robot("arm7")
    names = list(r.joint_names)
    model_order, reversed_order = TaskFromJoints(r, names), TaskFromJoints(r, names[::-1])
    a = np.random.default_rng(1).uniform(r.lower, r.upper)
    np.testing.assert_array_equal(reversed_order.point(a[::-1].copy()), model_order.point(a))
    assert not np.allclose(model_order.point(a[::-1].copy()), model_order.point(a))


def test_joints_not_given_are_held_at_rest():
    """A learner commanding some of the model's joints: the others stay at the rest posture."""
    r = robot("arm6")
    names = list(r.joint_names)
    a = np.random.default_rng(2).uniform(r.lower, r.upper)
    full = r.rest.copy()
    full[[1, 2]] = a[[1, 2]]
    np.testing.assert_array_equal(TaskFromJoints(r, [names[2], names[1]]).point(a[[2, 1]].copy()),
                                  r.task_point(full))


def test_a_joint_that_is_not_the_models_is_one_clear_error(tmp_path):
    r = robot("arm6")
    with pytest.raises(ConfigError) as err:
        TaskFromJoints(r, list(r.joint_names[:5]) + ["wrist_9"])
    text = str(err.value)
    assert text.startswith("parameter joints:") and "'wrist_9'" in text and "\n" not in text
    assert str(list(r.joint_names)) in text  # the model's joint names
    # a joint of the model that does not move the effector (j3 is beyond the body l2)
    urdf = write_urdf(tmp_path / "arm.urdf")
    r2 = RobotModel.load(str(urdf), "l2", rest=(0.1, 0.2))
    assert r2.moving_joints == ("j1", "j2")
    with pytest.raises(ConfigError, match=r"^parameter joints: got \['j1', 'j3'\].*\['j1', 'j2'\]"):
        TaskFromJoints(r2, ["j1", "j3"])
    with pytest.raises(ConfigError, match=r"^parameter joints: got \['j1', 'j1'\]"):
        TaskFromJoints(r2, ["j1", "j1"])


def test_robot_model_is_what_the_bridge_simulates():
    """The bridge's model arm is the RobotModel of its file: joints, limits, rest, base point, reach."""
    r, s = robot("arm7"), sim("arm7")
    assert isinstance(s.arm, RobotModel)
    np.testing.assert_array_equal(r.lower, s.lower)
    np.testing.assert_array_equal(r.upper, s.upper)
    np.testing.assert_array_equal(r.rest, REST7)
    np.testing.assert_array_equal(r.base_point(), s.spec.base_point())
    assert r.reach == s.spec.reach()
    assert len(r.notices) == 1 and "8 mesh file(s) not found" in r.notices[0]  # kinematic loading
