"""The evaluation, defined once: procedure and metrics (paper Sec. 3.7, 4.6, 5.3). ROS-free.

Procedure (every set-up, every strategy, every seed the same):

* **Test goals.** ``eval.goals`` (100) goals fixed by ``eval.seed`` alone, never by the run seed or the
  strategy, so every run of a comparison is scored on the same set.
  - Arm (evolving context, Sec. 3.7: "uniformly distributed in the reachable area"):
    :func:`sagg_sim_bridge.arm.test_goals`: actually reached tip positions, one per reachable grid
    cell drawn uniformly (grid of ``total_length/100``).
  - Synergy set-ups (quadruped, fishing rod; Sec. 4.6 "covering approximately uniformly the
    reachable part of the task space"): :func:`sagg_low_level.outcome_set.reachable_outcomes`
    estimates the reachable outcome set with a strategy-independent sampler (uniform synergies,
    then rounds that re-draw synergies from sparsely hit cells and perturb them, which evens the
    sample density out and pushes it to the set's edges); :func:`spread_goals` then takes the goals
    cell by cell over that set, so their density is uniform over the estimated support and not the
    density of random synergies (where ACTUATOR-RANDOM samples).
* **Reaching, frozen model.** From the rest posture, with reaching steps only (no exploration, no
  learning, nothing stored), on a simulator instance of its own:
  - arm: :func:`sagg_low_level.evaluate.reach_frozen`. **Budget** ``ceil(eval.timeout_factor ×
    D(y_rest, goal) / v)`` reaching steps (default factor 5); **stopping**: early when the tip is
    within ``eval.tolerance`` of the goal or the model has no Jacobian yet; the score is the
    **final** distance D(goal, y_final), not the best one seen (the paper: "the final state of a
    reaching attempt"). Each test goal has its own evaluation arm (motor noise from the goal's own
    stream, so a goal's score does not depend on the other goals), and all goals are advanced
    together (:func:`sagg_low_level.evaluate.evaluate_batch`: the same floats as goal after goal,
    the model's work batched; ``sagg_bringup.inprocess.arm_eval``).
  - synergies: :func:`sagg_low_level.fixed_context.evaluate_fixed`: one synergy θ from the reaching
    phase, run once from rest; a trial without outcome scores as the rest outcome.
* **Metrics** (:func:`error_metrics`, computed at every evaluation point of a curve and stored in
  ``result.json``): the **mean** final distance (the paper's metric, Figs. 10-12, 17, 21), the
  **median**, the **share of goals within** ``within_fraction`` × R, and the **mean error per band of
  distance from the base**: four bands of equal width over [0, R], where R is the largest distance
  from the base to a test goal. The base is the arm's base (the origin) for the arm and the rest
  outcome for the synergy set-ups. R makes the tolerance and the bands scale with the set-up (the
  50-unit arm: R ≈ 50, tolerance 1 unit = v/2, bands of 12.5 units).

Why the budget is ``5 × D/v`` (a choice: the paper gives none). Principle: the evaluation scores
the inverse model, so its budget must not cut off a reach that is still converging, for any
strategy; it must not depend on what a strategy learned. From a sweep of the factor on the 15-DOF
arm (docs/notes/evaluation.md): at 2 × D/v more than half of the SAGG strategies' test reaches are
still under way when the budget ends, so that budget scores reaching speed too, and that part falls
on SAGG; at 5 × D/v the median reach of every strategy ends by the early stop, and 10 × D/v changes
the strategies' means little. The learning itself is the same under every budget (identical memory
digests).
"""
from __future__ import annotations

import numpy as np

# Choices (documented above and in docs/notes/evaluation.md): not learning parameters, only how a vector of
# final distances is summarised; every strategy gets the same.
WITHIN_FRACTION = 0.02
BAND_EDGES = (0.0, 0.25, 0.5, 0.75, 1.0)


def metric_frame(goals: np.ndarray, base, within_fraction: float = WITHIN_FRACTION,
                 band_edges=BAND_EDGES) -> dict:
    """What the metrics of a test-goal set are measured against: the base, R (the largest distance
    from the base to a goal), the tolerance (``within_fraction`` × R), the absolute band edges and
    the band of each goal (index into the bands; the last band is closed)."""
    g = np.asarray(goals, dtype=float)
    b = np.asarray(base, dtype=float).reshape(-1)
    if g.ndim != 2 or g.shape[1] != b.size:
        raise ValueError(f"goals must have shape (N, {b.size}), got {g.shape}")
    if not 0.0 < within_fraction <= 1.0:
        raise ValueError(f"within_fraction must be in (0, 1], got {within_fraction!r}")
    fr = np.asarray(band_edges, dtype=float)
    if fr.ndim != 1 or len(fr) < 2 or fr[0] != 0.0 or fr[-1] != 1.0 or np.any(np.diff(fr) <= 0):
        raise ValueError(f"band_edges must increase from 0 to 1, got {band_edges!r}")
    dist = np.linalg.norm(g - b, axis=1)
    radius = float(dist.max()) if len(dist) else 0.0
    edges = fr * radius
    band = np.clip(np.searchsorted(edges, dist, side="right") - 1, 0, len(edges) - 2)
    return {"base": b.tolist(), "radius": radius, "within": within_fraction * radius,
            "within_fraction": within_fraction, "band_edges": edges.tolist(),
            "band_counts": np.bincount(band, minlength=len(edges) - 1).tolist(),
            "band_of_goal": band.tolist()}


def error_metrics(errors: np.ndarray, frame: dict) -> dict:
    """The evaluation's metrics for one vector of final distances (one per test goal, in the order
    of the goals ``frame`` was built from): mean (the paper's), median, share within tolerance, and
    the mean error per distance-from-base band (None for a band without goals)."""
    e = np.asarray(errors, dtype=float)
    band = np.asarray(frame["band_of_goal"], dtype=int)
    if e.shape != band.shape:
        raise ValueError(f"errors: {e.shape[0] if e.ndim else 0} values for {len(band)} test goals")
    bands = [float(e[band == i].mean()) if np.any(band == i) else None
             for i in range(len(frame["band_counts"]))]
    return {"mean_error": float(e.mean()), "median_error": float(np.median(e)),
            "within_share": float(np.mean(e <= frame["within"])), "band_mean_errors": bands}


def frame_summary(frame: dict) -> dict:
    """``frame`` without the per-goal band indices (what result.json keeps as ``eval_metrics``)."""
    return {k: v for k, v in frame.items() if k != "band_of_goal"}
