"""Sample memory of the evolving-context learner with k-nearest-neighbour search on alpha.

Paper Sec. 3.3 ("Representation of Forward and Inverse Models to be Learnt"): every micro-action
stores (alpha, delta_alpha, delta_y) and, at every micro-action, the learner needs the k nearest stored
alpha to the current alpha to fit a local Jacobian. The paper uses an incremental *approximate*
nearest-neighbour index (FLANN, "Muja09"). Two modes:

* exact (``checks=0``): the EXACT k nearest, a deterministic function of the stored samples (ties
  broken by index), independent of how the index is built, identical after save/load. Its cost
  grows with the memory (in 15 dims the k-NN ball meets a large share of the leaves).
* approximate (``checks > 0``, as in the paper): a bounded best-bin-first search in FLANN's sense
  ("checks"): at most ``checks`` leaves of the index are scanned per query (plus the buffer), so the
  cost per query stays flat as the memory grows. Results are real stored samples with their exact
  distances, sorted by (distance, index); they are a deterministic function of the stored samples
  (in insertion order), the query and k: NOT of earlier queries (the trajectory cache below is
  not used, so evaluation queries interleaved with learning cannot change what the learner
  gets), of timing, or of save/load. When the budget covers every leaf the search needs, the
  answer is the exact one. See :meth:`SampleMemory._knn_approx`.

Design (measured with ``python -m sagg_low_level.memory_bench``; numbers in the commit messages):

* Samples live in preallocated float64 arrays that double their capacity (amortised O(1) add).
* Index = logarithmic method (Bentley-Saxe): the newest samples sit in a brute-force *buffer*;
  whenever it holds ``2 * buffer_size`` samples, its oldest ``buffer_size`` become a static *block*,
  merged like a binary counter with every trailing block of equal size, so a sample takes part in
  O(log(N / buffer_size)) block builds and blocks hold contiguous index ranges (a bulk rebuild, e.g.
  after load, reproduces the incremental state exactly). The buffer keeps its newest samples because
  along a trajectory they give a first upper bound on the k-th distance for free.
* A static block partitions its samples into leaves of ``leaf_size`` points (balanced kd partition,
  or consecutive samples, chosen per block: ``leaf_order``), with bounding boxes of fan-out ``fanout``
  above the leaves up to at most ``max_roots`` top nodes. The nodes of one height of ALL blocks live
  in one array, so a query walks every block at once with a few vectorised numpy calls per height.
* Exact duplicates of alpha (the rest posture after each reset) are stored once per block: median
  splits would otherwise spread them over almost every leaf and inflate every box.
* Bounds: the buffer's k-th distance, refined when it is loose by a greedy descent to the few
  leaves closest to q (``refine_*``). Pruning uses box distance <= bound, which is exact: boxes and
  points use the same canonical distance, so no float slack is needed.
* Trajectory cache (``cache_*``): a query that walks the index also collects every sample within
  ``cache_expand`` times the bound's radius; the next queries along the trajectory are answered from
  that small set alone while the triangle inequality proves it contains their k nearest
  (``sqrt(kth) + |q - centre| < radius``, with a 1e-9 relative margin for float rounding).
* Approximate mode: blocks use kd leaves (``leaf_order="auto"`` means "kd" there: ranking leaves by
  their box distance works best on compact kd cells. Measured on the learner's own queries after
  ``sagg bench speed``'s prefill to 1M samples, 32 leaves: recall 0.87 (n=7) / 0.81 (n=15) with kd
  leaves against 0.71 / 0.72 with the exact mode's per-block choice; ranking by distance to the
  leaf's centroid (k-means-like) or box centre did no better), and exact duplicates of the query
  (the rest posture) are always found through a hash of the duplicate groups.
* Why not scipy's cKDTree: one ``cKDTree.query`` costs ~30 us even on a 10-point tree here (Python
  argument handling), a logarithmic forest needs one call per tree, and its k-th-neighbour ties are
  not broken by index (a forest of cKDTrees measured no faster: ``memory_bench --ckdtree``).
* Layouts are dimension-major ((n, points)) so numpy's inner loops run over points, not over the
  7-30 coordinates, and every squared distance is summed in the SAME order (coordinate 0, 1, ...,
  n-1, sequentially) whichever path found the point: distances are bit-identical across buffer,
  leaves, cache and brute force, which makes ties exact and results independent of the index.

Distances are squared Euclidean distances in float64, summed over coordinates in index order; the
order of results is by (that distance, sample index).

Pauses: a block build is done inside the ``add`` that triggers it. Builds double in size (binary
counter): the add that creates a 512k-sample block (once per 512k adds) took 0.76 s (n = 7) /
0.95 s (n = 15) with kd leaves (approximate mode) and 1.0 / 1.3 s with the exact mode's "auto"
leaf order on the development machine; the 1M-sample merge about twice that. In-process runs
just take the pause; a real-time robot loop would see that add stall (building the new block in
a background thread while queries use the old blocks is the remedy, not done here).
"""

from __future__ import annotations

import math

import numpy as np

from sagg_common.diagnostics import all_finite

from .memory_distance import _sqdist_cols, squared_distances  # noqa: F401
from .memory_index import LEAF_ORDERS as _LEAF_ORDERS, BlockIndex
from .memory_io import load_memory, memory_digest, params_array, save_memory

__all__ = ["SampleMemory", "squared_distances"]


def _is_pow2(x: int) -> bool:
    return x >= 1 and (x & (x - 1)) == 0


def _check_int(name: str, value, low: int, high: int | None = None) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer in [{low}, {high if high is not None else 'inf'}], got {value!r}")
    value = int(value)
    if value < low or (high is not None and value > high):
        raise ValueError(f"{name} must be an integer in [{low}, {high if high is not None else 'inf'}], got {value}")
    return value


class SampleMemory(BlockIndex):
    """Growing store of (alpha, delta_alpha, delta_y) with exact k-NN queries on alpha.

    Parameters (the paper gives none of these; they only trade speed and memory, never results):
      capacity     initial number of rows allocated (doubles when full), >= 1.
      buffer_size  B: the brute-force buffer holds the newest B..2B-1 samples once 2B were added;
                   must be leaf_size * 2**j. Smaller B = cheaper buffer scan, more rebuild work.
      leaf_size    points per kd leaf (power of two >= 2).
      fanout       children per box node (power of two >= 2).
      max_roots    a block grows box heights until it has at most this many top nodes (>= 1).
      split_sample points sampled per segment to pick the kd split coordinate (>= 2).
      refine_nodes when a query's first bound keeps more than this many nodes at some height, a
                   greedy descent to the refine_leaves most promising leaves computes a tighter
                   bound first (>= 1); speed only.
      refine_leaves leaves scanned by that descent (>= 1; at least ceil(k / leaf_size) + 1 are used).
      leaf_order   how a block groups its samples into leaves: "kd" (balanced kd partition: best when
                   samples are dense relative to the query radius, e.g. n = 7 or uniform data),
                   "time" (consecutive samples: best for trajectories in 15-30 dims, where a kd tree
                   splits each coordinate at most once), or "auto" (per block, the one whose leaves
                   meet fewer exact tune_k-NN balls of sample queries drawn from the block).
      tune_k       k used by "auto" (default 2 * state_dim + 2).
      cache_expand consecutive queries along a trajectory: a query that walks the index also keeps
                   every sample within cache_expand times (an upper bound of) its k-th distance;
                   later queries are answered from that cache alone while the triangle inequality
                   proves it holds their k nearest (0 disables; otherwise in (1, 16]).
      cache_scan   the wider walk scans at most cache_scan times the leaves the answer needs; the
                   cache radius is cut to what those leaves cover (in [1, 1e6]).
      cache_max    the cache is shrunk to about this many samples (>= 1).
      checks       0 = exact search. > 0 = approximate search as in the paper (Sec. 3.3, FLANN's
                   "checks"): at most this many leaves (of leaf_size samples) are scanned per query,
                   besides the buffer and the leaves holding exact copies of the query; in [0, 2**31].
                   Changes results (not only speed); the trajectory cache is not used.
      beam_ratio   approximate search: at box height h >= 1 at most ceil(checks * beam_ratio**h)
                   nodes are kept (those of smallest box distance); in (0, 1].
    """

    def __init__(
        self,
        state_dim: int,
        action_dim: int,
        outcome_dim: int,
        capacity: int = 1024,
        buffer_size: int = 256,
        *,
        leaf_size: int = 32,
        fanout: int = 16,
        max_roots: int = 64,
        split_sample: int = 16,
        refine_nodes: int = 64,
        refine_leaves: int = 16,
        leaf_order: str = "auto",
        tune_k: int | None = None,
        cache_expand: float = 1.6,
        cache_scan: float = 4.0,
        cache_max: int = 4096,
        checks: int = 0,
        beam_ratio: float = 0.5,
    ):
        self._sd = _check_int("state_dim", state_dim, 1)
        self._ad = _check_int("action_dim", action_dim, 1)
        self._od = _check_int("outcome_dim", outcome_dim, 1)
        cap = _check_int("capacity", capacity, 1)
        self._leaf = _check_int("leaf_size", leaf_size, 2)
        if not _is_pow2(self._leaf):
            raise ValueError(f"leaf_size must be a power of two >= 2, got {leaf_size}")
        self._fan = _check_int("fanout", fanout, 2)
        if not _is_pow2(self._fan):
            raise ValueError(f"fanout must be a power of two >= 2, got {fanout}")
        self._buf = _check_int("buffer_size", buffer_size, self._leaf)
        if self._buf % self._leaf or not _is_pow2(self._buf // self._leaf):
            raise ValueError(
                f"buffer_size must be leaf_size * 2**j (leaf_size={self._leaf}), got {buffer_size}"
            )
        self._max_roots = _check_int("max_roots", max_roots, 1)
        self._split_sample = _check_int("split_sample", split_sample, 2)
        self._refine_nodes = _check_int("refine_nodes", refine_nodes, 1)
        self._refine_leaves = _check_int("refine_leaves", refine_leaves, 1)
        if leaf_order not in _LEAF_ORDERS:
            raise ValueError(f"leaf_order must be one of {_LEAF_ORDERS}, got {leaf_order!r}")
        self._leaf_order = leaf_order
        # k the 'auto' leaf order is tuned for; default 2n + 2 (see memory_bench.default_k)
        self._tune_k = _check_int("tune_k", 2 * self._sd + 2 if tune_k is None else tune_k, 1)
        if isinstance(cache_expand, bool) or not isinstance(cache_expand, (int, float, np.floating)) \
                or not (cache_expand == 0 or 1.0 < cache_expand <= 16.0):
            raise ValueError(f"cache_expand must be 0 (no cache) or in (1, 16], got {cache_expand!r}")
        self._cache_expand = float(cache_expand)
        if isinstance(cache_scan, bool) or not isinstance(cache_scan, (int, float, np.floating)) \
                or not 1.0 <= cache_scan <= 1e6:
            raise ValueError(f"cache_scan must be in [1, 1e6], got {cache_scan!r}")
        self._cache_scan = float(cache_scan)
        self._cache_max = _check_int("cache_max", cache_max, 1)
        self._checks = _check_int("checks", checks, 0, 2**31)
        if isinstance(beam_ratio, bool) or not isinstance(beam_ratio, (int, float, np.floating)) \
                or not 0.0 < beam_ratio <= 1.0:
            raise ValueError(f"beam_ratio must be in (0, 1], got {beam_ratio!r}")
        self._beam_ratio = float(beam_ratio)
        # approximate search: nodes kept per box height (0 = leaves; heights stay far below 64)
        self._widths = [max(1, math.ceil(self._checks * self._beam_ratio**h)) for h in range(64)]

        n = self._sd
        self._n = 0  # number of samples
        self._alpha = np.empty((cap, n))
        self._dalpha = np.empty((cap, self._ad))
        self._dy = np.empty((cap, self._od))
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
        self._init_index()

    # ------------------------------------------------------------------ storage API
    def __len__(self) -> int:
        return self._n

    @property
    def state_dim(self) -> int:
        return self._sd

    @property
    def action_dim(self) -> int:
        return self._ad

    @property
    def outcome_dim(self) -> int:
        return self._od

    def _view(self, arr: np.ndarray) -> np.ndarray:
        v = arr[: self._n].view()
        v.flags.writeable = False
        return v

    @property
    def alpha(self) -> np.ndarray:
        """Read-only (len, state_dim) view of the stored alpha."""
        return self._view(self._alpha)

    @property
    def delta_alpha(self) -> np.ndarray:
        """Read-only (len, action_dim) view of the stored delta_alpha."""
        return self._view(self._dalpha)

    @property
    def delta_y(self) -> np.ndarray:
        """Read-only (len, outcome_dim) view of the stored delta_y."""
        return self._view(self._dy)

    @property
    def nbytes(self) -> int:
        """Bytes held by the sample arrays and the index (allocated capacity included)."""
        total = self._alpha.nbytes + self._dalpha.nbytes + self._dy.nbytes + self._buf_t.nbytes
        total += self._pts.nbytes + self._pidx.nbytes + sum(b.nbytes for b in self._boxes)
        total += self._cache_t.nbytes + self._cache_i.nbytes + self._dup.nbytes + self._dup_off.nbytes
        return int(total)

    @staticmethod
    def _vector(name: str, value, dim: int) -> np.ndarray:
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{name} must be a finite float vector of shape ({dim},): {exc}") from None
        if arr.shape != (dim,):
            raise ValueError(f"{name} must have shape ({dim},), got {arr.shape}")
        return arr

    def add(self, alpha, delta_alpha, delta_y) -> int:
        """Store one sample; return its index. Raises ValueError on wrong shapes or non-finite values."""
        a = self._vector("alpha", alpha, self._sd)
        da = self._vector("delta_alpha", delta_alpha, self._ad)
        dy = self._vector("delta_y", delta_y, self._od)
        # x . x is finite unless some entry is inf/NaN (or |x| > 1e154): one cheap call per vector,
        # the exact check only when it is not (inf * inf and NaN * NaN raise no FP warning).
        if not a.dot(a) + da.dot(da) + dy.dot(dy) < np.inf:
            for name, v in (("alpha", a), ("delta_alpha", da), ("delta_y", dy)):
                if not np.isfinite(v).all():
                    raise ValueError(f"{name} must be finite (no NaN/inf), got {v}")
        i = self._n
        if i == self._alpha.shape[0]:
            self._grow(2 * i)
        self._alpha[i] = a
        self._dalpha[i] = da
        self._dy[i] = dy
        self._buf_t[:, i - self._ns] = a
        m = self._cache_m
        if m >= 0:
            if m < self._cache_t.shape[1]:
                self._cache_t[:, m] = a
                self._cache_i[m] = i
                self._cache_m = m + 1
            else:
                self._cache_m = -1
        self._n = i + 1
        if self._n - self._ns == 2 * self._buf:
            self._index_batch()
        return i

    def _grow(self, cap: int) -> None:
        for name in ("_alpha", "_dalpha", "_dy"):
            old = getattr(self, name)
            new = np.empty((cap, old.shape[1]))
            new[: self._n] = old[: self._n]
            setattr(self, name, new)

    # ------------------------------------------------------------------ queries
    def _query_vector(self, query) -> np.ndarray:
        q = self._vector("query", query, self._sd)
        if not all_finite(q):
            raise ValueError(f"query must be finite (no NaN/inf), got {q}")
        return q

    def _check_k(self, k) -> int:
        return _check_int("k", k, 1)

    def neighbours(self, query: np.ndarray, k: int) -> np.ndarray:
        """Indices of the min(k, len) stored alpha nearest to ``query``, by (distance, index)."""
        q = self._query_vector(query)
        k = self._check_k(k)
        return self._knn(q, k)

    def neighbours_batch(self, queries: np.ndarray, k: int) -> np.ndarray:
        """(B, min(k, len)) array: row i is ``neighbours(queries[i], k)``."""
        try:
            qs = np.asarray(queries, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"queries must be a finite float array of shape (B, {self._sd}): {exc}") from None
        if qs.ndim != 2 or qs.shape[1] != self._sd:
            raise ValueError(f"queries must have shape (B, {self._sd}), got {qs.shape}")
        if not np.isfinite(qs).all():
            raise ValueError("queries must be finite (no NaN/inf)")
        k = self._check_k(k)
        out = np.empty((qs.shape[0], min(k, self._n)), dtype=np.int64)
        for i in range(qs.shape[0]):
            out[i] = self._knn(qs[i], k)
        return out

    def _knn(self, q: np.ndarray, k: int) -> np.ndarray:
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
                kth = np.partition(d, k - 1)[k - 1]
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
        tight = np.partition(bd, k - 1)[k - 1] if nb >= k else np.inf
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
                        wide = max(tight, np.partition(lb, need)[need])
                        keep = lb <= wide
                if slots is None:
                    sel = np.flatnonzero(keep)
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
            kth = np.partition(cd, k - 1)[k - 1]
            keep = cd <= kth
            cd, ci = cd[keep], ci[keep]
        return ci[np.lexsort((ci, cd))[:k]]

    def _knn_approx(self, q: np.ndarray, k: int) -> np.ndarray | None:
        """Approximate k nearest with a bounded number of scanned leaves (``checks``).

        Best-bin-first in FLANN's sense, level by level so each height of all blocks is one set of
        vectorised numpy calls: from the top box height down, the candidates are the children of the
        nodes kept at the height above plus the root nodes at this height; a node is dropped when its
        box distance exceeds the buffer's k-th distance (a true upper bound of the k-th distance),
        and of the rest only the ceil(checks * beam_ratio**h) of smallest box distance are kept
        (checks at the leaves; ties by candidate order, a stable sort). The buffer, the kept leaves
        and the leaves holding exact copies of the query are scanned; the k best of those are
        returned by (distance, index). No cap binding = every leaf that can hold a k-nearest sample
        was scanned = the exact answer. Returns None when fewer than k samples were scanned.
        """
        n_all, ns = self._n, self._ns
        nb = n_all - ns
        bd = _sqdist_cols(self._buf_t[:, :nb], q) if nb else np.empty(0)
        # nodes farther than an upper bound of the k-th distance cannot contribute; with no bound
        # yet, the largest float still drops the empty (infinite) padding boxes
        bound = np.partition(bd, k - 1)[k - 1] if nb >= k else np.finfo(np.float64).max
        sel = None  # kept node ids at the height above (= their children's group ids here)
        if self._height >= 0:
            q4 = self._q3[:, :, :, None]  # (3, n, 1, 1)
            q4[0, :, 0, 0] = q
            np.negative(q, out=q4[1, :, 0, 0])
            fan, leaf, n = self._fan, self._leaf, self._sd
            for h in range(self._height, -1, -1):
                # candidates: whole F-groups of slots (gathered as contiguous runs): the children
                # of the kept nodes and the root groups at this height
                roots = self._root_groups[h]
                groups = roots if sel is None else np.concatenate((sel, roots)) if len(roots) else sel
                if not len(groups):
                    sel = None
                    continue
                boxes = self._boxes[h]
                g = boxes.reshape(3, n, boxes.shape[2] // fan, fan).take(groups, axis=2)
                g -= q4
                lb = g.max(axis=0)
                lb *= lb
                lb = np.add.reduce(lb, axis=0).ravel()  # squared box distances, canonical order
                keep = np.flatnonzero(lb <= bound)
                cap = self._widths[h]
                if len(keep) > cap:
                    keep = keep[np.argsort(lb[keep], kind="stable")[:cap]]
                sel = groups[keep // fan] * fan + keep % fan
            if self._dupmap:
                dups = self._dupmap.get((q + 0.0).tobytes())
                if dups:
                    extra = np.array([self._ginfo[g][1] for g in dups], dtype=np.int64)
                    sel = extra if sel is None else np.union1d(sel, extra)
        if sel is None or not len(sel):
            cd, ci = bd, np.arange(ns, n_all)
        else:
            self.leaves_scanned += len(sel)
            p = self._pts.reshape(n, self._pts.shape[1] // leaf, leaf).take(sel, axis=1)
            p -= q[:, None, None]
            p *= p
            # canonical order, as every other path; empty leaf slots are NaN and never selected
            cd = np.concatenate((bd, np.add.reduce(p, axis=0).ravel()))
            ci = np.concatenate((np.arange(ns, n_all), self._pidx.reshape(-1, leaf).take(sel, axis=0).ravel()))
        if len(cd) < k:
            return None
        # a group code stands for >= 1 sample at its distance, so this k-th value bounds the answer
        kth = np.partition(cd, k - 1)[k - 1]
        if not kth <= np.inf:  # NaN: fewer than k samples scanned
            return None
        keep = cd <= kth
        cd, ci = cd[keep], ci[keep]
        if self._ngroups and ci.min() < -1:
            cd, ci = self._expand_groups(cd, ci, k)
            kth = np.partition(cd, k - 1)[k - 1]
            keep = cd <= kth
            cd, ci = cd[keep], ci[keep]
        return ci[np.lexsort((ci, cd))[:k]]

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
            r2 = np.partition(cd, self._cache_max - 1)[self._cache_max - 1]
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
        kth = np.partition(d, k - 1)[k - 1]
        return kth if kth == kth else np.inf  # NaN (empty leaf slots) -> no bound

    # ------------------------------------------------------------------ persistence
    def digest(self) -> str:
        """sha256 hex over the dims, the length and the filled arrays (see memory_io.memory_digest)."""
        return memory_digest(self)

    def _params(self) -> np.ndarray:
        return params_array(self)

    def save(self, path) -> None:
        """Atomically write an .npz (no pickle): <path>.tmp.npz, then os.replace onto ``path``."""
        save_memory(self, path)

    @classmethod
    def load(cls, path) -> "SampleMemory":
        """Read a file written by :meth:`save`; the index is rebuilt exactly as it was."""
        return load_memory(cls, path)
