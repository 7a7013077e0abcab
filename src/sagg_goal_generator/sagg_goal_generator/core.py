"""The goal generator (high level of SAGG-RIAC, paper Sec. 2.4, Algorithms 1-2). ROS-free.

It receives competence reports from the low level and chooses goals. The same object runs in-process
and inside the goal-generator node; its output is a deterministic function of its seed and of the
sequence of calls, which is what makes the graph and in-process runs identical.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sagg_common.params import SHARED_SCHEMA, ConfigError, Param, Schema
from sagg_common.region_arrays import restore_tree
from sagg_common.regions import RegionTree, interest_probabilities
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED
from sagg_common.rng import choice_index, stream, uniform_in

from . import alp_gmm, discretized_progress
from .teacher import Teacher
from .modes import (MODE_GLOBAL, MODE_INITIAL, MODE_LOW_COMPETENCE, MODE_NAMES,  # noqa: F401 - re-exported
                    MODE_RANDOM, MODE_REGION)


SCHEMA: Schema = SHARED_SCHEMA + (
    Param("prior.regions", "str", "",
          "Start the region tree from another run's (an .npz of its tree: `sagg run/experiment --prior SRC "
          "--prior-regions` writes and sets it): its regions, their points and competences, so the first "
          "goals follow that run's interests. '' (default) = an empty tree, the paper's start. The "
          "strategy's teacher keeps no other state from it. Not in the paper."),
    Param("g_max", "int", 50, "Maximal number of points in a region before it splits (Sec. 2.4.4).",
          low=2, high=1_000_000),
    Param("zeta", "int", 20,
          "Interest window ζ: number of most recent competences used by the interest (Sec. 2.4.3). "
          "Not given in the paper; 20 (two halves of 10) is our choice.", low=2, high=1_000_000),
    Param("split_candidates", "int", 20,
          "m: number of random (dimension, value) split candidates (Sec. 2.4.4). Not given in the "
          "paper; our choice.", low=1, high=10_000),
    Param("p1", "float", 0.7, "Probability of mode 1 (region by interest, uniform inside).",
          low=0.0, high=1.0),
    Param("p2", "float", 0.2, "Probability of mode 2 (uniform in Y).", low=0.0, high=1.0),
    Param("p3", "float", 0.1,
          "Probability of mode 3 (region by interest, near its lowest-competence point).",
          low=0.0, high=1.0),
    Param("mode3_sigma", "float", 0.05,
          "Mode 3 spread: std of the Gaussian around the lowest-competence point, as a fraction of "
          "the region's extent per dimension (paper: 'close to'; our choice).", low=0.0, high=10.0),
    Param("count_reached", "bool", True,
          "Every reached point (reaching and exploration micro-actions) counts as a goal of "
          "maximal competence (Sec. 2.5, 3.5). The paper turns it off for the DOF experiments."),
) + alp_gmm.SCHEMA + discretized_progress.SCHEMA


@dataclass
class GoalRecord:
    seq: int
    position: np.ndarray
    mode: int
    after_report: int
    competence: float | None = None  # filled by the goal's own report


class RegionInterest(Teacher):
    """``sagg-riac``: the three modes over the region tree (Sec. 2.4.4), after an initial uniform
    phase while the tree has one region."""

    def choose(self) -> tuple[np.ndarray, int]:
        """The next goal: uniform in Y while the tree has one region (mode ``initial``), then mode 1,
        2 or 3 with probabilities p1, p2, p3: uniform in a region chosen by interest
        (``region``), uniform in Y (``global``), or near the lowest-competence point of a region
        chosen by interest (``low-competence``).

        Returns
        -------
        goal : ndarray, shape (m,)
            The goal, in Y (m = task dimensions).
        mode : int
            How it was chosen: a ``MODE_*`` constant of :mod:`~sagg_goal_generator.modes`.
        """
        gen = self.gen
        if len(gen.tree.leaves()) < 2:
            return gen.uniform(gen.lower, gen.upper), MODE_INITIAL
        mode = choice_index(gen.rng, gen.mode_probs) + 1
        if mode == MODE_GLOBAL:
            return gen.uniform(gen.lower, gen.upper), mode
        region = gen._region_by_interest()
        return (gen.uniform(region.lower, region.upper) if mode == MODE_REGION
                else gen._near_lowest(region)), mode


class UniformGoals(Teacher):
    """``sagg-random``: goals uniform in Y (Sec. 3.7)."""

    def choose(self) -> tuple[np.ndarray, int]:
        """A goal uniform in Y (mode ``random``).

        Returns
        -------
        goal : ndarray, shape (m,)
            The goal, in Y (m = task dimensions).
        mode : int
            How it was chosen: a ``MODE_*`` constant of :mod:`~sagg_goal_generator.modes`.
        """
        return self.gen.uniform(self.gen.lower, self.gen.upper), MODE_RANDOM


# The goal strategies' teachers, by strategy name (keys: sagg_common.params.GOAL_STRATEGIES).
TEACHERS: dict[str, type] = {
    "sagg-riac": RegionInterest,
    "sagg-random": UniformGoals,
    alp_gmm.NAME: alp_gmm.AlpGmm,
    discretized_progress.NAME: discretized_progress.DiscretizedProgress,
}


class GoalGenerator:
    """High-level goal self-generation (Sec. 2.4.4) over a region tree of Y; the goals are chosen by
    the strategy's teacher (:data:`TEACHERS`). The tree takes every report whatever the strategy
    (it is what /sagg/regions shows).

    Parameters
    ----------
    params : dict
        The parameters by name (:data:`SCHEMA`), among them ``strategy``, ``seed``,
        ``task_space.lower`` and ``task_space.upper`` (m values each).

    Raises
    ------
    ValueError
        Task-space bounds of unequal length or not increasing, or p1 + p2 + p3 other than 1.
    ConfigError
        Inconsistent parameters of the strategy's teacher.
    """

    def __init__(self, params: dict):
        self.params = params
        self.strategy = params["strategy"]
        self.lower = np.asarray(params["task_space.lower"], dtype=float)
        self.upper = np.asarray(params["task_space.upper"], dtype=float)
        if self.lower.shape != self.upper.shape:
            raise ValueError(
                f"task_space.lower/upper: lengths {len(self.lower)} and {len(self.upper)} differ; "
                "allowed: equal lengths")
        if not np.all(self.upper > self.lower):
            raise ValueError("task_space.upper: every element must exceed task_space.lower")
        p = np.array([params["p1"], params["p2"], params["p3"]])
        if abs(p.sum() - 1.0) > 1e-9:
            raise ValueError(f"p1 + p2 + p3: got {p.sum()}; allowed: exactly 1")
        self.mode_probs = p
        self.rng = stream(params["seed"], "goal_generator")
        self.tree = RegionTree(self.lower, self.upper, params["g_max"], params["zeta"],
                               params["split_candidates"], stream(params["seed"], "region_splits"))
        self.count_reached = params["count_reached"]
        self.goals: list[GoalRecord] = []
        self.reports = 0  # number of reports processed (== seq of the last one)
        self.ignored_outside = 0
        self.skipped_reports = 0  # rejected or lost reports (skip_report)
        # actuator strategies choose no goals; their generator keeps sagg-riac's teacher (never asked)
        self.teacher: Teacher = TEACHERS.get(self.strategy, RegionInterest)(self)
        if params.get("prior.regions"):
            start_tree_from(self.tree, params["prior.regions"])

    @property
    def dim(self) -> int:
        return len(self.lower)

    # ---------------------------------------------------------------- reports
    def report(self, kind: int, target, competence: float) -> None:
        """Take one competence report (Alg. 1: UpdateRegions(R, y, Γ)).

        ``target`` is the goal/subgoal position for goals and subgoals, and the reached position for
        reached points and exploration samples, whose competence the learner chose: the maximal one,
        0 (Sec. 2.5; the evolving learner), or that of the outcome toward its goal (Alg. 4's Γ_{y_i};
        the fixed-context learner's ``outcome_competence``). Reached/exploration reports are ignored
        unless ``count_reached``.

        Parameters
        ----------
        kind : int
            A ``KIND_*`` constant of :mod:`sagg_common.report_kinds` (goal, subgoal, reached,
            exploration).
        target : array_like, shape (m,)
            The goal or subgoal position (goal and subgoal reports), or the reached position
            (reached and exploration reports); m = task dimensions.
        competence : float
            Its competence (Γ for goals and subgoals; for the others, as above).
        """
        self.reports += 1
        if kind == KIND_GOAL and self.goals:
            self.goals[-1].competence = float(competence)
        self.teacher.report(kind, target, competence)
        if kind in (KIND_REACHED, KIND_EXPLORATION) and not self.count_reached:
            return
        if self.tree.add(target, competence, stamp=len(self.goals)) is None:
            self.ignored_outside += 1

    def skip_report(self) -> None:
        """Count a report that was rejected as bad input (NaN, wrong dimension, unknown kind) or
        lost in transport, without using it: the report numbering (``after_report`` of goal
        requests) stays aligned with the learner's. Not in the paper (robustness)."""
        self.reports += 1
        self.skipped_reports += 1

    # ------------------------------------------------------------------ goals
    def next_goal(self) -> GoalRecord:
        """Self-generate the next goal (Sec. 2.4.4; the strategy's teacher chooses it).

        Returns
        -------
        GoalRecord
            The goal: ``seq`` (1, 2, ...), ``position`` (shape (m,)), ``mode`` (a ``MODE_*``
            constant) and ``after_report`` (the reports processed so far); also appended to
            ``goals``.
        """
        y, mode = self.teacher.choose()
        rec = GoalRecord(len(self.goals) + 1, y, mode, self.reports)
        self.goals.append(rec)
        return rec

    def uniform(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """A point uniform in the box [lower, upper], from the goal stream
        (:func:`~sagg_common.rng.uniform_in`).

        Parameters
        ----------
        lower, upper : ndarray, shape (m,)
            The box's bounds (Y's or a region's), lower <= upper.

        Returns
        -------
        ndarray, shape (m,)
            The point.
        """
        return uniform_in(self.rng, lower, upper)

    def region_probabilities(self) -> np.ndarray:
        """Selection probabilities of the leaves (mode 1, Sec. 2.4.4): :func:`interest_probabilities`.

        Returns
        -------
        ndarray, shape (L,)
            Probability of each of the L leaves, in ``tree.leaves()`` order.
        """
        return interest_probabilities(self.tree.interests())

    def _region_by_interest(self):
        leaves = self.tree.leaves()
        return leaves[choice_index(self.rng, self.region_probabilities())]

    def _near_lowest(self, region) -> np.ndarray:
        """Mode 3: a goal close to the region's point of lowest competence. Spread is
        ``mode3_sigma`` × region extent per dimension (our choice); clipped to Y."""
        if region.count == 0:
            return self.uniform(region.lower, region.upper)
        worst = region.filled_points[int(np.argmin(region.filled_values))]
        sigma = self.params["mode3_sigma"] * (region.upper - region.lower)
        return np.clip(worst + self.rng.normal(0.0, 1.0, self.dim) * sigma, self.lower, self.upper)

    # ------------------------------------------------------------- reporting
    def region_snapshot(self) -> list[dict]:
        """The region tree's leaves as JSON-able dicts
        (:meth:`~sagg_common.regions.RegionTree.snapshot`).

        Returns
        -------
        list of dict
            One dict per leaf: ``id``, ``lower``, ``upper``, ``interest``, ``count`` and
            ``mean_competence``.
        """
        return self.tree.snapshot()


def start_tree_from(tree: RegionTree, path: str) -> None:
    """Put the regions of another run's tree into the fresh ``tree``; its split history stays empty
    (this run's splits).

    Parameters
    ----------
    tree : RegionTree
        A fresh tree of this run's task space (one region).
    path : str
        An .npz holding the arrays of :func:`sagg_common.region_arrays.tree_arrays`: a prior's
        regions.npz or a goal-generator checkpoint's state file.

    Raises
    ------
    ConfigError
        Naming ``prior.regions``: the file cannot be read, or its root box is not this task space.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            lower, upper = z["region_lower"][0], z["region_upper"][0]
            if lower.shape != tree.root.lower.shape or not (np.allclose(lower, tree.root.lower)
                                                           and np.allclose(upper, tree.root.upper)):
                raise ConfigError(f"parameter 'prior.regions': {path!r} covers {lower.tolist()}..{upper.tolist()}; "
                                  f"allowed: a tree of this task space {tree.root.lower.tolist()}.."
                                  f"{tree.root.upper.tolist()}")
            restore_tree(tree, z)
    except ConfigError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise ConfigError(f"parameter 'prior.regions': {path!r}: {exc}") from exc
