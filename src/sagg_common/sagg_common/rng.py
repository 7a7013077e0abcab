"""Explicit, named random streams: no global RNG anywhere in sagg.

Every component gets its own ``numpy.random.Generator`` derived from the run seed and a stable
component name, so adding a component never shifts another component's stream, and the graph and
the in-process loop draw identical numbers.
"""
from __future__ import annotations

import hashlib
import math

import numpy as np


def stream(seed: int, name: str) -> np.random.Generator:
    """A Generator for component ``name`` of a run seeded with ``seed`` (deterministic)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: got {seed!r}; allowed: an integer >= 0")
    key = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")
    return np.random.default_rng(np.random.SeedSequence([int(seed), key]))


def substream_seed(seed: int, name: str) -> int:
    """An integer seed for a component that takes an int (e.g. a simulator), derived like :func:`stream`."""
    return int(stream(seed, name).integers(0, 2**31 - 1))


def choice_index(rng: np.random.Generator, p: np.ndarray) -> int:
    """``int(rng.choice(len(p), p=p))`` for probabilities ``p`` this code built itself (non-negative,
    summing to 1), the same index from the same draw, without the argument checks that dominate the
    call's cost: numpy draws one ``rng.random()`` and takes the first index whose normalised
    cumulative sum exceeds it (``Generator.choice``, numpy 2.x; test/test_rng.py checks the two
    agree draw for draw)."""
    cdf = np.cumsum(p, dtype=float)
    total = float(cdf[-1])
    if not 0.0 < total < math.inf or cdf.min() < 0.0:
        raise ValueError(f"probabilities: got {np.asarray(p)!r}; allowed: non-negative, finite, not all 0")
    cdf /= total
    return int(cdf.searchsorted(rng.random(), side="right"))


def uniform_in(rng: np.random.Generator, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """``rng.uniform(lower, upper)`` for two equal-length 1-D float bound arrays this code built itself
    (finite, ``lower <= upper``), the same floats from the same draws, without the broadcasting and
    argument checks that dominate the call's cost: numpy computes each element as
    ``low + (high - low) * next_double`` in C order (``Generator.uniform``, numpy 2.x), which is what
    ``rng.random(n)`` draws; test/test_rng.py checks the two agree draw for draw."""
    return lower + (upper - lower) * rng.random(len(lower))
