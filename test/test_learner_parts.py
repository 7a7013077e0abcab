"""The learner node's ROS-free parts: its holds (one entry per cause, each released by its cause,
a reach's own hold not blocking the reach) and its return to rest (steps of at most
max_joint_step from the measured posture, the request answered at the rest or after the step
limit, a joint that does not follow named)."""
from __future__ import annotations

import numpy as np

from sagg_low_level.holds import FOLLOW, REACH, SERVICE, Holds
from sagg_low_level.learner import Robot
from sagg_low_level.rest_return import RestReturn


def test_holds_set_release_and_block():
    said = []
    h = Holds(lambda m: said.append(("warn", m)), lambda m: said.append(("info", m)))
    h.set(SERVICE, "paused by the /sagg/pause service")
    h.set(SERVICE, "paused by the /sagg/pause service")  # the same reason: said once
    h.set("driver", "no valid joint_states for more than 1 s")
    assert said == [("warn", "pausing: paused by the /sagg/pause service"),
                    ("warn", "pausing: no valid joint_states for more than 1 s")]
    assert h.blocking(reaching=False) and h.faults() == "no valid joint_states for more than 1 s"
    assert h.release("driver") and not h.release("driver")  # released once, by its cause
    assert said[-1] == ("info", "driver hold released")
    h.release(SERVICE)
    assert said[-1] == ("info", "service hold released: resuming") and not h.blocking(reaching=False)
    h.set(REACH, "reaching a goal")
    assert h.blocking(reaching=False) and not h.blocking(reaching=True) and h.faults() == ""
    # a pause holds learning, not a reach asked for meanwhile (the evaluation on the robot); a fault does
    h.set(SERVICE, "paused by the /sagg/pause service")
    assert h.blocking(reaching=False) and not h.blocking(reaching=True)
    h.set(FOLLOW, "the arm does not follow its setpoints")
    assert h.blocking(reaching=True) and h.faults() == "the arm does not follow its setpoints"


def test_the_return_to_rest_steps_from_the_measured_posture():
    robot = Robot(["a", "b"], [-2.0, -2.0], [2.0, 2.0], [0.0, 0.0])
    warned = []
    params = {"max_joint_step": 0.25}
    r = RestReturn(robot, params, lambda m, **_: warned.append(m))
    rest = robot.rest.copy()
    measured = np.array([1.0, -0.3])
    targets = []
    while True:
        t = r.command(measured, rest, direct=False)
        assert np.abs(t - measured).max() <= 0.25 + 1e-12  # never more than a step from the measured posture
        targets.append(t)
        if r.final:
            break
        measured = t  # the arm followed
    np.testing.assert_array_equal(targets[-1], rest)
    assert len(targets) == 4 and r.steps == 4 and not warned
    r.answered()
    # a joint that does not follow: the request is answered after the step limit, the joint named
    stuck = np.array([1.0, 0.0])
    for _ in range(r.limit):
        r.command(stuck, rest, direct=False)
    assert r.final and "a at 1.0000 rad" in warned[-1]
    # straight to rest (only a simulator listens), clipped to the limits
    assert r.command(stuck, np.array([3.0, 0.0]), direct=True).tolist() == [2.0, 0.0] and r.final


def test_the_detours_of_a_refused_return_to_rest():
    """When the scene refuses the straight step to rest: partial returns, the distal joints first
    then the proximal ones, each one step of at most max_joint_step, none that stays put."""
    from sagg_low_level.learner import Robot
    from sagg_low_level.rest_return import detours

    robot = Robot(["a", "b", "c"], np.full(3, -2.0), np.full(3, 2.0), np.zeros(3))
    measured = np.array([1.0, 0.3, -0.2])
    got = detours(measured, robot.rest, 0.5, robot)
    # distal first: joints 1.. then 2.. to rest; proximal first: joints ..1 then ..0 to rest
    expected = [[1.0, 0.0, 0.0], [1.0, 0.3, 0.0], [0.5, 0.0, -0.2], [0.5, 0.3, -0.2]]
    assert np.allclose(got, expected)
    assert all(np.abs(t - measured).max() <= 0.5 + 1e-12 for t in got)
    # a joint already at rest gives no candidate that stays put
    assert all(np.abs(t - measured).max() > 0 for t in detours(np.array([0.0, 0.0, 0.3]), robot.rest, 0.5, robot))
