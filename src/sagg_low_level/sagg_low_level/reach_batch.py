"""The reaching step for many postures at once, on a frozen model (the evaluation's batch). ROS-free.

:func:`reach_steps` returns, row for row, exactly what
:meth:`~sagg_low_level.learner.EvolvingContextLearner.reach_step` returns for one posture (the same
floats, bit for bit), while the memory does not change (the evaluation freezes the model):

* the k nearest samples of every posture with one batch search
  (:func:`sagg_low_level.memory_batch.neighbours_many`, the single search's answers);
* the local Jacobian (:func:`~sagg_low_level.local_model.local_jacobian`, one least-squares fit per
  neighbour set, as the learner, by the compiled :func:`~sagg_low_level.compiled.jacobians`) is
  computed once per distinct ordered neighbour set and kept in ``cache``: the same input rows give
  the same floats, and along a reach (and at the common rest posture) consecutive steps often share
  their neighbours; ``cache`` also keeps it by posture, so a posture met again (a reach stuck at a
  joint limit repeats its posture) needs no search;
* the steps of all rows in one call of the compiled :func:`~sagg_low_level.compiled.reach_steps`,
  the same C routine per row as the learner's single step (the pseudo-inverse or damped step and,
  with ``reach_limits = clamp``, clamped_step's rounds), so each row gives the single step's floats.

Nothing here changes the reaching semantics: the per-goal functions stay the definition, this module
reproduces them faster; test/test_eval_batch.py compares the two on several set-ups.
"""
from __future__ import annotations

import numpy as np

from .compiled import jacobian, jacobians, reach_steps as compiled_steps
from .memory_batch import neighbours_many
from .prior import neighbour_rows


def batch_supported(learner) -> bool:
    """False when the learner's model functions were replaced on the instance (e.g. an analytic
    Jacobian in a lab tool): then only the per-goal path knows what the step is."""
    return not any(name in vars(learner) for name in ("reach_step", "reach_plan", "jacobian_at", "inverse"))


def reach_steps(learner, alphas: np.ndarray, dys: np.ndarray,
                cache: dict | None = None) -> np.ndarray | None:
    """``learner.reach_step(alphas[i], dys[i])`` for every row i, as a (B, n) array; None when the
    memory is too small (reach_step returns None for every row then). ``cache`` (a dict, one per
    frozen model) keeps the Jacobians by neighbour set and by posture across calls."""
    alphas = np.asarray(alphas, dtype=float)
    dys = np.asarray(dys, dtype=float)
    mem = learner.memory
    if learner.model_samples() < learner.min_samples:
        return None
    p = learner.p
    cache = {} if cache is None else cache
    jacs = np.empty((len(alphas), learner.m, alphas.shape[1]))
    # a posture met before (a reach stuck at a limit repeats its posture) has its Jacobian already
    keys = [("posture", a.tobytes()) for a in alphas]
    new = [i for i, key in enumerate(keys) if key not in cache]
    if new and learner.prior is not None:
        _fit_with_prior(learner, alphas, keys, new, cache)
    elif new:
        idx = neighbours_many(mem, alphas[new], learner.k)
        sets = {}  # the new neighbour sets, fitted together below
        for i, row in zip(new, idx):
            key = ("set", row.tobytes())
            if key not in cache:
                sets.setdefault(key, row)
        if sets:
            fitted = jacobians(mem.delta_alpha, mem.delta_y, np.stack(list(sets.values())), p["jacobian_rcond"])
            cache.update(zip(sets, fitted))
        for i, row in zip(new, idx):
            cache[keys[i]] = cache[("set", row.tobytes())]
    for i, key in enumerate(keys):
        jacs[i] = cache[key]
    return compiled_steps(jacs, dys, alphas, learner.robot.lower, learner.robot.upper, p["pinv_rcond"],
                          learner.damping, p["reach_limits"] == "clamp")


def _fit_with_prior(learner, alphas: np.ndarray, keys: list, new: list[int], cache: dict) -> None:
    """The Jacobians of the postures ``new`` for a learner with a prior: each from the merged
    neighbours of :func:`sagg_low_level.prior.neighbour_rows` (the learner's own
    :meth:`~sagg_low_level.learner.EvolvingContextLearner.jacobian_at`), kept by set and posture."""
    rcond = learner.p["jacobian_rcond"]
    for i in new:
        da, dy, set_key = neighbour_rows(learner.memory, learner.prior, alphas[i], learner.k)
        key = ("set", set_key)
        if key not in cache:
            cache[key] = jacobian(da, dy, None, rcond)
        cache[keys[i]] = cache[key]
