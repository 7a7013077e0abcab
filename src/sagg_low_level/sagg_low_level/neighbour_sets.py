"""Exact k-nearest-neighbour sets of stored samples, kept up to date as the memory grows. ROS-free.

The fixed-context reaching phase (Sec. 4.4.1) asks, for each of the l outcomes closest to a goal,
the m nearest stored synergies θ of that sample (the sets M_i). The same samples are asked again
and again (goals of a region share their neighbours) while only a few experiments were added in
between. A set found once stays the answer until a newer sample comes closer than its m-th member:
the m nearest of all samples are the m nearest of (the old m nearest ∪ the samples added since),
because every other old sample already ranks after the old m-th. So a cached set is updated from
the new samples alone, in the memory's own canonical distances and (distance, index) order
(:func:`sagg_low_level.memory_distance.squared_distances`): the answer is bit-identical to
``memory.neighbours(alpha[i], k)`` (tested in test/test_neighbour_sets.py). Speed only.
"""
from __future__ import annotations

import numpy as np

from .memory import SampleMemory
from .memory_distance import squared_distances


class NeighbourSets:
    """``get(i)`` = ``memory.neighbours(memory.alpha[i], k)`` for a stored sample i, cached.

    ``max_entries`` bounds the number of cached sets (oldest dropped first); ``max_gap``: when more
    samples than this were added since a set was found, it is searched afresh in the index instead
    (a scan of that many new samples would cost more than the index query)."""

    def __init__(self, memory: SampleMemory, k: int, max_entries: int = 8192, max_gap: int = 4096):
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        self.memory = memory
        self.k = int(k)
        self.max_entries = int(max_entries)
        self.max_gap = int(max_gap)
        # sample index -> (memory size when last updated, neighbour indices, their squared distances)
        self._sets: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
        self.hits = 0     # answered from the cache (statistics only)
        self.searches = 0  # searched in the index

    def get(self, i: int) -> np.ndarray:
        mem = self.memory
        n = len(mem)
        q = mem.alpha[i]
        entry = self._sets.get(i)
        if entry is not None and n - entry[0] <= self.max_gap:
            n_at, idx, d = entry
            if n_at < n:
                new_d = squared_distances(mem.alpha[n_at:n], q)
                if len(idx) < self.k or np.any(new_d < d[-1]):
                    cand_i = np.concatenate((idx, np.arange(n_at, n)))
                    cand_d = np.concatenate((d, new_d))
                    order = np.lexsort((cand_i, cand_d))[: self.k]
                    idx, d = cand_i[order], cand_d[order]
                self._sets[i] = (n, idx, d)
            self.hits += 1
            return idx
        self.searches += 1
        idx = mem.neighbours(q, self.k)
        d = squared_distances(mem.alpha[idx], q)
        if entry is None and len(self._sets) >= self.max_entries:
            self._sets.pop(next(iter(self._sets)))
        self._sets[i] = (n, idx, d)
        return idx
