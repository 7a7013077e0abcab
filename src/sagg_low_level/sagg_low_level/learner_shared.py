"""What the two low-level learners share, written once: the evolving-context learner
(:mod:`sagg_low_level.learner`, paper Alg. 3) and the fixed-context one
(:mod:`sagg_low_level.fixed_context`, Alg. 4). ROS-free.

Shared: the requests both yield to observe and to ask for a goal, their competence reports, the
parameters both declare alike, the task space Y they check, and ACTUATOR-RIAC's region tree and
region choice (Sec. 3.8, 4.5). What stays apart differs because the algorithms differ: a goal
attempt (Alg. 3 moves by micro-actions Δα from the current posture, with subgoals and a distance
timeout; Alg. 4 runs whole synergies θ from rest, with an exploration phase around the best θ),
what a sample is ((α, Δα, Δy) against (θ, y)), and ACTUATOR-RIAC's space (regions over (α, Δα)
of which only those holding the current α may be chosen, against regions over θ alone).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from sagg_common.params import Param
from sagg_common.regions import Region, RegionTree, interest_probabilities
from sagg_common.report_kinds import KIND_GOAL, KIND_SUBGOAL
from sagg_common.rng import choice_index, stream

# Parameters both learners declare alike
EPS_SIM = Param("eps_sim", "float", -0.05,
                "ε_sim < 0: a goal counts as reached when C > ε_sim (Sec. 2.4.1). Paper gives no value.",
                low=-1.0, high=0.0)
RIAC_SPLITTING = (
    Param("riac.zeta", "int", 20, "ACTUATOR-RIAC: interest window over prediction errors.",
          low=2, high=1_000_000),
    Param("riac.split_candidates", "int", 20, "ACTUATOR-RIAC: random split candidates.",
          low=1, high=10_000),
)


# --------------------------------------------------------------------------- coroutine protocol
@dataclass
class Observe:
    """Request the current state. Answer: ``(alpha, y)`` (evolving context) or the rest outcome
    y_rest (fixed context)."""


@dataclass
class GoalRequest:
    """Request the next goal once the generator has processed reports 1..after_report.
    Answer: ``(goal_seq, position)``."""

    after_report: int


@dataclass
class Report:
    seq: int
    goal_seq: int
    kind: int
    target: np.ndarray
    reached: np.ndarray
    start: np.ndarray
    competence: float
    micro_actions: int


class ReportSource:
    """What both learners (``EvolvingContextLearner``, and the fixed context's
    ``FixedContextLearner``) share for their competence reports (Alg. 1: one report per attempt):
    reports numbered from 1 (``reports_sent``), the competence of the last goal or subgoal
    (``last_competence``, for the status), each report handed to ``on_report``."""

    reports_sent: int
    last_competence: float
    on_report: Callable[[Report], None] | None

    def _init_reports(self) -> None:
        self.reports_sent = 0
        self.last_competence = float("nan")
        self.on_report = None

    def _emit_report(self, kind: int, goal_seq: int, target, reached: np.ndarray, start: np.ndarray, comp: float,
                     count: int) -> None:
        """Number and hand on one report (``reached`` and ``start`` as the report keeps them;
        ``count``: micro-actions, or experiments in the fixed context, so far)."""
        self.reports_sent += 1
        if kind in (KIND_GOAL, KIND_SUBGOAL):
            self.last_competence = comp
        if self.on_report is not None:
            self.on_report(Report(self.reports_sent, goal_seq, kind, np.array(target, dtype=float), reached, start,
                                  float(comp), count))


def task_space(params: dict, task_dim: int | None) -> tuple[np.ndarray, np.ndarray, int]:
    """The task space Y of a learner's parameters, checked against the dimensions its robot reports.

    Parameters
    ----------
    params : dict
        The learner's parameters, among them ``task_space.lower`` and ``task_space.upper``.
    task_dim : int or None
        m, the task dimensions the robot reports (None: taken from the task space).

    Returns
    -------
    lower, upper : ndarray, shape (m,)
        Y's bounds.
    m : int
        The task dimensions.

    Raises
    ------
    ValueError
        Bounds of unequal length or not increasing, or a ``task_dim`` other than the bounds' length.
    """
    lower = np.asarray(params["task_space.lower"], dtype=float)
    upper = np.asarray(params["task_space.upper"], dtype=float)
    if lower.shape != upper.shape or not np.all(upper > lower):
        raise ValueError("task_space.lower/upper: equal lengths and upper > lower required")
    m = task_dim or len(lower)
    if m != len(lower):
        raise ValueError(f"task_space: {len(lower)} dimensions but the robot reports {m}")
    return lower, upper, m


def riac_tree(params: dict, lower: np.ndarray, upper: np.ndarray) -> RegionTree:
    """ACTUATOR-RIAC's empty region tree over the box ``[lower, upper]`` (Sec. 3.8, 4.5), with
    ``riac.g_max``, ``riac.zeta``, ``riac.split_candidates`` and its own split stream.

    Parameters
    ----------
    params : dict
        The learner's parameters (``seed`` and the ``riac.*`` keys above).
    lower, upper : ndarray, shape (d,)
        The box of the tree's space.

    Returns
    -------
    RegionTree
        A tree of one region, the box.
    """
    return RegionTree(lower, upper, params["riac.g_max"], params["riac.zeta"], params["riac.split_candidates"],
                      stream(params["seed"], "actuator_riac_splits"))


def riac_region(rng: np.random.Generator, p_random: float, leaves: list[Region],
                candidates: Callable[[], tuple[np.ndarray | None, np.ndarray]]) -> Region | None:
    """ACTUATOR-RIAC's region choice (as SAGG-RIAC's mode 1): with probability ``p_random``, or while
    the tree is one leaf, None (the caller draws its action uniformly); else one of the candidate
    leaves with probability ∝ interest − min (:func:`~sagg_common.regions.interest_probabilities`).

    Parameters
    ----------
    rng : numpy.random.Generator
        The learner's stream: one ``random()`` draw, then one for the choice.
    p_random : float
        ``riac.p_random``.
    leaves : list of Region
        The tree's leaves (``RegionTree.leaves()``).
    candidates : callable
        ``() -> (rows, interests)``: the rows of ``leaves`` to choose among (None: all of them, in
        order) and their interests; called only when a region is chosen.

    Returns
    -------
    Region or None
        The chosen leaf, or None for a uniform draw.
    """
    if rng.random() < p_random or len(leaves) < 2:
        return None
    rows, interests = candidates()
    i = choice_index(rng, interest_probabilities(interests))
    return leaves[i if rows is None else int(rows[i])]
