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
  index) kept;
* the tree's own distances only choose candidates. A tree sample it did not return is at least as
  far, in the tree's arithmetic, as its farthest candidate; when that is not beyond the answer's
  k-th distance by a relative 1e-9 (far above the rounding of either distance: exact ties, e.g.
  duplicated samples), such a sample could belong to the answer, and that query is answered by a
  scan of every sample instead.

The memory is read, never written; the index notices new samples by the memory's length.
"""
from __future__ import annotations

import numpy as np

from .memory_distance import sum_squares_rows
from .memory_store import SampleStore

_MARGIN = 1.0 - 1e-9


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
        qt = qs.T.copy()
        # candidates, flattened row after row: canonical squared distance, sample index (and the
        # row, i.e. the query, when there are several)
        dist, index, rows = [], [], []
        bound = None  # per query, an upper bound of its k-th distance (the tree's candidates give it)
        if nt:
            kq = min(k + self.extra, nt)
            far, ti = self._tree.query(qs, k=kq)
            ti = ti.reshape(-1)
            diff = self._tree_t.take(ti, axis=1)
            diff.shape = (dim, b, kq)
            diff -= qt[:, :, None]
            td = sum_squares_rows(diff.reshape(dim, b * kq))
            dist.append(td)
            index.append(ti)
            if b > 1:
                rows.append(np.repeat(np.arange(b), kq))
            if kq >= k:
                bound = td.reshape(b, kq)[:, :k].max(axis=1)
        if nr:
            diff = np.subtract(self._recent_t[:, None, :nr], qt[:, :, None], out=np.empty((dim, b, nr)))
            rd = sum_squares_rows(diff.reshape(dim, b * nr))
            if bound is None:
                keep = np.arange(b * nr)
            else:  # only those not beyond the tree's bound can be among the k nearest
                keep = np.flatnonzero(rd.reshape(b, nr) <= bound[:, None])
            dist.append(rd[keep])
            if b > 1:
                r = keep // nr
                rows.append(r)
                keep -= r * nr
            index.append(keep + nt)
        dist = np.concatenate(dist) if len(dist) > 1 else dist[0]
        index = np.concatenate(index) if len(index) > 1 else index[0]
        if b == 1:
            pick = np.lexsort((index, dist))[None, :k]
        else:  # each row holds >= k candidates: its first k after sorting by (row, distance, index)
            rows = np.concatenate(rows) if len(rows) > 1 else rows[0]
            counts = np.bincount(rows, minlength=b)
            pick = np.lexsort((index, dist, rows))[(np.cumsum(counts) - counts)[:, None] + np.arange(k)]
        out = index[pick]
        if nt and nt > kq:
            # a tree sample not proposed is at least the farthest candidate away (tree arithmetic):
            # it can neither beat nor tie a k-th distance clearly smaller
            kth = dist[pick[:, -1]]
            far = far.reshape(b, kq)[:, -1]
            bad = ~(far * far * _MARGIN > kth)
            if bad.any():
                for j in np.flatnonzero(bad):
                    out[j] = self._scan(qt[:, j], k)
        return out

    def _scan(self, q: np.ndarray, k: int) -> np.ndarray:
        """The k nearest of every sample to q (canonical distances, (distance, index) order)."""
        self.scans += 1
        d = sum_squares_rows(self._tree_t - q[:, None])
        if self._nr:
            d = np.concatenate((d, sum_squares_rows(self._recent_t[:, : self._nr] - q[:, None])))
        return np.lexsort((np.arange(len(d)), d))[:k]
