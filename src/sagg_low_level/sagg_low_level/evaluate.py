"""Evaluation of the learned inverse model (paper Sec. 3.7). ROS-free.

Each test goal is reached from the rest posture with the frozen model: reaching steps only, no
exploration, no learning; the score is the final effector-goal distance. Evaluation runs on its own
simulator instance so the learning run is untouched, and is never counted as learning budget.
"""
from __future__ import annotations

from typing import Generator, Protocol, Sequence

import numpy as np

from .learner import EvolvingContextLearner, safe_target, timeout_budget
from .local_model import desired_displacement, norm
from .reach_batch import batch_supported, reach_steps


class ReachingRobot(Protocol):
    def reset(self) -> tuple[np.ndarray, np.ndarray]: ...
    def command(self, alpha_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...


def reach_frozen(learner: EvolvingContextLearner, robot: ReachingRobot, goal: np.ndarray) -> float:
    """Reach ``goal`` from rest with the learner's current model, without learning (Sec. 3.7).

    Budget: ``ceil(eval.timeout_factor × D(y_rest, goal) / v)`` steps; stops early within
    ``eval.tolerance``. Returns the final distance ``D(goal, y_f)``.
    """
    alpha, y = robot.reset()
    reach = frozen_reach(learner, alpha, y, goal)
    try:
        target = next(reach)
        while True:
            if not allowed(learner, alpha, target):
                target = reach.send((alpha, y))  # (not sent: the arm stays, the step is spent)
                continue
            alpha, y = robot.command(target)
            target = reach.send((alpha, y))
    except StopIteration as done:
        return done.value[1]


def allowed(learner: EvolvingContextLearner, alpha: np.ndarray, target: np.ndarray) -> bool:
    """Whether the learner's scene (``learner.scene``, None: none) lets an evaluation's step go from
    ``alpha`` to ``target``: an evaluation meets the scene as the learner node's reaches do (a
    refused step is not sent, the arm stays). Not counted among the learner's refusals."""
    return learner.scene is None or learner.scene.segment(alpha, target) is None


REACH_STEPS_FACTOR = 10  # a reach may ask for this many times the evaluation's longest budget


def reach_steps_limit(learner: EvolvingContextLearner, task_lower, task_upper) -> int:
    """The most steps one reach may ask for (``/sagg/reach``'s ``max_steps``): 10× the evaluation's
    budget (:func:`timeout_budget`) for the longest distance in Y, its diagonal; a bound so that
    no request can pause learning for ever, generous enough for any goal the evaluation reaches."""
    diagonal = float(np.linalg.norm(np.asarray(task_upper, float) - np.asarray(task_lower, float)))
    return REACH_STEPS_FACTOR * timeout_budget(diagonal, learner.v, learner.p["eval.timeout_factor"])


def frozen_reach(learner: EvolvingContextLearner, alpha: np.ndarray, y: np.ndarray, goal: np.ndarray,
                 tolerance: float = 0.0, max_steps: int = 0) -> Generator:
    """The frozen model's reach of ``goal`` from the posture ``alpha`` (effector at ``y``): reaching
    steps only (Sec. 3.6.1: Δy_next toward the goal at speed v, Δα from the local inverse), no
    exploration, no learning. A generator: it yields each command (a posture at most
    ``max_joint_step`` from the measured one, within the joint limits) and is sent the measured
    (α, y) after it; it returns ``(y, distance, steps, outcome)``, outcome 'reached' (within
    ``tolerance``, 0 = ``eval.tolerance``), 'budget' (``max_steps`` steps, 0 = the evaluation's
    budget ``ceil(eval.timeout_factor × D(y, goal) / v)``) or 'no model' (too few samples for a
    Jacobian). The evaluation (:func:`reach_frozen`, from rest) and the learner node's ``reach``
    action (from the current posture) both run it."""
    p = learner.p
    tol = p["eval.tolerance"] if tolerance <= 0 else tolerance
    budget = max_steps or timeout_budget(norm(goal - y), learner.v, p["eval.timeout_factor"])
    outcome = "budget"
    steps = 0
    for _ in range(budget):
        if norm(goal - y) <= tol:
            outcome = "reached"
            break
        dalpha = learner.reach_step(alpha, desired_displacement(y, goal, learner.v))
        if dalpha is None:
            outcome = "no model"
            break
        alpha, y = yield safe_target(alpha, alpha + dalpha, p["max_joint_step"], learner.robot)
        steps += 1
    else:
        if norm(goal - y) <= tol:
            outcome = "reached"
    return y, norm(goal - y), steps, outcome


def open_loop_reach(learner: EvolvingContextLearner, alpha: np.ndarray, y: np.ndarray, goal: np.ndarray,
                    tolerance: float = 0.0, max_steps: int = 0, check=None) -> tuple:
    """The frozen model's reach of ``goal`` run on the model alone, with no robot: inverse
    kinematics from what was learned (``/sagg/compute_ik``).

    The paper reaches with local inverse models (Sec. 3.3, reaching in Sec. 3.6.1): at each step
    ``Δα = J⁺(α)·Δy_next`` from the k nearest samples, then the arm moves and its effector is
    *measured*. Here the steps are :func:`frozen_reach`'s, the same step (``reach_step``, joint
    limits and ``max_joint_step`` included), but each is answered by the local forward model's
    *prediction* ``y ← y + J(α)·Δα`` (Sec. 3.3, ``learner.predict``) instead of a measurement:
    open loop, our choice for an answer without motion. Its errors add up along the way where a
    measured reach corrects them at every step (so its error exceeds the evaluation's).

    ``check(alpha0, alpha1, y0)`` (None: none) is the scene: a step it refuses is not taken, as
    the evaluation's reaches meet the scene (:func:`allowed`); open loop, the same step would come
    again, so the reach ends there (outcome 'scene').

    Parameters
    ----------
    learner : EvolvingContextLearner
        The model (its memory, ``robot`` limits and parameters); nothing is stored or changed.
    alpha : ndarray, shape (n,)
        The start posture.
    y : ndarray, shape (m,)
        The effector's point at ``alpha`` (measured, or predicted).
    goal : ndarray, shape (m,)
        The point to reach.
    tolerance, max_steps
        As :func:`frozen_reach` (0: ``eval.tolerance``; 0: the evaluation's budget).
    check : callable, optional
        ``(alpha0, alpha1, y0) -> Refusal | None``.

    Returns
    -------
    tuple
        ``(alpha, y, distance, steps, outcome, refusal)``: the final posture, its predicted point,
        the predicted distance to ``goal``, the steps taken, the outcome of :func:`frozen_reach`
        or 'scene', and the refusal that ended it (None).
    """
    alpha, y = np.asarray(alpha, dtype=float), np.asarray(y, dtype=float)
    reach = frozen_reach(learner, alpha, y, goal, tolerance, max_steps)
    steps = 0
    try:
        target = next(reach)
        while True:
            refusal = None if check is None else check(alpha, target, y)
            if refusal is not None:
                reach.close()
                return alpha, y, norm(goal - y), steps, "scene", refusal
            y = y + learner.predict(alpha, target - alpha)
            alpha = target
            steps += 1
            target = reach.send((alpha, y))
    except StopIteration as done:
        y, distance, steps, outcome = done.value
        return alpha, y, distance, steps, outcome, None


def evaluate(learner: EvolvingContextLearner, robot: ReachingRobot, goals: np.ndarray) -> np.ndarray:
    """Final distances for every test goal (paper Sec. 3.7: mean and median are reported)."""
    return np.array([reach_frozen(learner, robot, g) for g in np.asarray(goals, dtype=float)])


def evaluate_per_goal(learner: EvolvingContextLearner, robots: Sequence[ReachingRobot],
                      goals: np.ndarray) -> np.ndarray:
    """Final distances, test goal i reached on ``robots[i]`` (:func:`reach_frozen`, one goal after the
    other): the definition :func:`evaluate_batch` reproduces. With one noise-free robot per goal it
    equals :func:`evaluate` on one robot (every reach starts with ``reset``)."""
    goals = np.asarray(goals, dtype=float)
    if len(robots) != len(goals):
        raise ValueError(f"robots: {len(robots)} for {len(goals)} test goals (one per goal)")
    return np.array([reach_frozen(learner, r, g) for r, g in zip(robots, goals)])


def evaluate_batch(learner: EvolvingContextLearner, robots: Sequence[ReachingRobot],
                   goals: np.ndarray) -> np.ndarray:
    """:func:`evaluate_per_goal`, every test goal's reach advanced together, one frozen step at a time.

    Per goal the semantics are :func:`reach_frozen`'s (budget ``ceil(eval.timeout_factor × D / v)``,
    early stop within ``eval.tolerance``, stop when the model has no Jacobian, final distance); only
    the model's work is batched across the goals still reaching
    (:func:`sagg_low_level.reach_batch.reach_steps`, bit-identical to ``reach_step``). The clip to
    ``max_joint_step`` and the joint limits (:func:`~sagg_low_level.learner.safe_target`) is element-wise
    and is applied to all rows at once with the same operations. Each robot sees exactly the commands
    it would see in :func:`evaluate_per_goal`, so the result is the same, bit for bit (checked by
    test/test_eval_batch.py). A learner whose model functions were replaced on the instance is
    evaluated goal by goal."""
    goals = np.asarray(goals, dtype=float)
    if len(robots) != len(goals):
        raise ValueError(f"robots: {len(robots)} for {len(goals)} test goals (one per goal)")
    if not batch_supported(learner):
        return evaluate_per_goal(learner, robots, goals)
    p = learner.p
    tol, v, max_step = p["eval.tolerance"], learner.v, p["max_joint_step"]
    lower, upper = learner.robot.lower, learner.robot.upper
    starts = [r.reset() for r in robots]
    alpha = np.array([a for a, _ in starts], dtype=float)
    y = np.array([yy for _, yy in starts], dtype=float)
    budget = np.array([timeout_budget(norm(g - yy), v, p["eval.timeout_factor"])
                       for g, yy in zip(goals, y)])
    used = np.zeros(len(goals), dtype=int)
    active = list(range(len(goals)))
    cache: dict = {}
    while active:
        # reach_frozen's loop head: budget spent, or within tolerance
        active = [i for i in active
                  if used[i] < budget[i] and not norm(goals[i] - y[i]) <= tol]
        if not active:
            break
        rows = np.array(active)
        a = alpha[rows]
        dys = np.array([desired_displacement(y[i], goals[i], v) for i in active])
        dalpha = reach_steps(learner, a, dys, cache)
        if dalpha is None:  # no model yet: every reach stops where it is
            break
        # safe_target, row-wise with the same element-wise operations
        step = (a + dalpha) - a
        big = np.abs(step).max(axis=1) if step.shape[1] else np.zeros(len(rows))
        for j in np.flatnonzero(big > max_step):
            step[j] = step[j] * (max_step / float(big[j]))
        target = np.minimum(np.maximum(a + step, lower), upper)
        for j, i in enumerate(active):
            if allowed(learner, alpha[i], target[j]):
                alpha[i], y[i] = robots[i].command(target[j])
            used[i] += 1
    return np.array([norm(g - yy) for g, yy in zip(goals, y)])
