"""The interface of a goal strategy (a teacher) of the goal generator. ROS-free.

A teacher chooses goals for :class:`~sagg_goal_generator.core.GoalGenerator`, which keeps one per
run, registered by strategy name in :data:`~sagg_goal_generator.core.TEACHERS`: the paper's two in
``core.py``, the others in a module each (``alp_gmm.py``, ``discretized_progress.py``)."""
from __future__ import annotations

import numpy as np


class Teacher:
    """How a goal strategy chooses goals (a plug-in of :class:`GoalGenerator`, registered in
    :data:`TEACHERS`). Built with the generator, whose ``params``, bounds, goal stream ``rng``,
    ``uniform`` and region tree it may use. Subclasses define :meth:`choose`; the others are
    no-ops here (a teacher with no state of its own: the tree and the goal stream are the
    generator's, saved by its checkpoint).

    Parameters
    ----------
    gen : GoalGenerator
        The generator the teacher chooses goals for.
    """

    def __init__(self, gen):  # gen: the GoalGenerator (not imported here: it imports the teachers)
        self.gen = gen

    def choose(self) -> tuple[np.ndarray, int]:
        """The next goal and its mode.

        Returns
        -------
        goal : ndarray, shape (m,)
            The goal, in Y (m = task dimensions).
        mode : int
            How it was chosen: a ``MODE_*`` constant of :mod:`~sagg_goal_generator.modes`.
        """
        raise NotImplementedError

    def report(self, kind: int, target, competence: float) -> None:
        """Every report the generator takes (whatever ``count_reached`` says; before its tree takes it).

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

    def state(self) -> tuple[dict[str, np.ndarray], dict]:
        """The teacher's own state: arrays (for the checkpoint's npz) and JSON values.

        Returns
        -------
        arrays : dict of str to ndarray
            Arrays, for the checkpoint's npz (empty here).
        meta : dict
            JSON-able values (empty here).
        """
        return {}, {}

    def restore(self, arrays: dict, meta: dict) -> None:
        """Set the state :meth:`state` returned (arrays by the same names).

        Parameters
        ----------
        arrays : dict of str to ndarray
            The arrays of :meth:`state` (from the checkpoint's npz).
        meta : dict
            The JSON values of :meth:`state`.
        """

    def snapshot(self) -> dict | None:
        """JSON for the run's result (the report's "where goals went"); None: nothing of its own.

        Returns
        -------
        dict or None
            JSON-able values; None here.
        """
        return None
