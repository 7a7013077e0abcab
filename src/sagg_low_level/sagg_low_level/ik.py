"""Inverse kinematics from the learned model alone: what ``/sagg/compute_ik`` answers. ROS-free.

A target point of Y -> joint positions, with no motion: the frozen model's reach run open loop
(:func:`~sagg_low_level.evaluate.open_loop_reach`: the reaching steps of the evaluation, each
answered by the local forward model's prediction instead of a measurement) from a start posture,
the rest posture by default. The answer says how far to trust it: the predicted point and its
distance to the target, the distance in joint space to the nearest stored posture (how far the
answer extrapolates from what was experienced), and a success flag (predicted within tolerance,
within the joint limits, allowed by the scene).

The model's samples are displacements (α, Δα, Δy): a point needs one point to start from. That is
the effector's point at the rest posture, measured by the learner at its returns to rest (its
*rest point*), or a point the caller measured at its start posture. A start posture given without
its point is reached from rest on the model (:func:`predicted_point`).

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
from .learner import EvolvingContextLearner, step_toward, stepped_move_limit
from .memory import SampleMemory

REST_POINT_FILE = "model.json"  # beside a memory.npz: {"rest_point": [...], "source": "..."}


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


def nearest_sample(memory: SampleMemory, alpha: np.ndarray) -> float:
    """Distance (rad, Euclidean in joint space) from ``alpha`` to the nearest stored posture (the
    memory's own search: approximate with ``neighbour_checks`` > 0); NaN for an empty memory."""
    if not len(memory):
        return math.nan
    i = int(memory.neighbours(alpha, 1)[0])
    return float(np.linalg.norm(memory.alpha[i] - alpha))


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


def compute_ik(learner: EvolvingContextLearner, rest_point, target, start=(), start_point=(),
               tolerance: float = 0.0, max_steps: int = 0) -> IKAnswer:
    """Joint positions for ``target`` from the model alone (the module docstring); the request is
    assumed checked (:func:`request_problem`). ``rest_point``: the effector's point at rest (None:
    unknown; then ``start_point`` is needed)."""
    target = np.asarray(target, dtype=float)
    alpha = np.asarray(start, dtype=float) if len(start) else learner.robot.rest.copy()
    if len(start_point):
        y = np.asarray(start_point, dtype=float)
    elif rest_point is None:
        return IKAnswer(False, "no rest point: the learner has not measured the effector at rest yet (and the "
                               "model's files hold none); give start and start_point", outcome="no rest point")
    else:
        y = predicted_point(learner, rest_point, alpha) if len(start) else np.asarray(rest_point, dtype=float)
    tol = tolerance if tolerance > 0 else learner.p["eval.tolerance"]
    alpha, y, dist, steps, outcome, refusal = open_loop_reach(learner, alpha, y, target, tol, max_steps,
                                                             scene_check(learner.scene))
    success = outcome == "reached"
    if outcome == "reached":
        message = f"predicted within {tol:g} of the target"
    elif outcome == "scene":
        message = f"the scene refuses the next step ({refusal.cause}: {refusal.detail})"
    elif outcome == "no model":
        message = f"too few samples for a local model ({len(learner.memory)}; min_samples {learner.min_samples})"
    else:
        message = f"predicted {dist:.4g} from the target after {steps} steps (tolerance {tol:g})"
    return IKAnswer(success, message, alpha, y, dist, nearest_sample(learner.memory, alpha), steps, outcome)


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
