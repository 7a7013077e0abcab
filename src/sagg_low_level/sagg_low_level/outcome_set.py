"""The reachable outcome set of a synergy set-up, estimated independently of every strategy. ROS-free.

The test goals of the quadruped and the fishing rod must cover "approximately uniformly the reachable
part of the task space" (paper Sec. 4.6, 5.3), but that part is not known beforehand. Outcomes of
uniformly random synergies are not enough: they pile up where random synergies land (where
ACTUATOR-RANDOM samples) and rarely reach the set's edges (on the quadruped, SAGG-RIAC's own
outcomes span a far wider range of u than a random pool). Goals drawn from them favour the strategy
that samples like them.

Method (our choice, the synergy analogue of :func:`sagg_sim_bridge.arm.reachable_area`): a first
batch of uniformly random synergies; then ``rounds`` batches, each re-drawing earlier synergies with
probability ∝ (number of outcomes in their outcome cell)^-2 (sparse cells, which lie at the edges,
are drawn more often than dense ones, however many outcomes these hold) and perturbing them with
Gaussian noise of a log-uniform scale (1 %..30 % of each θ range). This evens the sample density out
and pushes it to the edges of the set. Every outcome is one actually produced by the simulator, so
the estimate can only miss reachable parts, never invent them. It uses its own seeded stream and no
strategy's data; all strategies and seeds get the same set.
"""
from __future__ import annotations

from typing import Callable

import numpy as np


def grid_cells(points: np.ndarray, bins: int) -> np.ndarray:
    """Flat cell index of each point on a grid of ``bins`` cells per dimension over the points'
    bounding box."""
    pts = np.asarray(points, dtype=float)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    cells = np.minimum((bins * (pts - lo) / span).astype(int), bins - 1)
    return np.ravel_multi_index(cells.T, (bins,) * pts.shape[1])


def reachable_outcomes(run_theta: Callable[[np.ndarray], np.ndarray | None], theta_lower, theta_upper,
                       total: int, rounds: int, rng: np.random.Generator, bins: int = 8,
                       noise: tuple[float, float] = (0.01, 0.3)) -> np.ndarray:
    """Outcomes of ``total`` synergy executions spread over the reachable outcome set (module
    docstring); ``rounds`` = 0 gives the plain uniform-synergy sample. Executions without an
    outcome (``run_theta`` returns None: no water contact) are dropped."""
    lo = np.asarray(theta_lower, dtype=float)
    hi = np.asarray(theta_upper, dtype=float)
    if total < 1 or rounds < 0:
        raise ValueError(f"total must be >= 1 and rounds >= 0, got {total}, {rounds}")
    sizes = np.full(rounds + 1, total // (rounds + 1))
    sizes[: total - int(sizes.sum())] += 1
    thetas, outs = [], []

    def run(batch: np.ndarray) -> None:
        for th in batch:
            y = run_theta(th)
            if y is not None:
                thetas.append(th)
                outs.append(np.asarray(y, dtype=float))

    run(rng.uniform(lo, hi, size=(int(sizes[0]), lo.size)))
    for n in sizes[1:]:
        if not outs or n == 0:
            run(rng.uniform(lo, hi, size=(int(n), lo.size)))
            continue
        keys = grid_cells(np.array(outs), bins)
        _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
        w = counts[inverse] ** -2.0
        pick = rng.choice(len(outs), size=int(n), p=w / w.sum())
        scale = np.exp(rng.uniform(np.log(noise[0]), np.log(noise[1]), size=(int(n), 1))) * (hi - lo)
        run(np.clip(np.array(thetas)[pick] + rng.normal(size=(int(n), lo.size)) * scale, lo, hi))
    if not outs:
        return np.zeros((0, 0))
    return np.array(outs)
