"""k-nearest-neighbour search of the sample memory over its index: exact, approximate, cached.

A mixin of :class:`sagg_low_level.memory.SampleMemory` (one object; this module owns the trajectory
cache ``_cache_*``, the query scratch ``_q3`` / ``_arange_*`` and the statistics ``cache_hits`` /
``leaves_scanned``; it reads the index of :mod:`sagg_low_level.memory_index` and the stored rows).

* exact (``checks=0``): the EXACT k nearest, a deterministic function of the stored samples (ties
  broken by index). Bounds: the buffer's k-th distance, refined when it is loose by a greedy descent
  to the few leaves closest to q (``refine_*``). Pruning uses box distance <= bound, which is exact:
  boxes and points use the same canonical distance (:mod:`sagg_low_level.memory_distance`), so no
  float slack is needed.
* Trajectory cache (``cache_*``, exact mode only): a query that walks the index also collects every
  sample within ``cache_expand`` times the bound's radius; the next queries along the trajectory are
  answered from that small set alone while the triangle inequality proves it contains their k nearest
  (``sqrt(kth) + |q - centre| < radius``, with a 1e-9 relative margin for float rounding).
* approximate (``checks > 0``, as in the paper, Sec. 3.3, FLANN's "checks"): a bounded best-bin-first
  search, see :meth:`KnnSearch._knn_approx`; results depend only on the stored samples, the query
  and k (not on earlier queries: the cache is not used).

Results are sample indices ordered by (squared distance, index).
"""

from __future__ import annotations

import math

import numpy as np

from .compiled import knn_kernel
from .memory_distance import _sqdist_cols


_NO_SLOTS = np.empty(0, dtype=np.int64)  # no duplicate leaves to add to a walk


def _kth(d: np.ndarray, k: int) -> float:
    """The k-th smallest entry of ``d`` (NaN last), ``np.partition(d, k - 1)[k - 1]`` without the
    wrapper's dispatch (the method on a copy: the same selection)."""
    c = d.copy()
    c.partition(k - 1)
    return c[k - 1]


class KnnSearch:
    """Queries over the index and the trajectory cache (mixin of SampleMemory)."""

    def _init_search(self) -> None:
        n = self._sd
        # query scratch: rows (q, -q, 0) against boxes stored as (lo, -hi, 0)
        self._q3 = np.zeros((3, n, 1))
        self._arange_f = np.arange(self._fan)
        self._arange_b = np.arange(self._leaf)
        # query cache: every stored sample within sqrt(_cache_r2) of _cache_c (plus every sample added
        # since), dimension-major; _cache_m < 0 means no cache
        self._cache_t = np.empty((n, 0))
        self._cache_i = np.empty(0, dtype=np.int64)
        self._cache_c = np.zeros(n)
        self._cache_r = 0.0
        self._cache_m = -1
        self._cache_k = 0
        self.cache_hits = 0  # queries answered from the cache (statistics only)
        self.leaves_scanned = 0  # leaves scanned by approximate queries (statistics only)

    def _knn(self, q: np.ndarray, k: int) -> np.ndarray:
        """Indices of the min(k, len) stored alpha nearest to ``q`` (checked), by (distance, index)."""
        n_all, ns = self._n, self._ns
        if k >= n_all:
            if n_all == 0:
                return np.empty(0, dtype=np.int64)
            d = _sqdist_cols(np.ascontiguousarray(self._alpha[:n_all].T), q)
            return np.lexsort((np.arange(n_all), d))
        if self._checks:
            got = self._knn_approx(q, k)
            if got is not None:
                return got
            # fewer than k samples among the buffer and the scanned leaves (tiny buffers and
            # large k only): the exact search, whose answer depends on nothing but the samples
        m = self._cache_m
        cache_kth = np.inf
        if m >= k and k <= self._cache_k:
            dq = q - self._cache_c
            delta = math.sqrt(dq.dot(dq))
            if delta < self._cache_r:
                d = _sqdist_cols(self._cache_t[:, :m], q)
                kth = _kth(d, k)
                # Any sample outside the cache is farther than r from the centre, so farther than
                # r - delta from q; if that exceeds the k-th cached distance the cache holds the
                # answer. The 1e-9 margins dwarf the float rounding of all these distances.
                if (math.sqrt(kth) + delta) * (1.0 + 1e-9) + 1e-150 < self._cache_r * (1.0 - 1e-9):
                    self.cache_hits += 1
                    keep = d <= kth
                    ci = self._cache_i[:m][keep]
                    return ci[np.lexsort((ci, d[keep]))[:k]]
                cache_kth = kth  # k real samples: still an upper bound of the k-th distance
        nb = n_all - ns
        bd = _sqdist_cols(self._buf_t[:, :nb], q) if nb else np.empty(0)
        # tight: an upper bound of the k-th distance (any k stored samples give one). wide: the walk
        # also collects everything that far for the cache (capped at the leaves by cache_scan).
        tight = _kth(bd, k) if nb >= k else np.inf
        if cache_kth < tight:
            tight = cache_kth
        grow = self._cache_expand**2 if self._cache_expand else 1.0
        wide = tight * grow
        if self._height < 0:  # everything is in the buffer
            leaf_d = leaf_i = None
        else:
            q3 = self._q3
            q3[0, :, 0] = q
            np.negative(q, out=q3[1, :, 0])
            fan = self._fan
            sel = None  # selected node ids (slots) at the height above
            refined = False
            for h in range(self._height, -1, -1):
                r0, r1 = self._roots[h]
                if sel is None or not len(sel):
                    if r0 == r1:
                        sel = None
                        continue
                    slots = None
                    g = self._boxes[h][:, :, r0:r1] - q3
                else:
                    slots = (sel[:, None] * fan + self._arange_f).ravel()
                    if r0 < r1:
                        slots = np.concatenate((slots, np.arange(r0, r1)))
                    g = self._boxes[h].take(slots, axis=2)
                    g -= q3
                lb = g.max(axis=0)
                lb *= lb
                lb = np.add.reduce(lb, axis=0)  # squared box distances, canonical order
                keep = lb <= wide
                if not refined and np.count_nonzero(keep) > self._refine_nodes:
                    refined = True
                    ids = np.arange(r0, r1) if slots is None else slots
                    better = self._refine_bound(h, ids, g, lb, q, k, bd)
                    if better < tight:
                        tight, wide = better, better * grow
                        keep = lb <= wide
                if h == 0 and grow > 1.0:
                    # cap the extra scan for the cache at cache_scan times the leaves the answer
                    # needs (in 15-30 dims a wider ball holds most of the memory); the cache radius
                    # is then what the scanned leaves cover
                    need = int(self._cache_scan * np.count_nonzero(lb <= tight)) + 1
                    if np.count_nonzero(keep) > need:
                        wide = max(tight, _kth(lb, need + 1))
                        keep = lb <= wide
                if slots is None:
                    sel = keep.nonzero()[0]
                    sel += r0
                else:
                    sel = slots[keep]
            if sel is None or not len(sel):
                leaf_d = leaf_i = None
            else:
                idx = (sel[:, None] * self._leaf + self._arange_b).ravel()
                p = self._pts.take(idx, axis=1)
                p -= q[:, None]
                p *= p
                leaf_d = np.add.reduce(p, axis=0)
                leaf_i = self._pidx[idx]
        if leaf_d is None:
            all_d, all_i = bd, np.arange(ns, n_all)
        else:
            all_d = np.concatenate((bd, leaf_d))
            all_i = np.concatenate((np.arange(ns, n_all), leaf_i))
        # every stored sample with distance <= wide (>= tight) is among (all_d, all_i): >= k of them
        keep = all_d <= wide
        cd, ci = all_d[keep], all_i[keep]
        if self._ngroups and ci.min() < -1:
            cd, ci = self._expand_groups(cd, ci, k)
        if grow > 1.0:
            self._fill_cache(q, cd, ci, wide, k)
            kth = _kth(cd, k)
            keep = cd <= kth
            cd, ci = cd[keep], ci[keep]
        return ci[np.lexsort((ci, cd))[:k]]

    def _knn_approx(self, q: np.ndarray, k: int) -> np.ndarray | None:
        """Approximate k nearest with a bounded number of scanned leaves (``checks``).

        Best-bin-first in FLANN's sense, level by level over every block at once: from the top box
        height down, the candidates are the children of the nodes kept at the height above plus the
        root nodes at this height; a node is dropped when its box distance exceeds the buffer's k-th
        distance (a true upper bound of the k-th distance; with no bound yet, the largest float),
        and of the rest only the ceil(checks * beam_ratio**h) of smallest box distance are kept
        (checks at the leaves; ties by candidate order, a stable sort). The buffer, the kept leaves
        and the leaves holding exact copies of the query (found through the duplicate groups' hash)
        are scanned; the k best of those are returned by (distance, index), a duplicate group
        standing for its members. No cap binding = every leaf that can hold a k-nearest sample was
        scanned = the exact answer. Returns None when fewer than k samples were scanned.

        The walk runs in the compiled :mod:`sagg_low_level.knn_kernel` (knn_kernel.c), one call per
        query, instead of ~60 numpy calls for the same walk in numpy (kept in test/test_knn_kernel.py
        as its reference: the same answers bit for bit).
        """
        extra = _NO_SLOTS
        if self._dupmap:
            dups = self._dupmap.get((q + 0.0).tobytes())
            if dups:
                extra = np.array([self._ginfo[g][1] for g in dups], dtype=np.int64)
        out = np.empty(k, dtype=np.int64)
        scanned = knn_kernel.approx(q, k, self._buf_t, self._n - self._ns, self._ns, self._height, self._boxes,
                                    self._root_groups, self._widths, self._fan, self._leaf, self._pts,
                                    self._pidx, extra, self._dup, self._dup_off, out)
        if scanned < 0:  # -1 - leaves scanned: fewer than k samples among them
            self.leaves_scanned += -1 - scanned
            return None
        self.leaves_scanned += scanned
        return out

    def _expand_groups(self, cd, ci, k):
        """Replace group codes by their samples (the k smallest indices are all a top-k can use)."""
        ci = ci.copy()
        ds, js = [cd], [ci]
        for j in np.flatnonzero(ci < -1):
            g = -int(ci[j]) - 2
            a, b = int(self._dup_off[g]), int(self._dup_off[g + 1])
            mem = self._dup[a : min(b, a + k)]
            ci[j] = mem[0]
            js.append(mem[1:])
            ds.append(np.full(len(mem) - 1, cd[j]))
        return np.concatenate(ds), np.concatenate(js)

    def _fill_cache(self, q, cd, ci, bound, k) -> None:
        """Keep the samples within sqrt(r2) of q (all of them are in cd/ci when r2 <= bound)."""
        r2 = bound
        if len(cd) > self._cache_max:
            r2 = _kth(cd, self._cache_max)
            keep = cd <= r2
            cd, ci = cd[keep], ci[keep]
        m = len(ci)
        if not r2 < np.inf or m < k:
            self._cache_m = -1
            return
        cap = self._cache_t.shape[1]
        if cap < m + 64 or cap > 4 * (m + 64):
            cap = 2 * (m + 64)
            self._cache_t = np.empty((self._sd, cap))
            self._cache_i = np.empty(cap, dtype=np.int64)
        self._cache_t[:, :m] = self._alpha[ci].T
        self._cache_i[:m] = ci
        self._cache_c[:] = q
        self._cache_r = math.sqrt(r2)
        self._cache_m = m
        self._cache_k = k  # duplicate groups were cut to k samples: answers only for k' <= k

    @staticmethod
    def _beam_key(g: np.ndarray, lb: np.ndarray) -> np.ndarray:
        """Rank of nodes for the beam: box distance + distance to the farthest box corner.

        The box distance alone ties at 0 for every box containing q (dense regions); the farthest
        corner favours small boxes close to q, which hold q's nearest samples.
        """
        far = np.maximum(np.abs(g[0]), np.abs(g[1]))
        far *= far
        return np.add.reduce(far, axis=0) + lb

    def _refine_bound(self, h, ids, g, lb, q, k, bd) -> float:
        """Upper bound on the k-th distance from a greedy beam descent to the most promising leaves.

        Keeps the ``width`` nodes of smallest _beam_key at each height, scans their leaves and
        returns the k-th smallest distance among those points and the buffer: an upper bound of the
        true k-th distance (any k stored samples give one). Speed only, never results.
        """
        fan = self._fan
        width = max(self._refine_leaves, -(-k // self._leaf) + 1)
        q3 = self._q3
        nodes, flat = ids, self._beam_key(g, lb)
        for hh in range(h, -1, -1):
            if len(nodes) > width:
                nodes = nodes[np.argpartition(flat, width - 1)[:width]]
            if hh == 0:
                break
            nodes = (nodes[:, None] * fan + self._arange_f).ravel()
            g = self._boxes[hh - 1].take(nodes, axis=2)
            g -= q3
            m = g.max(axis=0)
            m *= m
            flat = self._beam_key(g, np.add.reduce(m, axis=0))
        idx = (nodes[:, None] * self._leaf + self._arange_b).ravel()
        p = self._pts.take(idx, axis=1)
        p -= q[:, None]
        p *= p
        d = np.concatenate((bd, np.add.reduce(p, axis=0)))
        if len(d) < k:
            return np.inf
        kth = _kth(d, k)
        return kth if kth == kth else np.inf  # NaN (empty leaf slots) -> no bound

    def _cache_add(self, i: int, a: np.ndarray) -> None:
        """Sample i (alpha ``a``) was just stored: the live cache keeps it too (or is dropped when full)."""
        m = self._cache_m
        if m >= 0:
            if m < self._cache_t.shape[1]:
                self._cache_t[:, m] = a
                self._cache_i[m] = i
                self._cache_m = m + 1
            else:
                self._cache_m = -1
