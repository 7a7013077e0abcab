"""The static-block index of the sample memory: which stored alpha live in which leaf and box.

A mixin of :class:`sagg_low_level.memory.SampleMemory` (one object; this module owns the index
state: ``_ns``, the buffer ``_buf_t``, ``_blocks``, ``_boxes``, ``_used``, ``_pts``, ``_pidx``,
``_roots``, ``_root_groups``, ``_height``, the duplicate groups ``_dup``, ``_dup_off``,
``_ngroups``, ``_dupmap``, ``_ginfo``; it reads the stored rows ``_alpha`` / ``_n``).

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
* Approximate mode (``checks > 0``): blocks use kd leaves (``leaf_order="auto"`` means "kd" there:
  ranking leaves by their box distance works best on compact kd cells: on the learner's own queries
  after ``sagg bench speed``'s prefill to 1M samples, kd leaves recall more of the exact neighbours
  than the exact mode's per-block choice, and ranking by distance to the leaf's centroid
  (k-means-like) or box centre does no better), and exact duplicates of the query (the rest posture)
  are always found through a hash of the duplicate groups.

Pauses: a block build is done inside the ``add`` that triggers it. Builds double in size (binary
counter): the add that creates a 512k-sample block (once per 512k adds) takes on the order of a
second, the 1M-sample merge about twice that. In-process runs just take the pause; a real-time robot
loop would see that add stall (building the new block in a background thread while queries use the
old blocks is the remedy, not done here).
"""

from __future__ import annotations

import numpy as np

from .memory_distance import _sqdist_cols

LEAF_ORDERS = ("auto", "kd", "time")


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
        # NaN rows (padding) are ignored by fmax/fmin and sort last in argpartition
        dim = (np.fmax.reduce(sample, axis=1) - np.fmin.reduce(sample, axis=1)).argmax(axis=1)
        vals = x[seg, dim[:, None]]  # (segs, s)
        half = s // 2
        part = np.argpartition(vals, half, axis=1)
        idx = np.take_along_axis(seg, part, axis=1).ravel()
        segs, s = segs * 2, half
    return idx


class _Block:
    """Bookkeeping of one static block: rows [start, start + size) of the memory."""

    __slots__ = ("start", "size", "top", "nblocks", "offset", "ngroups", "nmembers")

    def __init__(self, start: int, size: int, top: int, nblocks: list[int]):
        self.start = start
        self.size = size
        self.top = top  # height of its root nodes
        self.nblocks = nblocks  # number of F-wide node groups at heights 0..top
        self.offset = [0] * (top + 1)  # first group index at heights 0..top in the global arrays
        self.ngroups = 0  # groups of exact duplicates (stored once in the leaves)
        self.nmembers = 0  # samples in those groups


class BlockIndex:
    """Index state and its builds (mixin of SampleMemory; see the module docstring)."""

    def _init_index(self) -> None:
        n = self._sd
        self._ns = 0  # samples [0, _ns) are in static blocks, [_ns, _n) in the buffer
        # buffer, dimension-major: column j is sample _ns + j
        self._buf_t = np.empty((n, 2 * self._buf))
        self._reset_index()

    def _reset_index(self) -> None:
        n = self._sd
        self._blocks: list[_Block] = []
        # per height: (3, n, slots) rows (lo, -hi, 0) of every node's box; node id = slot; a node
        # at height h + 1 with id j has the children slots j*F .. j*F + F - 1 at height h
        self._boxes: list[np.ndarray] = []
        self._used: list[int] = []  # per height: F-wide groups in use
        self._pts = np.empty((n, 0))  # leaf slot j holds points j*b .. j*b + b - 1, dimension-major
        self._pidx = np.empty(0, dtype=np.int64)  # their sample indices
        self._roots: list[tuple[int, int]] = []  # per height: slot range of root nodes
        self._root_groups: list[np.ndarray] = []  # per height: F-wide groups of the root nodes
        self._height = -1  # highest height in use
        # Exact duplicates of alpha (the rest posture after every reset!) would be spread by the
        # median splits over almost every leaf of a block, each leaf box then reaching from the
        # duplicate to its other points. So a block stores each distinct alpha once; a leaf slot of
        # a point standing for a group holds -(group + 2) in _pidx, and the group's sample indices
        # (ascending) are _dup[_dup_off[group]:_dup_off[group + 1]].
        self._dup = np.empty(0, dtype=np.int64)
        self._dup_off = np.zeros(1, dtype=np.int64)
        self._ngroups = 0
        # approximate mode: alpha bytes of every group -> its group ids, and group id -> (bytes,
        # leaf slot holding its representative), so a query equal to a stored duplicate always
        # scans that leaf (with r = 1 every attempt's first query is the rest posture itself)
        self._dupmap: dict[bytes, list[int]] = {}
        self._ginfo: dict[int, tuple[bytes, int]] = {}

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
        n, f, b = self._sd, self._fan, self._leaf
        while len(self._boxes) <= h:
            self._boxes.append(np.empty((3, n, 0)))
            self._used.append(0)
        arr = self._boxes[h]
        slots = groups_needed * f
        if arr.shape[2] < slots:
            new = np.empty((3, n, max(slots, 2 * arr.shape[2], 4 * f)))
            used = self._used[h] * f
            new[:, :, :used] = arr[:, :, :used]
            self._boxes[h] = new
        if h == 0 and self._pts.shape[1] < slots * b:
            cap = max(slots * b, 2 * self._pts.shape[1])
            pts = np.empty((n, cap))
            pidx = np.empty(cap, dtype=np.int64)
            used = self._used[0] * f * b
            pts[:, :used] = self._pts[:, :used]
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
        x, ids = self._distinct_rows(blk, start, size)  # (size, n): distinct alpha, NaN padding
        perm = self._leaf_perm(x)
        nleaf = size // b
        slots0 = groups[0] * f
        xp = x[perm]  # (size, n) in leaf order
        leaves = xp.reshape(nleaf, b, n)
        lo = np.full((n, slots0), np.inf)
        nhi = np.full((n, slots0), np.inf)  # -hi
        with np.errstate(invalid="ignore"):
            lo[:, :nleaf] = np.fmin.reduce(leaves, axis=1).T  # NaN only for all-padding leaves
            nhi[:, :nleaf] = -np.fmax.reduce(leaves, axis=1).T
        lo[np.isnan(lo)] = np.inf
        nhi[np.isnan(nhi)] = np.inf
        for h in range(top + 1):
            self._ensure_height(h, blk.offset[h] + groups[h])
        p0, p1, p2 = blk.offset[0] * f * b, (blk.offset[0] * f + nleaf) * b, (blk.offset[0] * f + slots0) * b
        self._pts[:, p0:p1] = xp.T
        self._pts[:, p1:p2] = np.nan  # empty leaf slots never match
        self._pidx[p0:p1] = ids[perm]
        self._pidx[p1:p2] = -1
        if self._checks:
            self._hash_groups(blk, ids[perm], xp, p0)
        for h in range(top + 1):
            s0, cnt = blk.offset[h] * f, groups[h] * f
            box = self._boxes[h]
            box[0, :, s0 : s0 + cnt] = lo
            box[1, :, s0 : s0 + cnt] = nhi
            box[2, :, s0 : s0 + cnt] = 0.0
            self._used[h] = blk.offset[h] + groups[h]
            if h < top:  # parents: boxes of their F children
                lo = lo.reshape(n, groups[h], f).min(axis=2)
                nhi = nhi.reshape(n, groups[h], f).min(axis=2)
        return blk

    def _hash_groups(self, blk: _Block, codes: np.ndarray, xp: np.ndarray, p0: int) -> None:
        """Register the block's duplicate groups in _dupmap/_ginfo (after dropping merged blocks')."""
        g0 = self._ngroups - blk.ngroups  # groups of the blocks kept before this one
        for g in [g for g in self._ginfo if g >= g0]:
            key = self._ginfo.pop(g)[0]
            ids = self._dupmap[key]
            ids.remove(g)
            if not ids:
                del self._dupmap[key]
        for pos in np.flatnonzero(codes < -1).tolist():
            g = -int(codes[pos]) - 2
            key = (xp[pos] + 0.0).tobytes()  # + 0.0: -0.0 -> 0.0, equal values give equal keys
            self._ginfo[g] = (key, (p0 + pos) // self._leaf)
            self._dupmap.setdefault(key, []).append(g)

    def _distinct_rows(self, blk: _Block, start: int, size: int) -> tuple[np.ndarray, np.ndarray]:
        """The block's rows with exact duplicates stored once, and their _pidx codes.

        Returns (x, codes): the distinct rows in index order followed by NaN padding up to ``size``
        rows, and per row its sample index, or -(group + 2) for the first sample of a group of
        identical rows (whose samples are appended to _dup), or -1 for padding.
        """
        x = self._alpha[start : start + size]
        # groups are appended after those of the blocks kept before this one
        g0 = sum(o.ngroups for o in self._blocks)
        m0 = sum(o.nmembers for o in self._blocks)
        self._ngroups = g0
        # identical rows share their first coordinate: a float sort finds the few candidates,
        # only those are compared whole
        o = np.argsort(x[:, 0], kind="stable")
        first_col = x[o, 0]
        eq = first_col[1:] == first_col[:-1]
        if not eq.any():
            return x, np.arange(start, start + size)
        rep = np.zeros(size, dtype=bool)
        rep[1:] = eq
        rep[:-1] |= eq
        cand = np.sort(o[rep])  # rows whose first coordinate repeats, ascending
        keys = np.ascontiguousarray(x[cand]).view(np.dtype((np.void, 8 * x.shape[1]))).ravel()
        _, first, inverse, counts = np.unique(keys, return_index=True, return_inverse=True, return_counts=True)
        inverse = inverse.ravel()
        grp = np.flatnonzero(counts > 1)
        if not len(grp):
            return x, np.arange(start, start + size)
        order = np.argsort(inverse, kind="stable")  # grouped by value, ascending index inside
        members = cand[order[counts[inverse[order]] > 1]]  # local rows, group after group
        blk.ngroups, blk.nmembers = len(grp), len(members)
        self._dup = np.concatenate((self._dup[:m0], members + start))
        self._dup_off = np.concatenate((self._dup_off[: g0 + 1], m0 + np.cumsum(counts[grp])))
        self._ngroups = g0 + len(grp)
        firsts = cand[first[grp]]
        kept = np.ones(size, dtype=bool)
        kept[members] = False
        kept[firsts] = True
        codes = np.arange(start, start + size)
        codes[firsts] = -(g0 + np.arange(len(grp))) - 2
        distinct = np.flatnonzero(kept)
        xd = np.full(x.shape, np.nan)
        xd[: len(distinct)] = x[distinct]
        out = np.full(size, -1, dtype=np.int64)
        out[: len(distinct)] = codes[distinct]
        return xd, out

    def _leaf_perm(self, x: np.ndarray) -> np.ndarray:
        """Order of the block's rows: leaf i holds rows perm[i * leaf_size:(i + 1) * leaf_size]."""
        kd = _kd_order(x, self._leaf, self._split_sample)
        if self._leaf_order == "kd" or (self._leaf_order == "auto" and self._checks):
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
        u = p - int(np.count_nonzero(np.isnan(x[:, 0])))  # distinct rows (then NaN padding)
        stride = -(-u // self._TUNE_SUBSET)
        sub = np.ascontiguousarray(x[:u:stride].T)
        k = max(1, min(sub.shape[1] - 1, round(self._tune_k / stride)))
        pts = x[perm].reshape(p // self._leaf, self._leaf, n)
        lo, hi = pts.min(axis=1), pts.max(axis=1)
        cost = 0
        for i in range(self._TUNE_QUERIES):
            q = x[(2 * i + 1) * u // (2 * self._TUNE_QUERIES)]
            r = np.partition(_sqdist_cols(sub, q), k)[k]
            gap = np.maximum(np.maximum(lo - q, q - hi), 0.0)
            cost += int(np.count_nonzero(np.einsum("ij,ij->i", gap, gap) <= r))
        return cost

    def _refresh_roots(self) -> None:
        self._height = max((blk.top for blk in self._blocks), default=-1)
        self._roots = []
        f = self._fan
        for h in range(self._height + 1):
            firsts = [blk.offset[h] for blk in self._blocks if blk.top == h]
            end = sum(blk.nblocks[h] for blk in self._blocks if blk.top >= h)
            self._roots.append((firsts[0] * f, end * f) if firsts else (0, 0))
            self._used[h] = end
        self._root_groups = [np.arange(r0 // f, r1 // f) for r0, r1 in self._roots]  # F-aligned
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

    def _buffer_add(self, i: int, a: np.ndarray) -> None:
        """Sample i (alpha ``a``) was just stored: append it to the buffer, flush a full buffer."""
        self._buf_t[:, i - self._ns] = a
        if self._n - self._ns == 2 * self._buf:
            self._index_batch()
