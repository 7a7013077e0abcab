"""Exact k nearest stored samples of stored samples, kept from one search to the next: the
fixed-context learner's θ-neighbour sets M_i of its l seeds (Sec. 4.4.1). ROS-free.

``StoredKnn(index).query(rows, k)[j]`` is ``index.query(memory.alpha[rows], k)[j]`` (the memory's
exact answer, :class:`~sagg_low_level.tree_knn.TreeKnn`), bit for bit, found another way, for speed
only: a seed is mostly a sample that was a seed before (docs/notes/compiled-loop.md), with few
samples stored in between, and the memory only grows, so a kept answer over samples 0 .. n0 - 1 plus
the samples stored since gives the answer over all of them:

* the kept answer is the first k of 0 .. n0 - 1 by (canonical distance, index), with its canonical
  distances (:mod:`.memory_distance`'s arithmetic);
* a sample stored since has a larger index than every kept one, so it enters when its distance is
  below the k-th (a tie goes to the older sample), after every kept entry of equal distance;
  this merge is one compiled call for all rows (``knn_kernel.stored_refresh``, knn_kernel.c);
* a row with no kept answer, or more than ``refresh_limit`` samples stored since (then the index's
  own search is cheaper than the scan), is asked of the index, and its answer kept.

A query with another k forgets what was kept. The memory is read, never written.
"""
from __future__ import annotations

import numpy as np

from .compiled import knn_kernel
from .tree_knn import TreeKnn


class StoredKnn:
    """``query(rows, k)`` = ``index.query(index.memory.alpha[rows], k)`` for stored samples ``rows``."""

    def __init__(self, index: TreeKnn, refresh_limit: int = 4096):
        self.index = index
        self.refresh_limit = int(refresh_limit)
        self._k = 0  # the k of the kept answers (0: nothing kept)
        self._slot_of = np.full(0, -1, dtype=np.int64)  # sample -> its slot, -1 when none
        self._slots = 0  # slots in use
        self._n0 = np.empty(0, dtype=np.int64)  # per slot: samples 0 .. n0 - 1 are in its answer
        self._cnt = np.empty(0, dtype=np.int64)  # per slot: entries kept (min(k, n0))
        self._idx = np.empty((0, 0), dtype=np.int64)  # per slot: the kept answer, (distance, index) order
        self._dist = np.empty((0, 0))  # per slot: its canonical squared distances
        self.kept = 0  # rows answered from a kept answer (statistics only)
        self.asked = 0  # rows asked of the index

    @property
    def nbytes(self) -> int:
        """Bytes held by the kept answers."""
        return int(self._slot_of.nbytes + self._n0.nbytes + self._cnt.nbytes + self._idx.nbytes
                   + self._dist.nbytes)

    def _forget(self, k: int) -> None:
        self._k, self._slots = k, 0
        self._slot_of[:] = -1
        self._idx = np.empty((len(self._n0), k), dtype=np.int64)
        self._dist = np.empty((len(self._n0), k))

    def _grow(self, n: int, slots: int) -> None:
        """Room for ``n`` samples and ``slots`` slots (capacities double)."""
        if len(self._slot_of) < n:
            grown = np.full(max(n, 2 * len(self._slot_of)), -1, dtype=np.int64)
            grown[: len(self._slot_of)] = self._slot_of
            self._slot_of = grown
        if len(self._n0) < slots:
            cap = max(slots, 2 * len(self._n0), 64)
            for name in ("_n0", "_cnt", "_idx", "_dist"):
                old = getattr(self, name)
                new = np.empty((cap,) + old.shape[1:], dtype=old.dtype)
                new[: len(old)] = old
                setattr(self, name, new)

    def query(self, rows, k: int) -> np.ndarray:
        """(B, min(k, len)) int64: row j = the memory's exact ``neighbours(alpha[rows[j]], k)``."""
        rows = np.ascontiguousarray(rows, dtype=np.int64).reshape(-1)
        alpha = self.index.memory.alpha
        n = len(alpha)
        if len(rows) and (rows.min() < 0 or rows.max() >= n):
            raise ValueError(f"rows must be stored samples 0 .. {n - 1}")
        if int(k) != self._k:
            self._forget(int(k))
        kk = min(int(k), n)
        if kk < 1 or not len(rows):
            return np.empty((len(rows), max(kk, 0)), dtype=np.int64)
        self._grow(n, self._slots)
        out = np.empty((len(rows), kk), dtype=np.int64)
        miss = np.empty(len(rows), dtype=np.int64)
        m = knn_kernel.stored_refresh(alpha, rows, kk, self.refresh_limit, self._slot_of, self._n0, self._cnt,
                                      self._idx, self._dist, out, miss)
        self.kept += len(rows) - m
        if m:
            self.asked += m
            at = miss[:m]
            ask = rows[at]
            ans = self.index.query(alpha[ask], kk)
            out[at] = ans
            ask, first = np.unique(ask, return_index=True)  # a row asked twice is kept once
            slots = self._slot_of[ask]
            new = slots < 0
            if new.any():
                slots[new] = np.arange(self._slots, self._slots + int(new.sum()))
                self._slots += int(new.sum())
                self._grow(n, self._slots)
                self._slot_of[ask[new]] = slots[new]
            knn_kernel.stored_keep(alpha, ask, np.ascontiguousarray(ans[first]), slots, self._n0, self._cnt,
                                   self._idx, self._dist)
        return out
