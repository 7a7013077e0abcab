"""Evaluation of the learned inverse model (paper Sec. 3.7). ROS-free.

Each test goal is reached from the rest posture with the frozen model: reaching steps only, no
exploration, no learning; the score is the final effector-goal distance. Evaluation runs on its own
simulator instance so the learning run is untouched, and is never counted as learning budget.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

from .learner import EvolvingContextLearner, safe_target, timeout_budget
from .local_model import desired_displacement


class ReachingRobot(Protocol):
    def reset(self) -> tuple[np.ndarray, np.ndarray]: ...
    def command(self, alpha_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def reach_frozen(learner: EvolvingContextLearner, robot: ReachingRobot, goal: np.ndarray) -> float:
    """Reach ``goal`` from rest with the learner's current model, without learning (Sec. 3.7).

    Budget: ``ceil(eval.timeout_factor × D(y_rest, goal) / v)`` steps; stops early within
    ``eval.tolerance``. Returns the final distance ``D(goal, y_f)``.
    """
    p = learner.p
    alpha, y = robot.reset()
    budget = timeout_budget(float(np.linalg.norm(goal - y)), learner.v, p["eval.timeout_factor"])
    for _ in range(budget):
        if float(np.linalg.norm(goal - y)) <= p["eval.tolerance"]:
            break
        dalpha = learner.reach_step(alpha, desired_displacement(y, goal, learner.v))
        if dalpha is None:
            break
        alpha, y = robot.command(safe_target(alpha, alpha + dalpha, p["max_joint_step"], learner.robot))
    return float(np.linalg.norm(goal - y))


def evaluate(learner: EvolvingContextLearner, robot: ReachingRobot, goals: np.ndarray) -> np.ndarray:
    """Final distances for every test goal (paper Sec. 3.7: mean and median are reported)."""
    return np.array([reach_frozen(learner, robot, g) for g in np.asarray(goals, dtype=float)])
