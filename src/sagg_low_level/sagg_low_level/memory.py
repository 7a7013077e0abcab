"""Sample memory of the evolving-context learner with exact k-nearest-neighbour search on alpha.

Paper Sec. 3.3 ("Representation of Forward and Inverse Models to be Learnt"): every micro-action
stores (alpha, delta_alpha, delta_y) and, at every micro-action, the learner needs the k nearest stored
alpha to the current alpha to fit a local Jacobian. The paper uses an incremental *approximate*
nearest-neighbour index (FLANN k-means tree); we return the EXACT k nearest instead, so results are a
deterministic function of the stored samples (ties broken by index), independent of how the index is
built, and identical after save/load.

Design (numbers behind every choice are in ``memory_bench``):

* Samples live in preallocated float64 arrays that double their capacity (amortised O(1) add).
* The k-NN index over alpha is a logarithmic method (Bentley-Saxe): the newest samples sit in a small
  brute-force *buffer*; whenever it holds ``2 * buffer_size`` samples, its oldest ``buffer_size``
  become a new static *block*, merged (like a binary counter) with every trailing block of equal size,
  so each sample is rebuilt O(log(N / buffer_size)) times in all and blocks hold contiguous index
  ranges. The buffer keeps the newest ``buffer_size`` samples because they give, for free, a tight
  first upper bound on the k-th distance along a trajectory (the learner's queries follow alpha).
* A static block is a balanced kd-partition of its samples into leaves of ``leaf_size`` points, with a
  hierarchy of axis-aligned bounding boxes of fan-out ``fanout`` above the leaves, capped so that a
  block exposes at most ``max_roots`` top nodes. All blocks' nodes of one height live in ONE array, so a
  query walks all blocks at once with a handful of vectorised numpy calls per height: the cost is a
  function of the depth (log_fanout of the size), not of the number of blocks.
* Why not scipy's cKDTree: one ``cKDTree.query`` call costs ~30 us on this machine even on a 10-point
  tree (Python-level argument handling), so a logarithmic set of trees needs several calls per query
  and blows the per-micro-action budget; its k-th-neighbour ties are also not broken by index.
* Layouts are dimension-major ((..., n, points)) so numpy's inner loops run over points, not over the
  7-30 coordinates, and so every squared distance is summed in the SAME order (coordinate 0, 1, ...,
  n-1, sequentially) whichever path found the point: distances are bit-identical across the buffer,
  the leaves and the brute-force path, which is what makes ties exact and the result independent of
  the index structure.

Distances are squared Euclidean distances in float64, summed over coordinates in index order; the
order of results is by (that distance, sample index).
"""

from __future__ import annotations

import hashlib
import os

import numpy as np

__all__ = ["SampleMemory", "squared_distances"]

_FORMAT_VERSION = 1
_LEAF_ORDERS = ("auto", "kd", "time")
_DIGEST_TAG = b"sagg.SampleMemory/v1"


def _is_pow2(x: int) -> bool:
    return x >= 1 and (x & (x - 1)) == 0


def _check_int(name: str, value, low: int, high: int | None = None) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer in [{low}, {high if high is not None else 'inf'}], got {value!r}")
    value = int(value)
    if value < low or (high is not None and value > high):
        raise ValueError(f"{name} must be an integer in [{low}, {high if high is not None else 'inf'}], got {value}")
    return value


def squared_distances(points: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Canonical squared distances of the rows of ``points`` (c, n) to ``query`` (n,).

    Sum over coordinates in index order, sequentially: ((d0^2 + d1^2) + d2^2) + ... . This is the
    definition every path of :class:`SampleMemory` reproduces bit for bit.
    """
    points = np.asarray(points, dtype=np.float64)
    query = np.asarray(query, dtype=np.float64)
    if points.ndim != 2 or query.shape != (points.shape[1],):
        raise ValueError(f"points must be (c, n) and query (n,), got {points.shape} and {query.shape}")
    return _sqdist_cols(np.ascontiguousarray(points.T), query)


def _sqdist_cols(xt: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Squared distances of the columns of C-contiguous ``xt`` (n, c) to ``q`` (n,), canonical order.

    numpy reduces axis 0 of a C-contiguous (n, c >= 2) array row after row (sequential over n). With a
    single column it would use pairwise summation over n instead, so that case is summed explicitly.
    """
    d = xt - q[:, None]
    d *= d
    if d.shape[1] == 1:
        s = d[0].copy()
        for j in range(1, d.shape[0]):
            s += d[j]
        return s
    return np.add.reduce(d, axis=0)


def _kd_order(x: np.ndarray, leaf_size: int, split_sample: int) -> np.ndarray:
    """Permutation of the rows of ``x`` (P, n) into a balanced kd order with leaves of ``leaf_size``.

    P / leaf_size must be a power of two. Every segment is split at its median (exact halves, so all
    leaves are full) along the coordinate of widest spread, estimated on a strided sample of at most
    ``split_sample`` of its points (a choice of ours: the exact spread costs a full pass per level).
    Deterministic: np.argpartition is a deterministic selection and argmax takes the lowest dimension.
    """
    p = x.shape[0]
    idx = np.arange(p)
    segs, s = 1, p
    while s > leaf_size:
        seg = idx.reshape(segs, s)
        step = max(1, s // split_sample)
        sample = x[seg[:, ::step]]  # (segs, <=split_sample, n)
        dim = (sample.max(axis=1) - sample.min(axis=1)).argmax(axis=1)
        vals = x[seg, dim[:, None]]  # (segs, s)
        half = s // 2
        part = np.argpartition(vals, half, axis=1)
        idx = np.take_along_axis(seg, part, axis=1).ravel()
        segs, s = segs * 2, half
    return idx


class _Block:
    """Bookkeeping of one static block: rows [start, start + size) of the memory."""

    __slots__ = ("start", "size", "top", "nblocks", "offset")

    def __init__(self, start: int, size: int, top: int, nblocks: list[int]):
        self.start = start
        self.size = size
        self.top = top  # height of its root nodes
        self.nblocks = nblocks  # number of F-wide node groups at heights 0..top
        self.offset = [0] * (top + 1)  # first group index at heights 0..top in the global arrays


class SampleMemory:
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
        refine_leaves: int = 8,
        leaf_order: str = "auto",
        tune_k: int | None = None,
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

        n = self._sd
        self._n = 0  # number of samples
        self._ns = 0  # samples [0, _ns) are in static blocks, [_ns, _n) in the buffer
        self._alpha = np.empty((cap, n))
        self._dalpha = np.empty((cap, self._ad))
        self._dy = np.empty((cap, self._od))
        # buffer, dimension-major: column j is sample _ns + j
        self._buf_t = np.empty((n, 2 * self._buf))
        # query scratch: rows (q, -q, 0) against boxes stored as (lo, -hi, 0)
        self._q3 = np.zeros((3, n, 1))
        self._arange_f = np.arange(self._fan)
        self._reset_index()

    # ------------------------------------------------------------------ index storage
    def _reset_index(self) -> None:
        n, b = self._sd, self._leaf
        self._blocks: list[_Block] = []
        self._boxes: list[np.ndarray] = []  # per height: (groups_cap, 3, n, F)
        self._used: list[int] = []  # per height: groups in use
        self._pts = np.empty((0, n, b))  # per leaf slot: its points, dimension-major
        self._pidx = np.empty((0, b), dtype=np.int64)  # per leaf slot: sample indices
        self._roots: list[np.ndarray] = []  # per height: group ids holding root nodes
        self._height = -1  # highest height in use

    def _plan(self, size: int) -> tuple[int, list[int]]:
        """Top height and F-wide groups per height for a block of ``size`` samples."""
        f = self._fan
        real = [size // self._leaf]
        while real[-1] > self._max_roots:
            real.append(-(-real[-1] // f))
        top = len(real) - 1
        groups = [0] * (top + 1)
        groups[top] = -(-real[top] // f)
        for h in range(top - 1, -1, -1):
            groups[h] = groups[h + 1] * f
        return top, groups

    def _ensure_height(self, h: int, groups_needed: int) -> None:
        n, f = self._sd, self._fan
        while len(self._boxes) <= h:
            self._boxes.append(np.empty((0, 3, n, f)))
            self._used.append(0)
        arr = self._boxes[h]
        if arr.shape[0] < groups_needed:
            new = np.empty((max(groups_needed, 2 * arr.shape[0], 4), 3, n, f))
            new[: self._used[h]] = arr[: self._used[h]]
            self._boxes[h] = new
        if h == 0:
            slots = groups_needed * f
            if self._pts.shape[0] < slots:
                cap = max(slots, 2 * self._pts.shape[0], 4 * f)
                pts = np.empty((cap, n, self._leaf))
                pidx = np.empty((cap, self._leaf), dtype=np.int64)
                used = self._used[0] * f
                pts[:used] = self._pts[:used]
                pidx[:used] = self._pidx[:used]
                self._pts, self._pidx = pts, pidx

    def _build_block(self, start: int, size: int) -> _Block:
        """Build the static block over rows [start, start + size) and write it after the kept blocks."""
        n, f, b = self._sd, self._fan, self._leaf
        top, groups = self._plan(size)
        blk = _Block(start, size, top, groups)
        # offsets: right after the blocks that have each height (they precede this one)
        for h in range(top + 1):
            blk.offset[h] = sum(o.nblocks[h] for o in self._blocks if o.top >= h)
        x = self._alpha[start : start + size]
        perm = self._leaf_perm(x)
        nleaf = size // b
        slots0 = groups[0] * f
        pts_t = np.ascontiguousarray(x[perm].reshape(nleaf, b, n).transpose(0, 2, 1))  # (L, n, b)
        lo = np.full((slots0, n), np.inf)
        nhi = np.full((slots0, n), np.inf)  # stores -hi
        lo[:nleaf] = pts_t.min(axis=2)
        nhi[:nleaf] = -pts_t.max(axis=2)
        for h in range(top + 1):
            self._ensure_height(h, blk.offset[h] + groups[h])
        s0 = blk.offset[0] * f
        self._pts[s0 : s0 + nleaf] = pts_t
        self._pts[s0 + nleaf : s0 + slots0] = np.nan  # empty leaf slots never match
        self._pidx[s0 : s0 + nleaf] = (perm + start).reshape(nleaf, b)
        self._pidx[s0 + nleaf : s0 + slots0] = -1
        for h in range(top + 1):
            g0 = blk.offset[h]
            box = self._boxes[h][g0 : g0 + groups[h]]
            box[:, 0] = lo.reshape(groups[h], f, n).transpose(0, 2, 1)
            box[:, 1] = nhi.reshape(groups[h], f, n).transpose(0, 2, 1)
            box[:, 2] = 0.0
            self._used[h] = g0 + groups[h]
            if h < top:  # parents: boxes of their F children
                lo = lo.reshape(groups[h], f, n).min(axis=1)
                nhi = nhi.reshape(groups[h], f, n).min(axis=1)
        return blk

    def _leaf_perm(self, x: np.ndarray) -> np.ndarray:
        """Order of the block's rows: leaf i holds rows perm[i * leaf_size:(i + 1) * leaf_size]."""
        kd = _kd_order(x, self._leaf, self._split_sample)
        if self._leaf_order == "kd":
            return kd
        nleaf = x.shape[0] // self._leaf
        centres = x.reshape(nleaf, self._leaf, -1).mean(axis=1)
        # consecutive samples per leaf; leaves in kd order of their centres so F-groups are compact
        order = _kd_order(centres, 1, self._split_sample) if nleaf > 1 else np.zeros(1, dtype=np.int64)
        tm = (order[:, None] * self._leaf + np.arange(self._leaf)).ravel()
        if self._leaf_order == "time":
            return tm
        return tm if self._leaf_cost(x, tm) < self._leaf_cost(x, kd) else kd

    # "auto" leaf order: sample queries and subset size of the cost estimate (speed only).
    _TUNE_QUERIES = 8
    _TUNE_SUBSET = 32768

    def _leaf_cost(self, x: np.ndarray, perm: np.ndarray) -> int:
        """Leaves whose box meets the k-NN ball of a few sample queries taken from the block itself."""
        p, n = x.shape
        stride = -(-p // self._TUNE_SUBSET)
        sub = np.ascontiguousarray(x[::stride].T)
        k = max(1, min(sub.shape[1] - 1, round(self._tune_k / stride)))
        pts = x[perm].reshape(p // self._leaf, self._leaf, n)
        lo, hi = pts.min(axis=1), pts.max(axis=1)
        cost = 0
        for i in range(self._TUNE_QUERIES):
            q = x[(2 * i + 1) * p // (2 * self._TUNE_QUERIES)]
            r = np.partition(_sqdist_cols(sub, q), k)[k]
            gap = np.maximum(np.maximum(lo - q, q - hi), 0.0)
            cost += int(np.count_nonzero(np.einsum("ij,ij->i", gap, gap) <= r))
        return cost

    def _refresh_roots(self) -> None:
        self._height = max((blk.top for blk in self._blocks), default=-1)
        self._roots = []
        for h in range(self._height + 1):
            firsts = [blk.offset[h] for blk in self._blocks if blk.top == h]
            end = sum(blk.nblocks[h] for blk in self._blocks if blk.top >= h)
            self._roots.append(np.arange(firsts[0], end) if firsts else np.empty(0, dtype=np.int64))
            self._used[h] = end
        for h in range(self._height + 1, len(self._used)):
            self._used[h] = 0

    def _index_batch(self) -> None:
        """Move the oldest buffer_size buffered samples into the static blocks (binary-counter merge)."""
        bsz = self._buf
        start, size = self._ns, bsz
        while self._blocks and self._blocks[-1].size == size:
            start = self._blocks.pop().start
            size *= 2
        self._blocks.append(self._build_block(start, size))
        self._ns += bsz
        self._refresh_roots()
        nb = self._n - self._ns
        self._buf_t[:, :nb] = self._buf_t[:, bsz : bsz + nb]

    def _rebuild_all(self) -> None:
        """Build the index of the current rows exactly as incremental adds would have left it."""
        self._reset_index()
        bsz = self._buf
        flushes = max(0, (self._n - bsz) // bsz)
        start = 0
        for bit in range(flushes.bit_length() - 1, -1, -1):
            if flushes >> bit & 1:
                size = bsz << bit
                self._blocks.append(self._build_block(start, size))
                start += size
        self._ns = start
        self._refresh_roots()
        self._buf_t[:, : self._n - self._ns] = self._alpha[self._ns : self._n].T

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
        total += sum(r.nbytes for r in self._roots)
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
        if not q.dot(q) < np.inf and not np.isfinite(q).all():
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
        nb = n_all - ns
        bd = _sqdist_cols(self._buf_t[:, :nb], q) if nb else np.empty(0)
        bound = np.partition(bd, k - 1)[k - 1] if nb >= k else np.inf
        if self._height < 0:  # everything is in the buffer
            leaf_d = leaf_i = None
        else:
            q3 = self._q3
            q3[0, :, 0] = q
            np.negative(q, out=q3[1, :, 0])
            fan = self._fan
            sel = None  # node ids at the height above = group ids at this height
            refined = False
            for h in range(self._height, -1, -1):
                roots = self._roots[h]
                if sel is None or not len(sel):
                    if not len(roots):
                        sel = None
                        continue
                    groups = roots
                    g = self._boxes[h][roots[0] : roots[-1] + 1] - q3
                else:
                    groups = np.concatenate((sel, roots)) if len(roots) else sel
                    g = self._boxes[h][groups]
                    g -= q3
                lb = g.max(axis=1)
                lb *= lb
                lb = np.add.reduce(lb, axis=1)  # (groups, F): squared box distances, canonical order
                keep = lb <= bound
                gi, slot = keep.nonzero()
                if not refined and len(gi) > self._refine_nodes:
                    refined = True
                    better = self._refine_bound(h, groups, lb, q, k, bd)
                    if better < bound:
                        bound = better
                        gi, slot = (lb <= bound).nonzero()
                sel = groups[gi]
                sel *= fan
                sel += slot
            if sel is None or not len(sel):
                leaf_d = leaf_i = None
            else:
                p = self._pts[sel]
                p -= q[:, None]
                p *= p
                leaf_d = np.add.reduce(p, axis=1).ravel()
                leaf_i = self._pidx[sel].ravel()
        if leaf_d is None:
            all_d, all_i = bd, np.arange(ns, n_all)
        else:
            all_d = np.concatenate((bd, leaf_d))
            all_i = np.concatenate((np.arange(ns, n_all), leaf_i))
        m = all_d <= bound
        cd, ci = all_d[m], all_i[m]
        return ci[np.lexsort((ci, cd))[:k]]

    def _refine_bound(self, h, groups, lb, q, k, bd) -> float:
        """Upper bound on the k-th distance from a greedy beam descent to the most promising leaves.

        Keeps the ``width`` nodes of smallest box distance at each height, scans their leaves and
        returns the k-th smallest distance among those points and the buffer: an upper bound of the
        true k-th distance (any k stored points give one). Speed only, never results.
        """
        fan = self._fan
        width = max(self._refine_leaves, -(-k // self._leaf) + 1)
        q3 = self._q3
        nodes = (groups[:, None] * fan + self._arange_f).ravel()
        flat = lb.ravel()
        for hh in range(h, -1, -1):
            if len(nodes) > width:
                pick = np.argpartition(flat, width - 1)[:width]
                nodes = nodes[pick]
            if hh == 0:
                break
            g = self._boxes[hh - 1][nodes]
            g -= q3
            m = g.max(axis=1)
            m *= m
            flat = np.add.reduce(m, axis=1).ravel()
            nodes = (nodes[:, None] * fan + self._arange_f).ravel()
        p = self._pts[nodes]
        p -= q[:, None]
        p *= p
        d = np.concatenate((bd, np.add.reduce(p, axis=1).ravel()))
        if len(d) < k:
            return np.inf
        kth = np.partition(d, k - 1)[k - 1]
        return kth if kth == kth else np.inf  # NaN (empty leaf slots) -> no bound

    # ------------------------------------------------------------------ persistence
    def digest(self) -> str:
        """sha256 hex over the dims, the length and the filled arrays (little-endian float64, C order)."""
        h = hashlib.sha256(_DIGEST_TAG)
        h.update(np.array([self._sd, self._ad, self._od, self._n], dtype="<i8").tobytes())
        for arr in (self._alpha, self._dalpha, self._dy):
            h.update(np.ascontiguousarray(arr[: self._n], dtype="<f8").data)
        return h.hexdigest()

    def _params(self) -> np.ndarray:
        return np.array(
            [
                _FORMAT_VERSION,
                self._sd,
                self._ad,
                self._od,
                self._buf,
                self._leaf,
                self._fan,
                self._max_roots,
                self._split_sample,
                self._refine_nodes,
                self._refine_leaves,
                _LEAF_ORDERS.index(self._leaf_order),
                self._tune_k,
            ],
            dtype=np.int64,
        )

    def save(self, path) -> None:
        """Atomically write an .npz (no pickle): <path>.tmp.npz, then os.replace onto ``path``."""
        path = os.fspath(path)
        tmp = path + ".tmp.npz"
        with open(tmp, "wb") as fh:
            np.savez(
                fh,
                params=self._params(),
                alpha=self._alpha[: self._n],
                delta_alpha=self._dalpha[: self._n],
                delta_y=self._dy[: self._n],
                digest=np.array(self.digest()),
            )
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)

    @classmethod
    def load(cls, path) -> "SampleMemory":
        """Read a file written by :meth:`save`; the index is rebuilt exactly as it was."""
        with np.load(os.fspath(path), allow_pickle=False) as z:
            missing = {"params", "alpha", "delta_alpha", "delta_y", "digest"} - set(z.files)
            if missing:
                raise ValueError(f"path is not a SampleMemory file: missing {sorted(missing)}")
            params = z["params"]
            alpha, dalpha, dy = z["alpha"], z["delta_alpha"], z["delta_y"]
            digest = str(z["digest"])
        if params.shape != (13,) or int(params[0]) != _FORMAT_VERSION:
            raise ValueError(f"path has an unsupported SampleMemory format (params {params.tolist()})")
        _, sd, ad, od, buf, leaf, fan, roots, split, refine, rleaves, order, tune_k = (int(v) for v in params)
        if not 0 <= order < len(_LEAF_ORDERS):
            raise ValueError(f"path has an unknown leaf_order code {order}")
        mem = cls(
            sd, ad, od, capacity=max(1, alpha.shape[0]), buffer_size=buf, leaf_size=leaf, fanout=fan,
            max_roots=roots, split_sample=split, refine_nodes=refine, refine_leaves=rleaves,
            leaf_order=_LEAF_ORDERS[order], tune_k=tune_k,
        )
        n = alpha.shape[0]
        for name, arr, dim in (("alpha", alpha, sd), ("delta_alpha", dalpha, ad), ("delta_y", dy, od)):
            if arr.dtype != np.float64 or arr.shape != (n, dim):
                raise ValueError(f"{name} in file must be float64 of shape ({n}, {dim}), got {arr.dtype} {arr.shape}")
            if not np.isfinite(arr).all():
                raise ValueError(f"{name} in file must be finite")
        mem._alpha[:n], mem._dalpha[:n], mem._dy[:n] = alpha, dalpha, dy
        mem._n = n
        if mem.digest() != digest:
            raise ValueError("file digest does not match its content (corrupted file)")
        mem._rebuild_all()
        return mem
