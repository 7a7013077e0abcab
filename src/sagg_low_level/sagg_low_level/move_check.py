"""Which scene check the learner gets (ROS-free): one builder for the learner node and the in-process run.

- a model arm (``task_model.file`` set): :class:`sagg_common.scene.SceneChecker`, the arm's
  geometry against the declared obstacles and itself, for every posture on the way;
- no model (a tracker gives the task point): :class:`TaskPointCheck`, the declared obstacles
  against the task point only, where the learner's local model predicts it after the move (no
  prediction yet: the move is not refused). Said as such at start: the arm's links are not checked;
- nothing declared: None.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from sagg_common.scene import SceneParams, scene_from_params, task_point_refusal


class TaskPointCheck:
    """The scene for a set-up without the robot's model: a move is refused when the task point the
    learner predicts after it (``predict(alpha0, dalpha)``, its local model) is closer than
    ``scene.clearance`` to the floor or a box (:func:`sagg_common.scene.task_point_refusal`).

    Parameters
    ----------
    params : SceneParams
        The declared scene.
    axes : str
        The world axes of the task point (``task_model.task_axes``: 'xyz', 'xy', ...).
    predict : callable
        ``(alpha0 (n,), dalpha (n,)) -> (m,)``: the learner's prediction of the task point's
        displacement.
    current : callable
        ``() -> (m,)``: the task point now.
    """

    def __init__(self, params: SceneParams, axes: str, predict: Callable, current: Callable):
        self.params, self.axes, self.predict, self.current = params, axes, predict, current

    def segment(self, alpha0: np.ndarray, alpha1: np.ndarray):
        """The refusal of the move's predicted end point, or None. A point already too close (the
        arm rests there) may move away: a prediction no closer than now is not refused."""
        dy = self.predict(alpha0, alpha1 - alpha0)
        if not np.all(np.isfinite(dy)):
            return None
        y0 = np.asarray(self.current(), dtype=float)
        refusal = task_point_refusal(y0 + dy, self.params, self.axes)
        if refusal is None:
            return None
        now = task_point_refusal(y0, self.params, self.axes)
        return None if now is not None and refusal.distance >= now.distance else refusal


def build_move_check(p: dict, joints: Sequence[str], base_dir: str, learner) -> tuple[object | None, list[str]]:
    """The scene check of a learner (the module docstring) and what to say once at start.

    Parameters
    ----------
    p : dict
        The learner's parameters (``scene.*``, ``task_model.*``, ``joint_limits.*``, ``rest_posture``).
    joints : sequence of str
        The learner's joints, in command order.
    base_dir : str
        The parameter file's directory (relative model paths).
    learner : EvolvingContextLearner
        Its ``predict`` and task point ``y`` serve :class:`TaskPointCheck`.

    Returns
    -------
    (checker or None, list of str)
        The check (an object with ``segment(alpha0, alpha1) -> Refusal | None``) and the notices.
    """
    params = SceneParams.from_params(p)
    if p.get("task_model.file"):
        checker = scene_from_params(p, joints, base_dir)
        return checker, ([params.describe()] + list(checker.notices)) if checker is not None else []
    if not params.obstacles:
        return None, []
    axes = p.get("task_model.task_axes", "xyz")[:len(learner.task_lower)]
    return (TaskPointCheck(params, axes, learner.predict, lambda: learner.y),
            [params.describe() + "; no robot model (task_model.file): the task point only is checked against it, "
             "where the learner predicts it after each move; the arm's links are not checked"])
