"""Exact k nearest stored samples of a growing sample store (:class:`~sagg_low_level.memory.SampleMemory`
or the index-free :class:`~sagg_low_level.memory.SampleTable`), many queries per call: the
fixed-context learner's searches (outcomes in 2-3 dims, synergies in 4-24). ROS-free.

The answer is SampleMemory's exact one, ``neighbours(q, k)`` bit for bit: the min(k, len)
stored alpha nearest to q in the canonical squared distance (:mod:`.memory_distance`), ordered by
(distance, index), ties included (tested in test/test_tree_knn.py). It is found another way, for
speed only (the memory's index is built for 15-30-D trajectories, one query per call):

* a kd tree over the samples stored at its last build (``knn_kernel.kd_build``: balanced median
  splits along the widest coordinate, leaves of at most ``leafsize`` samples (64, the fastest of
  8-64 for queries and builds on the fixed-context arm: docs/notes/compiled-loop.md), every node's
  exact box) is searched depth first, nearer child first, a node skipped only when its box is
  farther than the k-th distance found so far; the samples stored since (fewer than
  ``rebuild_share`` of the memory, or ``min_recent``) are scanned first. Box bounds and distances
  use the canonical arithmetic, so the bound never exceeds a member's distance and no float slack is
  needed; the first k by (distance, index) are kept (``knn_kernel.kd_query``, one compiled call per
  query batch). Not ``scipy.spatial.cKDTree``: its per-query overhead is large even for one 2-D
  row, and its own distances would need a check against the canonical k-th distance and full scans
  on ties.

The memory is read, never written; the index notices new samples by the memory's length.
"""
from __future__ import annotations

import numpy as np

from .compiled import knn_kernel
from .memory_store import SampleStore


def split_levels(n: int, leafsize: int) -> int:
    """The fewest levels of halving splits that leave at most ``leafsize`` of ``n`` samples in a leaf."""
    depth = 0
    while -(-n // (1 << depth)) > leafsize:
        depth += 1
    return depth


class TreeKnn:
    """``query(Q, k)[j]`` = ``SampleMemory.neighbours(Q[j], k)`` over the same samples, exact, for a
    growing store."""

    def __init__(self, memory: SampleStore, min_recent: int = 64, rebuild_share: float = 1 / 32,
                 leafsize: int = 64):
        if int(leafsize) < 1:
            raise ValueError(f"leafsize must be >= 1, got {leafsize}")
        self.memory = memory
        self.min_recent = int(min_recent)
        self.rebuild_share = float(rebuild_share)
        self.leafsize = int(leafsize)
        dim = memory.state_dim
        self._nt = 0  # samples in the tree: indices 0 .. _nt - 1
        self._split_levels = 0
        self._tree = self._arrays(0, dim, 0)  # kd_build's arrays (empty tree)
        self._recent_t = np.empty((dim, 0))  # the samples stored since (a prefix), dimension-major
        self._nr = 0
        self.leaves_scanned = 0  # statistics only

    @staticmethod
    def _arrays(nt: int, dim: int, depth: int) -> tuple:
        """(perm, pts_t, lo, hi, nstart, nend) of a tree of ``nt`` samples and ``depth`` split levels."""
        nodes = (2 << depth) - 1
        return (np.empty(nt, dtype=np.int64), np.empty((dim, nt)), np.empty((nodes, dim)),
                np.empty((nodes, dim)), np.zeros(nodes, dtype=np.int64), np.zeros(nodes, dtype=np.int64))

    @property
    def nbytes(self) -> int:
        """Bytes held by the index: the tree's arrays and the recent samples' copy."""
        return int(sum(a.nbytes for a in self._tree) + self._recent_t.nbytes)

    def _update(self, n: int) -> None:
        """Rebuild the tree when the samples stored since its build exceed the allowed share, else
        copy the newest samples into the recent part."""
        nt = self._nt
        if n - nt > max(self.min_recent, int(self.rebuild_share * n)):
            alpha = np.ascontiguousarray(self.memory.alpha)
            depth = split_levels(n, self.leafsize)
            tree = self._arrays(n, alpha.shape[1], depth)
            knn_kernel.kd_build(alpha, depth, *tree)
            self._tree, self._split_levels = tree, depth
            self._nt, self._nr = n, 0
            return
        if nt + self._nr < n:
            if self._recent_t.shape[1] < n - nt:
                grown = np.empty((self._recent_t.shape[0], 2 * (n - nt)))
                grown[:, : self._nr] = self._recent_t[:, : self._nr]
                self._recent_t = grown
            self._recent_t[:, self._nr : n - nt] = self.memory.alpha[nt + self._nr :].T
            self._nr = n - nt

    def query(self, queries: np.ndarray, k: int) -> np.ndarray:
        """(B, min(k, len)) int64: row j = the memory's exact ``neighbours(queries[j], k)``."""
        qs = np.asarray(queries, dtype=np.float64)
        b, dim = qs.shape
        want = self._recent_t.shape[0]
        if dim != want or not np.isfinite(qs).all():
            raise ValueError(f"queries must be finite, of shape (B, {want}), got {qs.shape}")
        n = len(self.memory)
        k = min(int(k), n)
        if k < 1 or not b:
            return np.empty((b, max(k, 0)), dtype=np.int64)
        self._update(n)
        out = np.empty((b, k), dtype=np.int64)
        self.leaves_scanned += knn_kernel.kd_query(np.ascontiguousarray(qs), k, *self._tree,
                                                   self._split_levels, self._recent_t, self._nr, out)
        return out
