"""Exact k nearest stored samples of a growing sample store (:class:`~sagg_low_level.memory.SampleMemory`
or the index-free :class:`~sagg_low_level.memory.SampleTable`), many queries per call: the
fixed-context learner's searches (outcomes in 2-3 dims, synergies in 4-24). ROS-free.

The answer is SampleMemory's exact one, ``neighbours(q, k)`` bit for bit: the min(k, len)
stored alpha nearest to q in the canonical squared distance (:mod:`.memory_distance`), ordered by
(distance, index), ties included (tested in test/test_tree_knn.py). It is found another way, for
speed only (the memory's index is built for 15-30-D trajectories, one query per call):

* a static ``scipy.spatial.cKDTree`` over the samples stored at its last build proposes the
  k + ``extra`` nearest of every query (one call for all queries); the samples stored since (fewer
  than ``rebuild_share`` of the memory, or ``min_recent``) are scanned;
* the canonical distances of all these candidates are computed and the k smallest by (distance,
  index) kept (this step, the check below and its scans are one compiled call per query batch,
  ``knn_kernel.tree_answers`` in knn_kernel.c, since 2026-11-27: the numpy steps it replaced cost
  ~90 µs a call beside the tree's own query);
* the tree's own distances only choose candidates. A tree sample it did not return is at least as
  far, in the tree's arithmetic, as its farthest candidate; when that is not beyond the answer's
  k-th distance by a relative 1e-9 (far above the rounding of either distance: exact ties, e.g.
  duplicated samples), such a sample could belong to the answer, and that query is answered by a
  scan of every sample instead.

The memory is read, never written; the index notices new samples by the memory's length.
"""
from __future__ import annotations

import numpy as np

from .compiled import knn_kernel
from .memory_store import SampleStore

_MARGIN = 1.0 - 1e-9
_NO_DISTANCES = np.empty(0)
_NO_INDICES = np.empty(0, dtype=np.int64)


class TreeKnn:
    """``query(Q, k)[j]`` = ``SampleMemory.neighbours(Q[j], k)`` over the same samples, exact, for a
    growing store."""

    def __init__(self, memory: SampleStore, extra: int = 1, min_recent: int = 64,
                 rebuild_share: float = 1 / 32, leafsize: int = 16):
        self.memory = memory
        self.extra = int(extra)
        self.min_recent = int(min_recent)
        self.rebuild_share = float(rebuild_share)
        self.leafsize = int(leafsize)
        # lazy (heavy): scipy
        from scipy.spatial import cKDTree

        self._kdtree = cKDTree  # imported when the index is made, not at its first search
        dim = memory.state_dim
        self._tree = None  # scipy.spatial.cKDTree of samples 0 .. _nt - 1, once built
        self._tree_t = np.empty((dim, 0))  # the tree's samples, dimension-major
        self._nt = 0  # samples in the tree: indices 0 .. _nt - 1
        self._recent_t = np.empty((dim, 0))  # the samples stored since (a prefix), dimension-major
        self._nr = 0
        self.scans = 0  # queries answered by a scan of every sample (statistics only)

    @property
    def nbytes(self) -> int:
        """Bytes held by the index: the tree's copy of the samples and its index array (its node
        structure is not exposed by scipy, so not counted), and the two dimension-major copies."""
        tree = 0 if self._tree is None else self._tree.data.nbytes + self._tree.indices.nbytes
        return int(tree + self._tree_t.nbytes + self._recent_t.nbytes)

    def _update(self, n: int) -> None:
        """Rebuild the tree when the samples stored since its build exceed the allowed share, else
        copy the newest samples into the recent part."""
        nt = self._nt
        if n - nt > max(self.min_recent, int(self.rebuild_share * n)):
            alpha = self.memory.alpha
            self._tree = self._kdtree(alpha, leafsize=self.leafsize, compact_nodes=False,
                                      balanced_tree=False, copy_data=True)
            self._tree_t = np.ascontiguousarray(alpha.T)
            self._nt, self._nr = n, 0
            return
        if nt + self._nr < n:
            if self._recent_t.shape[1] < n - nt:
                grown = np.empty((self._tree_t.shape[0], 2 * (n - nt)))
                grown[:, : self._nr] = self._recent_t[:, : self._nr]
                self._recent_t = grown
            self._recent_t[:, self._nr : n - nt] = self.memory.alpha[nt + self._nr :].T
            self._nr = n - nt

    def query(self, queries: np.ndarray, k: int) -> np.ndarray:
        """(B, min(k, len)) int64: row j = the memory's exact ``neighbours(queries[j], k)``."""
        qs = np.asarray(queries, dtype=np.float64)
        b, dim = qs.shape
        want = self._tree_t.shape[0]
        if dim != want or not np.isfinite(qs).all():
            raise ValueError(f"queries must be finite, of shape (B, {want}), got {qs.shape}")
        n = len(self.memory)
        k = min(int(k), n)
        if k < 1 or not b:
            return np.empty((b, max(k, 0)), dtype=np.int64)
        self._update(n)
        nt, nr = self._nt, self._nr
        if nt:
            kq = min(k + self.extra, nt)
            far, ti = self._tree.query(qs, k=kq)
        else:
            far, ti = _NO_DISTANCES, _NO_INDICES
        out = np.empty((b, k), dtype=np.int64)
        # the candidates' canonical distances, the bound, the (distance, index) order, the check
        # against the farthest proposal and the full scans: one compiled call (knn_kernel.c)
        self.scans += knn_kernel.tree_answers(np.ascontiguousarray(qs), k, far, ti, self._tree_t, nt,
                                              self._recent_t, nr, _MARGIN, out)
        return out
