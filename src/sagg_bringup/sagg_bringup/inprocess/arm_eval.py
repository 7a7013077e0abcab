"""The arm's evaluation on the simulator: one evaluation arm per test goal, all goals reached together.

Used by ``sagg experiment`` / ``bench compare`` (``InProcessRun.evaluate``) and by the graph's
evaluation process alike, so both score the same way (sagg_low_level/eval_metrics.py, docs/notes/evaluation.md).

Test goal i is reached from rest on its own ``ArmSim`` whose motor noise comes from its own stream,
``substream_seed(seed, "eval_sim/<i>")``: a goal's noise is fixed by the run seed and its index alone.
With one simulator reaching the goals one after the other, goal i's noise (config/arm8.yaml) would
depend on how many steps the model used on goals 0..i-1, so a goal's score would depend on the
others and its noise would differ between strategies; with one arm per goal the goals can also be
reached in a batch (:func:`sagg_low_level.evaluate.evaluate_batch`). Noise-free arms (motor_noise 0,
every other config) have no random draw in their evaluation. The arms are kept per process and
reseeded for each evaluation (building 100 MuJoCo arms costs more than a batched evaluation of a
5k-sample model).
"""
from __future__ import annotations

import numpy as np

from sagg_common.rng import substream_seed
from sagg_low_level.evaluate import evaluate_batch, evaluate_per_goal
from sagg_sim_bridge.arm import ArmSim
from sagg_sim_bridge.arms import make_arm_sim

_POOLS: dict[str, list[ArmSim]] = {}


def goal_noise_seed(seed: int, i: int) -> int:
    """The motor-noise seed of test goal ``i``'s evaluation arm."""
    return substream_seed(seed, f"eval_sim/{i}")


def eval_arms(spec, seed: int, n: int) -> list[ArmSim]:
    """``n`` evaluation arms of ``spec``, arm i with the noise stream of test goal i of run ``seed``
    (reused across calls in this process; each reach starts with ``reset``)."""
    key = repr(spec)
    pool = _POOLS.get(key)
    if pool is None:
        if len(_POOLS) >= 4:
            _POOLS.pop(next(iter(_POOLS)))
        pool = _POOLS[key] = []
    while len(pool) < n:
        pool.append(make_arm_sim(spec, seed=0))
    arms = pool[:n]
    if spec.motor_noise > 0:
        for i, arm in enumerate(arms):
            arm.reseed(goal_noise_seed(seed, i))
    return arms


def evaluate_arm(learner, spec, seed: int, goals: np.ndarray, batched: bool = True) -> np.ndarray:
    """Final distances of the frozen model on ``goals`` (one evaluation arm per goal; batched or,
    for comparison, goal by goal: the same floats)."""
    goals = np.asarray(goals, dtype=float)
    arms = eval_arms(spec, seed, len(goals))
    return (evaluate_batch if batched else evaluate_per_goal)(learner, arms, goals)
