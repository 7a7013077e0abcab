"""The fixed-context evaluation with the model's work batched across test goals. ROS-free.

:func:`evaluate_fixed_batch` returns exactly what
:func:`sagg_low_level.fixed_context.evaluate_fixed` returns (the same floats): the frozen model's
synergy θ_g of every test goal (:func:`inverses`, row for row ``learner.inverse(goal)``) is computed
first, with the goals' outcome-neighbour searches batched (one query of the learner's exact index
``y_index``, the single search's answers); then the θ_g are executed one goal after
the other, in goal order, exactly as ``evaluate_fixed`` executes them (the inverse model is frozen
and draws no random number, so computing all θ_g first changes nothing the simulator sees).
"""
from __future__ import annotations

from typing import Callable

import numpy as np


def inverses(learner, goals: np.ndarray) -> list[np.ndarray | None]:
    """``[learner.inverse(g) for g in goals]`` (reaching phase of Sec. 4.4.1): the l nearest
    outcomes L of every goal in one batch search, then the learner's own step from L
    (``_inverse_from``: the θ-neighbour sets M_i, the least-spread set, the local model)."""
    goals = np.asarray(goals, dtype=float)
    if len(learner) < learner.min_samples:
        return [None] * len(goals)
    gs = np.array([learner.scale_y(g) for g in goals]).reshape(len(goals), -1)
    seeds = learner.y_index.query(gs, learner.l_nb)                  # L per goal
    return [learner._inverse_from(g, row) for g, row in zip(gs, seeds)]


def evaluate_fixed_batch(learner, run_theta: Callable[[np.ndarray], np.ndarray | None],
                         goals: np.ndarray) -> np.ndarray:
    """:func:`~sagg_low_level.fixed_context.evaluate_fixed`, the inverse model's work batched."""
    goals = np.asarray(goals, dtype=float)
    if "inverse" in vars(learner):  # replaced on the instance: only it knows the model
        thetas = [learner.inverse(g) for g in goals]
    else:
        thetas = inverses(learner, goals)
    out = []
    for g, theta in zip(goals, thetas):
        y = None if theta is None else run_theta(theta)
        if y is None:
            y = learner.y_rest
        out.append(float(np.linalg.norm(g - np.asarray(y, dtype=float))))
    return np.array(out)
