"""Exact k-nearest-neighbour sets of stored samples, kept up to date as the memory grows. ROS-free.

The fixed-context reaching phase (Sec. 4.4.1) asks, for each of the l outcomes closest to a goal,
the m nearest stored synergies θ of that sample (the sets M_i). The same samples are asked again
and again (goals of a region share their neighbours), with many experiments added in between (a
median of ~300 on the 7-DOF arm, issue 10). So the cached sets are kept current as samples arrive:
each new sample's canonical squared distance to every cached set's own sample is computed in one
array operation, and the sample is inserted into the sets it enters (those whose m-th member is
farther), all of them in one array operation too. The m nearest of all samples are the m nearest
of (the old m nearest ∪ the new one), because every other old sample already ranks after the old
m-th; distances are the memory's own (:func:`sagg_low_level.memory_distance.squared_distances`:
the same sum over the coordinates in index order, and (a − b)² = (b − a)² exactly) and ties are
broken by index as the memory does (a new sample has the largest index, so it goes after equal
distances). The answer is therefore bit-identical to ``memory.neighbours(alpha[i], k)`` (tested in
test/test_neighbour_sets.py). Speed only.
"""
from __future__ import annotations

from collections import deque

import numpy as np

from .memory import SampleMemory
from .memory_distance import _sqdist_cols, squared_distances


class NeighbourSets:
    """``get(i)`` = ``memory.neighbours(memory.alpha[i], k)`` for a stored sample i, cached.

    ``max_entries`` bounds the number of cached sets (the oldest is dropped first), and with it the
    cost of taking in one new sample (one distance per cached set)."""

    def __init__(self, memory: SampleMemory, k: int, max_entries: int = 8192):
        if k < 1:
            raise ValueError(f"k must be >= 1, got {k}")
        if max_entries < 1:
            raise ValueError(f"max_entries must be >= 1, got {max_entries}")
        self.memory = memory
        self.k = int(k)
        self.max_entries = int(max_entries)
        self._row: dict[int, int] = {}           # sample index -> row of the tables below
        self._sample: list[int] = []             # row -> sample index
        self._age: deque[int] = deque()          # cached sample indices, oldest first
        cap = 16
        self._q = np.empty((memory.state_dim, cap))  # row's alpha, dimension-major (canonical layout)
        # row's set by (squared distance, index); a set shorter than k (a small memory) is padded
        # with distance inf and index -1, so the k-th distance is inf until it is full
        self._d = np.empty((cap, self.k))
        self._idx = np.empty((cap, self.k), dtype=np.int64)
        self._cols = np.arange(self.k)
        self._seen = 0                           # samples taken into every cached set
        self.hits = 0      # answered from the cache (statistics only)
        self.searches = 0  # searched in the index

    def __len__(self) -> int:
        return len(self._sample)

    def _take_new_samples(self) -> None:
        """Insert every sample added since the last call into the cached sets it enters."""
        mem = self.memory
        n, rows = len(mem), len(self._sample)
        if rows == 0:
            self._seen = n
            return
        alpha, q, d_all, idx_all, cols = mem.alpha, self._q[:, :rows], self._d, self._idx, self._cols
        for j in range(self._seen, n):
            dist = _sqdist_cols(q, alpha[j])
            enter = np.flatnonzero(dist < d_all[:rows, -1])
            if not len(enter):
                continue
            dj = dist[enter][:, None]
            d, idx = d_all[enter], idx_all[enter]
            at = (d <= dj).sum(axis=1)[:, None]            # after equal distances (larger index)
            before = cols < at
            d_all[enter, 1:] = np.where(before[:, 1:], d[:, 1:], d[:, :-1])
            idx_all[enter, 1:] = np.where(before[:, 1:], idx[:, 1:], idx[:, :-1])
            hit = cols == at
            d_all[enter] = np.where(hit, dj, d_all[enter])
            idx_all[enter] = np.where(hit, j, idx_all[enter])
        self._seen = n

    def _drop_oldest(self) -> None:
        """Forget the oldest cached set: the last row moves into its place."""
        i = self._age.popleft()
        r, last = self._row.pop(i), len(self._sample) - 1
        if r != last:
            moved = self._sample[last]
            self._sample[r] = moved
            self._q[:, r], self._d[r], self._idx[r] = self._q[:, last], self._d[last], self._idx[last]
            self._row[moved] = r
        del self._sample[last]

    def get(self, i: int) -> np.ndarray:
        self._take_new_samples()
        r = self._row.get(i)
        if r is not None:
            self.hits += 1
            idx = self._idx[r]
            return idx.copy() if idx[-1] >= 0 else idx[idx >= 0]
        self.searches += 1
        mem = self.memory
        q = mem.alpha[i]
        idx = mem.neighbours(q, self.k)
        d = squared_distances(mem.alpha[idx], q)
        if len(self._sample) >= self.max_entries:
            self._drop_oldest()
        rows = len(self._sample)
        if rows == len(self._d):
            self._q = np.concatenate((self._q, np.empty_like(self._q)), axis=1)
            self._d = np.concatenate((self._d, np.empty_like(self._d)))
            self._idx = np.concatenate((self._idx, np.empty_like(self._idx)))
        self._q[:, rows] = q
        self._d[rows] = np.inf
        self._idx[rows] = -1
        self._d[rows, :len(d)] = d
        self._idx[rows, :len(idx)] = idx
        self._row[i] = rows
        self._sample.append(i)
        self._age.append(i)
        return idx
