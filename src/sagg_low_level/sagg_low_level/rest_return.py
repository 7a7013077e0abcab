"""The learner's return to the rest posture (ROS-free): one command straight to rest, or steps of at most
``max_joint_step`` from the newest measured posture (``rest_return`` 'stepped', what a real arm
gets), the request answered once the rest is reached or after a bounded number of steps."""
from __future__ import annotations

from typing import Callable

import numpy as np

from .learner import Robot, step_toward, stepped_move_limit


class RestReturn:
    """The commands of one return to rest at a time, for ``robot`` with steps of the learner
    parameter ``max_joint_step`` (read from ``params`` at every step).

    :meth:`command` gives the next command; :attr:`final` says whether its answer answers the
    learner's request (the rest reached, or ``limit`` steps sent: a joint that does not follow is
    then logged through ``warn``), else the next step follows from the measured posture.
    :attr:`steps` counts every stepped command sent (for /diagnostics)."""

    def __init__(self, robot: Robot, params: dict, warn: Callable[..., None]):
        self.robot, self.params, self.warn = robot, params, warn
        self.limit = stepped_move_limit(robot, params["max_joint_step"])
        self.steps = 0      # stepped rest commands sent in all
        self.count = 0      # steps of the return in progress
        self.final = True   # the command in flight answers the pending request

    def command(self, measured: np.ndarray, rest: np.ndarray, direct: bool) -> np.ndarray:
        """The next command toward ``rest`` from the ``measured`` posture: ``rest`` itself (within
        the limits) when ``direct``, else one step toward it."""
        robot = self.robot
        if direct:
            self.final = True
            return np.minimum(np.maximum(rest, robot.lower), robot.upper)
        target = step_toward(measured, rest, self.params["max_joint_step"], robot)
        self.steps += 1
        self.count += 1
        self.final = bool((target == rest).all())
        if not self.final and self.count >= self.limit:
            self.final = True
            worst = int(np.argmax(np.abs(rest - measured)))
            self.warn(f"return to rest incomplete after {self.count} steps of at most max_joint_step: "
                      f"{robot.joint_names[worst]} at {float(measured[worst]):.4f} rad, rest "
                      f"{float(rest[worst]):.4f}; going on from there", throttle_duration_sec=10.0)
        return target

    def not_resting(self) -> None:
        """A command that is no return to rest: its answer answers the request."""
        self.final = True

    def answered(self) -> None:
        """The request was answered: the next return starts counting anew."""
        self.count = 0
