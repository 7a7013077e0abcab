"""Competence of a reaching attempt (paper Sec. 2.4.1, 3.5 and 4.3). ROS-free."""
from __future__ import annotations

import math
from typing import Callable

import numpy as np


def competence(goal, reached, start, eps_c: float, scale=None) -> float:
    """Normalised competence C(y_g, y_f, y_start) of paper Sec. 3.5 (equation "C").

    ``C = -D(y_g, y_f) / D(y_start, y_g)`` with two edge cases from the text:
    ``C = 0`` when ``D(y_start, y_g) < eps_c`` (the goal is too close to the start) and
    ``C = -1`` when ``D(y_g, y_f) > D(y_start, y_g)`` (the effector moved away from the goal).
    ``C`` is therefore in [-1, 0].

    ``scale`` (optional, one positive number per task dimension) divides each dimension before
    distances are taken: the "rescaled in [0;1]" variant of Sec. 4.3, where ``scale`` is the
    extent of the task space in each dimension so every dimension weighs the same.

    Parameters
    ----------
    goal : array_like, shape (m,)
        The goal y_g; m = task-space dimensions.
    reached : array_like, shape (m,)
        The effector's final position y_f.
    start : array_like, shape (m,)
        The effector's position y_start when the attempt began.
    eps_c : float
        ε_C: distance D(y_start, y_g) under which the competence is 0 (in rescaled units when
        ``scale`` is given).
    scale : array_like, shape (m,), optional
        Positive divisor of each task dimension (None: distances in task units).

    Returns
    -------
    float
        The competence C, in [-1, 0].
    """
    return competence_toward(goal, start, eps_c, scale)(reached)


def competence_toward(goal, start, eps_c: float, scale=None) -> Callable[[np.ndarray], float]:
    """``reached -> competence(goal, reached, start, eps_c, scale)``, the goal's part (its distance
    to the start) computed once: for the many outcomes of one goal.

    Parameters
    ----------
    goal : array_like, shape (m,)
        The goal y_g; m = task-space dimensions.
    start : array_like, shape (m,)
        The effector's position y_start when the attempt began.
    eps_c : float
        ε_C of :func:`competence`.
    scale : array_like, shape (m,), optional
        Positive divisor of each task dimension (None: distances in task units).

    Returns
    -------
    callable
        ``of(reached) -> float``: ``reached`` array_like of shape (m,), the effector's position
        y_f; returns the competence C in [-1, 0].
    """
    g = np.asarray(goal, dtype=float)
    s = np.asarray(start, dtype=float)
    sc = None
    if scale is not None:
        sc = np.asarray(scale, dtype=float)
        g, s = g / sc, s / sc
    d_start = math.sqrt(float(np.dot(g - s, g - s)))

    def of(reached) -> float:
        if d_start < eps_c:
            return 0.0
        f = np.asarray(reached, dtype=float)
        if sc is not None:
            f = f / sc
        d_final = math.sqrt(float(np.dot(g - f, g - f)))
        if d_final > d_start:
            return -1.0
        return -d_final / d_start

    return of


def gamma(c: float, eps_sim: float) -> float:
    """Competence measure Γ of a terminated attempt (paper Sec. 2.4.1, equation "Γ").

    ``Γ = C`` if ``C <= eps_sim`` (not reached), else ``0`` (reached: maximal competence).
    ``eps_sim < 0`` is the tolerance: ``C > eps_sim`` means the goal counts as reached.

    Parameters
    ----------
    c : float
        Competence C of the attempt (:func:`competence`), in [-1, 0].
    eps_sim : float
        ε_sim < 0, the reaching tolerance.

    Returns
    -------
    float
        Γ: ``c`` when the goal was not reached, else 0.0.
    """
    return float(c) if c <= eps_sim else 0.0


def is_reached(c: float, eps_sim: float) -> bool:
    """The reaching test of Sec. 2.4.1: ``C > eps_sim``.

    Parameters
    ----------
    c : float
        Competence C (:func:`competence`), in [-1, 0].
    eps_sim : float
        ε_sim < 0, the reaching tolerance.

    Returns
    -------
    bool
        True when the goal counts as reached.
    """
    return c > eps_sim
