"""The learner's return to the rest posture (ROS-free): one command straight to rest, or steps of at most
``max_joint_step`` from the newest measured posture (``rest_return`` 'stepped', what a real arm
gets), the request answered once the rest is reached or after a bounded number of steps. When the
scene refuses the straight step, :func:`detours` are the partial returns tried instead."""
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


def detours(measured: np.ndarray, rest: np.ndarray, max_step: float, robot: Robot) -> list[np.ndarray]:
    """Partial returns to rest, for when the scene refuses the straight step: the distal joints
    first (joints k..n-1 to rest, the others kept; k from 1 up: the wrist before the elbow, as an
    arm folds away from a table), then the proximal ones first; each one step of at most
    ``max_step`` (:func:`step_toward`). Our choice, no planner: the caller takes the first one the
    scene allows; the return goes on from there.

    Parameters
    ----------
    measured, rest : ndarray, shape (n,)
        The measured posture and the rest posture.
    max_step : float
        Largest joint motion per command (``max_joint_step``).
    robot : Robot
        Gives the joint limits.

    Returns
    -------
    list of ndarray, shape (n,)
        The candidate commands in the order to try, none equal to ``measured``.
    """
    n = len(rest)
    partial = []
    for k in range(1, n):
        t = measured.copy()
        t[k:] = rest[k:]
        partial.append(t)
    for k in range(n - 1, 0, -1):
        t = measured.copy()
        t[:k] = rest[:k]
        partial.append(t)
    steps = [step_toward(measured, t, max_step, robot) for t in partial]
    return [t for t in steps if float(np.abs(t - measured).max()) > 1e-9]
