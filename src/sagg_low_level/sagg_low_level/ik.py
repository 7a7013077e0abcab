"""Inverse kinematics from the learned model alone: what ``/sagg/compute_ik`` answers. ROS-free.

A target point of Y -> joint positions, with no motion: the frozen model's reach run open loop
(:func:`~sagg_low_level.evaluate.open_loop_reach`: the reaching steps of the evaluation, each
answered by the local forward model's prediction instead of a measurement) from a start posture.
The answer says how far to trust it: the predicted point and its distance to the target, the
distance in joint space to the nearest stored posture (how far the answer extrapolates from what
was experienced), and a success flag (predicted within tolerance, within the joint limits, allowed
by the scene).

Open loop, the model's small errors add up step by step, so the reach starts as near the target
as the model knows a point (our choice; the paper reaches from rest with a measurement at every
step): from the stored posture whose effector point, rebuilt exactly from the memory's
measurements (:mod:`.known_points`), is nearest the target, a few short steps away. The few
nearest are tried in turn, with the rest posture (its point measured by the learner at its
returns to rest, the *rest point*) among them at its own distance: the first whose reach the model
predicts within tolerance is the answer (:func:`start_candidates`). A start posture the caller
gives is honoured: the reach starts there, from the point the caller measured, or from the point
the model predicts on the way from rest (:func:`predicted_point`).

The model of a finished run is read by :func:`load_model`: a run's learner checkpoint (the learner
node keeps its rest point there, in ``model.json``), or the model directory ``sagg serve`` writes.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sagg_common.diagnostics import goal_problem
from sagg_common.journal import write_json_atomic

from .checkpoint import checkpoint_memory
from .evaluate import open_loop_reach
from .known_points import KnownPoints
from .learner import EvolvingContextLearner, step_toward, stepped_move_limit
from .memory import SampleMemory

REST_POINT_FILE = "model.json"  # beside a memory.npz: {"rest_point": [...], "source": "..."}
CANDIDATES = 4  # stored postures tried as starts, nearest first (our choice: the nearest nearly always reaches)


@dataclass
class IKAnswer:
    """One answer of :func:`compute_ik` (the fields of ``sagg_msgs/srv/ComputeIK``'s response)."""

    success: bool
    message: str
    joints: np.ndarray = field(default_factory=lambda: np.zeros(0))
    predicted: np.ndarray = field(default_factory=lambda: np.zeros(0))
    predicted_error: float = math.nan
    nearest_sample: float = math.nan
    steps: int = 0
    outcome: str = ""
    start: str = ""  # where the reach started: 'stored posture', 'rest posture' or 'given'


def request_problem(learner: EvolvingContextLearner, target, start, start_point, tolerance: float,
                    max_steps: int, steps_limit: int) -> str:
    """What is wrong with a request ('' if nothing), naming the field, its value and what is
    allowed: ``target`` one finite value per task dimension within Y; ``start`` empty or one finite
    value per joint within the joint limits; ``start_point`` empty or one finite value per task
    dimension; ``tolerance`` finite and >= 0; ``max_steps`` at most ``steps_limit``."""
    _, why = goal_problem(target, learner.task_lower, learner.task_upper)
    if why:
        return f"target {why}"
    lo, hi = learner.robot.lower, learner.robot.upper
    a = np.asarray(start, dtype=float)
    if a.size and (a.shape != lo.shape or not np.all(np.isfinite(a)) or np.any(a < lo) or np.any(a > hi)):
        return (f"start {a.tolist()}: allowed: empty (the rest posture) or {len(lo)} finite joint positions "
                f"within the joint limits [{lo.tolist()}, {hi.tolist()}]")
    y = np.asarray(start_point, dtype=float)
    if y.size and (y.shape != (learner.m,) or not np.all(np.isfinite(y))):
        return (f"start_point {y.tolist()}: allowed: empty (predicted by the model) or {learner.m} finite "
                "values (the effector's point at the start posture)")
    if not (math.isfinite(tolerance) and tolerance >= 0.0):
        return f"tolerance {tolerance}: allowed: a finite number >= 0 (0 = eval.tolerance)"
    if max_steps > steps_limit:
        return (f"max_steps {max_steps}: allowed: 0 (the evaluation's budget) to {steps_limit} "
                "(10x the evaluation's budget across Y)")
    return ""


def predicted_point(learner: EvolvingContextLearner, rest_point: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """The effector's point at the posture ``alpha`` as the model predicts it: from the rest point,
    along the straight joint-space path from rest in steps of ``explore_amplitude`` per joint (the
    size of the micro-actions the local models were learned from, over which they are linear; our
    choice), each adding the local forward model's ``J(α)·Δα`` (Sec. 3.3)."""
    robot, max_step = learner.robot, learner.p["explore_amplitude"]
    a, y = robot.rest.copy(), np.asarray(rest_point, dtype=float).copy()
    for _ in range(stepped_move_limit(robot, max_step)):
        if np.array_equal(a, alpha):
            break
        nxt = step_toward(a, alpha, max_step, robot)
        y = y + learner.predict(a, nxt - a)
        a = nxt
    return y


def nearest_sample(memory: SampleMemory, alpha: np.ndarray, prior=None) -> float:
    """Distance (rad, Euclidean in joint space) from ``alpha`` to the nearest stored posture: the
    robot's (the memory's own search: approximate with ``neighbour_checks`` > 0) and, with a prior
    (:class:`~sagg_low_level.prior.Prior`), its samples still in use, which the local models are
    fitted from too. NaN when there is none."""
    best = math.inf
    if len(memory):
        i = int(memory.neighbours(alpha, 1)[0])
        best = float(np.linalg.norm(memory.alpha[i] - alpha))
    if prior is not None:
        _, sq = prior.nearest_live(alpha, 1)
        if len(sq):
            best = min(best, math.sqrt(float(sq[0])))
    return best if math.isfinite(best) else math.nan


def scene_check(scene):
    """``(alpha0, alpha1, y0) -> Refusal | None`` of the learner's scene for an open-loop reach (None:
    no scene). A check without the robot's model (:class:`~.move_check.TaskPointCheck`) judges the
    predicted task point, from the reach's own point ``y0`` (not the learner's): it is made again with
    that point (its ``current``)."""
    if scene is None:
        return None
    if hasattr(scene, "current"):  # (TaskPointCheck, known by its attribute: move_check loads mujoco)
        def at(y0):
            return type(scene)(scene.params, scene.axes, scene.predict, lambda: y0)
        return lambda a0, a1, y0: at(y0).segment(a0, a1)
    return lambda a0, a1, y0: scene.segment(a0, a1)


def start_candidates(learner: EvolvingContextLearner, rest_point: np.ndarray, target: np.ndarray,
                     points: KnownPoints | None = None, k: int = CANDIDATES) -> list[tuple]:
    """Where a reach toward ``target`` may start, nearest first by point: the ``k`` stored end
    postures whose rebuilt point (:mod:`.known_points`) is nearest ``target``, and the rest
    posture at its own distance (so it is tried too when none of them reaches: the fallback).
    :func:`compute_ik` skips a stored posture the scene refuses.

    Parameters
    ----------
    learner : EvolvingContextLearner
        The model (its memory and rest posture).
    rest_point : ndarray, shape (m,)
        The effector's point at rest.
    target : ndarray, shape (m,)
    points : KnownPoints, optional
        The known points of ``learner.memory``, brought up to date here (None: built for this call).
    k : int
        Stored postures to try.

    Returns
    -------
    list of (alpha, point, kind)
        Start posture (n,), its point (m,) and 'stored posture' or 'rest posture'.
    """
    rest_point = np.asarray(rest_point, dtype=float)
    points = (KnownPoints() if points is None else points).update(learner.memory, learner.robot.rest)
    alpha, offset = points.nearest(target - rest_point, k)
    found = [(a, rest_point + o, "stored posture") for a, o in zip(alpha, offset)]
    far = [np.linalg.norm(y - target) for _, y, _ in found]   # (nearest first)
    cut = int(np.searchsorted(far, np.linalg.norm(rest_point - target), side="right"))
    return found[:cut] + [(learner.robot.rest.copy(), rest_point, "rest posture")] + found[cut:]


def compute_ik(learner: EvolvingContextLearner, rest_point, target, start=(), start_point=(),
               tolerance: float = 0.0, max_steps: int = 0, points: KnownPoints | None = None) -> IKAnswer:
    """Joint positions for ``target`` from the model alone (the module docstring); the request is
    assumed checked (:func:`request_problem`).

    Parameters
    ----------
    learner : EvolvingContextLearner
        The model; nothing is stored or changed.
    rest_point : array_like, shape (m,), or None
        The effector's point at rest (None: unknown; then ``start_point`` is needed).
    target : array_like, shape (m,)
    start : array_like, shape (n,) or empty
        A start posture to reach from (empty: the nearest known point's, :func:`start_candidates`).
    start_point : array_like, shape (m,) or empty
        The effector's point at ``start`` (at rest when ``start`` is empty), measured by the caller.
    tolerance, max_steps
        As :func:`~sagg_low_level.evaluate.open_loop_reach` (0: ``eval.tolerance``; the budget).
    points : KnownPoints, optional
        The known points of ``learner.memory``, kept by the caller across calls (None: built for
        this call, which costs a pass over the memory).

    Returns
    -------
    IKAnswer
    """
    target = np.asarray(target, dtype=float)
    if len(start):
        alpha = np.asarray(start, dtype=float)
        if not len(start_point) and rest_point is None:
            return no_rest_point()
        y = np.asarray(start_point, dtype=float) if len(start_point) else predicted_point(learner, rest_point, alpha)
        starts = [(alpha, y, "given")]
    else:
        rest_y = start_point if len(start_point) else rest_point
        if rest_y is None:
            return no_rest_point()
        starts = start_candidates(learner, rest_y, target, points)
    tol = tolerance if tolerance > 0 else learner.p["eval.tolerance"]
    check = scene_check(learner.scene)
    best = None
    for alpha, y, kind in starts:
        if kind == "stored posture" and check is not None and check(alpha, alpha, y) is not None:
            continue  # (a stored posture the scene refuses now: not a start)
        reach = open_loop_reach(learner, alpha, y, target, tol, max_steps, check) + (kind,)
        if best is None or reach[2] < best[2]:
            best = reach
        if reach[4] == "reached":
            best = reach
            break
    return answer(learner, best, tol)


def no_rest_point() -> IKAnswer:
    """The answer when no point is known to start from."""
    return IKAnswer(False, "no rest point: the learner has not measured the effector at rest yet (and the "
                           "model's files hold none); give start and start_point", outcome="no rest point")


def answer(learner: EvolvingContextLearner, reach: tuple, tol: float) -> IKAnswer:
    """The :class:`IKAnswer` of one open-loop reach (``open_loop_reach``'s tuple and where it started)."""
    alpha, y, dist, steps, outcome, refusal, kind = reach
    if outcome == "reached":
        message = f"predicted within {tol:g} of the target"
    elif outcome == "scene":
        message = f"the scene refuses the next step ({refusal.cause}: {refusal.detail})"
    elif outcome == "no model":
        message = f"too few samples for a local model ({len(learner.memory)}; min_samples {learner.min_samples})"
    else:
        message = f"predicted {dist:.4g} from the target after {steps} steps (tolerance {tol:g})"
    message += " (from the given start)" if kind == "given" else f" (from the {kind})"
    return IKAnswer(outcome == "reached", message, alpha, y, dist,
                    nearest_sample(learner.memory, alpha, learner.prior), steps, outcome, kind)


def rest_point_file(directory: Path) -> np.ndarray | None:
    """The rest point of ``directory/model.json`` (None: no file, or it holds none)."""
    path = Path(directory) / REST_POINT_FILE
    if not path.is_file():
        return None
    value = json.loads(path.read_text()).get("rest_point")
    return None if value is None else np.asarray(value, dtype=float)


def write_rest_point(directory: Path, point, source: str) -> None:
    """``directory/model.json`` (atomically): the rest point and where it came from."""
    write_json_atomic(Path(directory) / REST_POINT_FILE,
                      {"rest_point": [float(v) for v in point], "source": source})


def load_model(path: str | Path) -> tuple[SampleMemory, np.ndarray | None, str]:
    """``(memory, rest point or None, what was read)`` of a learned model at ``path``: a run
    directory with its learner checkpoint (``checkpoint/learner.json``), a checkpoint directory, a
    model directory (``memory.npz`` and ``model.json``, as ``sagg serve`` writes), or a ``.npz``
    memory file (its ``model.json`` beside it). ValueError naming what was looked for."""
    p = Path(path)
    for ck in (p / "checkpoint", p):
        if (ck / "learner.json").is_file():
            return checkpoint_memory(ck), rest_point_file(ck), f"the learner checkpoint in {ck}"
    file = p / "memory.npz" if p.is_dir() else p
    if file.is_file():
        return SampleMemory.load(file), rest_point_file(file.parent), str(file)
    raise ValueError(f"'{p}': no learned model (looked for checkpoint/learner.json, learner.json, memory.npz); "
                     "allowed: a run directory with its learner checkpoint, or the model directory of `sagg serve`")
