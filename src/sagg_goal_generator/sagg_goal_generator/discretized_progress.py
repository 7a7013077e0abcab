"""``discretized-progress``: competence progress on a fixed grid of Y. ROS-free.

The grid interest model of explauto (Moulin-Frier, Rouanet & Oudeyer; flowersteam/explauto,
``explauto/interest_model/discrete_progress.py``: ``DiscretizedProgress`` and ``DiscreteProgress``,
default configuration ``x_card = 400, win_size = 10, eps_random = 0.3``), whose defaults are the
parameters' defaults here:

- Y is cut into ``floor(cells ** (1 / dim))`` equal bins per dimension (:func:`grid_shape`);
- every cell keeps a window of its last ``window`` normalised competences, filled with 0 (the least
  competence) at the start;
- a cell's progress is the mean of the older half of its window minus the mean of the newer half
  (:func:`cell_progress`);
- a goal's cell is uniform with probability ``random_share``, else chosen in proportion to the
  absolute progress of the cells, uniform when every progress is 0 (:func:`cell_probabilities`);
  the goal is uniform in its cell;
- novelty bonus: a reached point in a cell whose window sums to 0 gives that cell the maximal
  competence (explauto: "if novel cell is reached, give it competence").

Competence: the paper's C in [-1, 0] normalised to [0, 1] as explauto normalises its own
(``(c - c_min) / (c_max - c_min)``), i.e. ``C + 1``. Where our reports differ from explauto's update
(which sees the goal and the reached point together, and credits the goal's cell only when the
reached point falls in it): a goal report carries the goal and its competence only, so every goal's
competence goes to the goal's cell (our choice: C already measures how far the goal was missed);
the novelty bonus is given by the reached-point and exploration reports (every micro-action's
outcome, sent whatever ``count_reached`` says).
"""
from __future__ import annotations

import math

import numpy as np

from sagg_common.params import ConfigError, Param, Schema
from sagg_common.regions import proportional
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED
from sagg_common.rng import choice_index

from .teacher import Teacher
from .modes import MODE_GLOBAL, MODE_REGION

NAME = "discretized-progress"
P = "discretized_progress."

SCHEMA: Schema = (
    Param(P + "cells", "int", 400,
          "Number of grid cells aimed at: floor(cells^(1/dim)) bins per dimension of Y (explauto "
          "x_card = 400: 20 x 20 in 2-D, 7 x 7 x 7 in 3-D). cells x window at most 10^7 (the windows' "
          "memory).", low=1, high=1_000_000),
    Param(P + "window", "int", 10,
          "Competences kept per cell; progress compares the older half with the newer (explauto "
          "win_size = 10).", low=2, high=10_000),
    Param(P + "random_share", "float", 0.3,
          "Probability of a uniform cell instead of one chosen by progress (explauto eps_random = 0.3).",
          low=0.0, high=1.0),
    Param(P + "novelty_bonus", "bool", True,
          "A reached point in a cell whose window sums to 0 gives that cell the maximal competence "
          "(explauto's novelty bonus)."),
)


def grid_shape(cells: int, dim: int) -> tuple[int, ...]:
    """Bins per dimension: ``floor(cells ** (1 / dim))`` each (explauto ``DiscretizedProgress``:
    ``int(x_card ** (1. / len(expl_dims)))``); the root is taken exactly (integer check), so 1000
    cells in 3-D give 10 bins, not 9 from a rounding error.

    Parameters
    ----------
    cells : int
        Number of cells aimed at, >= 1.
    dim : int
        Dimensions of Y (m), >= 1.

    Returns
    -------
    tuple of int, length dim
        b bins in every dimension, the largest b with ``b ** dim <= cells`` (at least 1).
    """
    b = max(1, int(math.floor(cells ** (1.0 / dim))))
    while (b + 1) ** dim <= cells:
        b += 1
    while b > 1 and b ** dim > cells:
        b -= 1
    return (b,) * dim


def cell_progress(window: np.ndarray) -> float:
    """Progress of one cell (explauto ``DiscreteProgress.update_from_index_and_competence``): the mean
    of the older half of its window (oldest first) minus the mean of the newer half. Negative when
    the competence rises; the choice uses its absolute value. An odd window's newer half is the
    larger (explauto's ``range(win_size / 2)`` split).

    Parameters
    ----------
    window : ndarray, shape (w,)
        The cell's last w normalised competences, oldest first, w >= 2.

    Returns
    -------
    float
        The progress (older mean − newer mean).
    """
    h = len(window) // 2
    # (np.mean's arithmetic, without its dispatch: the sum of each half over its length)
    return float(window[:h].sum() / h - window[h:].sum() / (len(window) - h))


def cell_probabilities(progress: np.ndarray) -> np.ndarray:
    """Probability of each cell: its absolute progress over the sum (explauto ``DiscreteProgress.sample``,
    ``discrete_random_draw``); uniform when every progress is 0.

    Parameters
    ----------
    progress : array_like, shape (G,)
        Progress of each of the G cells.

    Returns
    -------
    ndarray, shape (G,)
        Probability of each cell, summing to 1.
    """
    return proportional(np.abs(np.asarray(progress, float)))


class DiscretizedProgress(Teacher):
    """The ``discretized-progress`` teacher of a :class:`~sagg_goal_generator.core.GoalGenerator`
    (its draws from the generator's goal stream).

    Parameters
    ----------
    gen : GoalGenerator
        The generator the teacher chooses goals for (its parameters hold the
        ``discretized_progress.*`` ones).

    Raises
    ------
    ConfigError
        More than 10^7 competences to keep (``cells`` × ``window``).
    """

    def __init__(self, gen):
        p = gen.params
        super().__init__(gen)
        self.p = {q.name[len(P):]: p[q.name] for q in SCHEMA}
        if self.p["cells"] * self.p["window"] > 10_000_000:
            raise ConfigError(f"{P}cells x {P}window: got {self.p['cells']} x {self.p['window']}; allowed: at "
                              "most 10^7 competences kept")
        self.shape = grid_shape(self.p["cells"], gen.dim)
        self.n_cells = int(np.prod(self.shape))
        self.width = (gen.upper - gen.lower) / np.array(self.shape)
        self.windows = np.zeros((self.n_cells, self.p["window"]))  # oldest first
        self.progress = np.zeros(self.n_cells)
        # per dimension (lower, upper, bin width, bins), as Python floats: cell_of runs per report
        self._bins = list(zip(gen.lower.tolist(), gen.upper.tolist(), self.width.tolist(), self.shape))

    def cell_of(self, y) -> int | None:
        """Flat index (C order, as ``np.ravel_multi_index``) of the cell holding ``y`` (the upper
        faces belong to the last bins); None outside Y (or NaN).

        Parameters
        ----------
        y : array_like, shape (m,)
            A point; m = task dimensions.

        Returns
        -------
        int or None
            The cell's flat index, in [0, G) (G = number of cells); None when ``y`` is outside Y,
            NaN or not of shape (m,).
        """
        y = np.asarray(y, float)
        if y.shape != self.gen.lower.shape:
            return None
        flat = 0
        for v, (lo, hi, width, bins) in zip(y.tolist(), self._bins):
            if not lo <= v <= hi:
                return None
            flat = flat * bins + min(int((v - lo) / width), bins - 1)
        return flat

    def _append(self, cell: int, value: float) -> None:
        w = self.windows[cell]
        w[:-1] = w[1:]
        w[-1] = value
        self.progress[cell] = cell_progress(w)

    def report(self, kind: int, target, competence: float) -> None:
        """A goal report appends its competence, normalised to [0, 1] (``C + 1``), to the window of the
        goal's cell; with ``novelty_bonus``, a reached-point or exploration report gives a cell
        whose window sums to 0 the maximal competence 1. Subgoal reports and reports outside Y are
        ignored.

        Parameters
        ----------
        kind : int
            A ``KIND_*`` constant of :mod:`sagg_common.report_kinds` (goal, subgoal, reached,
            exploration).
        target : array_like, shape (m,)
            The goal or subgoal position (goal and subgoal reports), or the reached position
            (reached and exploration reports); m = task dimensions.
        competence : float
            Its competence (Γ for goals and subgoals; for the others, the learner's choice: see
            :meth:`~sagg_goal_generator.core.GoalGenerator.report`).
        """
        cell = self.cell_of(target)
        if cell is None:
            return
        if kind == KIND_GOAL:
            self._append(cell, min(1.0, max(0.0, float(competence) + 1.0)))
        elif (kind in (KIND_REACHED, KIND_EXPLORATION) and self.p["novelty_bonus"]
              and self.windows[cell].sum() == 0.0):
            self._append(cell, 1.0)

    def choose(self) -> tuple[np.ndarray, int]:
        """The next goal: a cell uniform with probability ``random_share`` or while every progress is
        0 (mode ``global``), else one chosen by :func:`cell_probabilities` (``region``); the goal is
        uniform in that cell.

        Returns
        -------
        goal : ndarray, shape (m,)
            The goal, in Y (m = task dimensions).
        mode : int
            How it was chosen: a ``MODE_*`` constant of :mod:`~sagg_goal_generator.modes`.
        """
        rng = self.gen.rng
        if rng.random() < self.p["random_share"] or not self.progress.any():
            cell, mode = int(rng.integers(self.n_cells)), MODE_GLOBAL
        else:
            cell, mode = choice_index(rng, cell_probabilities(self.progress)), MODE_REGION
        lo = self.gen.lower + np.array(np.unravel_index(cell, self.shape)) * self.width
        return np.minimum(self.gen.uniform(lo, lo + self.width), self.gen.upper), mode

    def state(self) -> tuple[dict[str, np.ndarray], dict]:
        """The windows (npz) and the number of cells (JSON); the progress is derived from the
        windows.

        Returns
        -------
        arrays : dict of str to ndarray
            ``windows``, shape (G, w): every cell's window, oldest first (G = cells, w = ``window``).
        meta : dict
            ``cells``: G.
        """
        return {"windows": self.windows}, {"cells": self.n_cells}

    def restore(self, arrays: dict, meta: dict) -> None:
        """Set the windows :meth:`state` returned and recompute every cell's progress.

        Parameters
        ----------
        arrays : dict of str to ndarray
            The arrays of :meth:`state` (from the checkpoint's npz).
        meta : dict
            The JSON values of :meth:`state`.

        Raises
        ------
        ValueError
            Windows whose shape is not this run's parameters'.
        """
        w = np.asarray(arrays["windows"], float)
        if w.shape != self.windows.shape:
            raise ValueError(f"discretized-progress checkpoint: windows of shape {w.shape}; this run's "
                             f"parameters give {self.windows.shape}")
        self.windows = w.copy()
        self.progress = np.array([cell_progress(x) for x in self.windows])

    def snapshot(self) -> dict:
        """JSON for the result: the grid (shape, Y) and every cell's progress and window mean.

        Returns
        -------
        dict
            ``teacher`` (the name), ``shape`` (bins per dimension), ``lower`` and ``upper`` (Y's
            bounds, m floats each), ``progress`` and ``competence`` (G floats each, the cells in
            C order).
        """
        return {"teacher": NAME, "shape": list(self.shape), "lower": self.gen.lower.tolist(),
                "upper": self.gen.upper.tolist(), "progress": self.progress.tolist(),
                "competence": self.windows.mean(axis=1).tolist()}
