"""Many approximate k-nearest-neighbour queries at once, with the answers of one query at a time.

:func:`neighbours_many` returns, row for row, exactly what ``memory.neighbours(q, k)`` returns (the
same sample indices in the same order), for a frozen memory: the evaluation reaches all its test
goals together (:mod:`sagg_low_level.reach_batch`) and asks one query per test goal and step.

It replays the approximate search of :meth:`KnnSearch._knn_approx` (``checks > 0``, the paper's
FLANN-like search) for all queries with one set of numpy calls per box height instead of one per
query: the same candidates in the same order, the same box and point distances (summed over the
coordinates in index order, sequentially, as :mod:`sagg_low_level.memory_distance` defines them, so
they are bit-identical), the same bound, the same cap with the same tie order (a stable sort on the
candidates in order), the same k-th distance and the same final order by (distance, index). Rows
that leave that common case are answered by the memory's own one-query search: k not below the
memory size, a query with exact stored copies (the rest posture:
duplicate groups) or fewer than k samples scanned. Rows with a duplicate group among the answer's
candidates finish with the one-query search's last step on their own candidates. Identical query
rows are searched once. In exact mode (``checks = 0``) a small memory is scanned whole for all rows
(the exact answer is unique: canonical distances, ties by index), a large one answers row by row.
"""
from __future__ import annotations

import numpy as np

__all__ = ["neighbours_many"]

_PAD = np.iinfo(np.int64).max  # sample index of padding entries (sorts after every real index)
# exact mode: scan every sample when (samples × dimensions) is at most this (speed only: measured on
# the fixed-context arm, 15 dims, 5k samples, a scan of all samples costs a fraction of an index
# query there; the scan grows with the memory, the index does not)
BRUTE_FORCE_MAX = 200_000
_CHUNK = 16  # queries per scan (bounds the work array to _CHUNK × samples × dimensions)


class _Scratch:
    """Reused work arrays (fresh large temporaries cost more in page faults than the arithmetic)."""

    def __init__(self):
        self._bufs: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple, dtype=np.float64) -> np.ndarray:
        size = int(np.prod(shape))
        buf = self._bufs.get(name)
        if buf is None or buf.size < size or buf.dtype != dtype:
            buf = self._bufs[name] = np.empty(max(size, 1) * 2, dtype=dtype)
        return buf[:size].reshape(shape)


_SCRATCH = _Scratch()


def _seq_sum(sq: np.ndarray) -> np.ndarray:
    """Sum over axis 0, sequentially in index order (the canonical order of memory_distance)."""
    s = sq[0].copy()
    for j in range(1, sq.shape[0]):
        s += sq[j]
    return s


def _compact(mask: np.ndarray, values: np.ndarray, fill) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the entries of ``values`` where ``mask``, in column order, left-aligned and padded
    with ``fill``: (B, max count) array and the counts."""
    counts = mask.sum(axis=1)
    width = int(counts.max()) if len(counts) else 0
    out = np.full((mask.shape[0], width), fill, dtype=values.dtype)
    rows, cols = np.nonzero(mask)
    if len(rows):
        starts = np.concatenate(([0], np.cumsum(counts)[:-1]))
        out[rows, np.arange(len(rows)) - starts[rows]] = values[rows, cols]
    return out, counts


def neighbours_many(mem, queries: np.ndarray, k: int) -> np.ndarray:
    """(B, min(k, len)) array: row i is ``mem.neighbours(queries[i], k)``, bit for bit."""
    qs = np.asarray(queries, dtype=np.float64)
    if qs.ndim != 2 or qs.shape[1] != mem._sd:
        raise ValueError(f"queries must have shape (B, {mem._sd}), got {qs.shape}")
    if not np.isfinite(qs).all():
        raise ValueError("queries must be finite (no NaN/inf)")
    k = mem._check_k(k)
    out = np.empty((len(qs), min(k, mem._n)), dtype=np.int64)
    if not len(qs):
        return out
    uniq, inverse = np.unique(qs, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    res = np.empty((len(uniq), out.shape[1]), dtype=np.int64)
    if not mem._checks and mem._n * mem._sd <= BRUTE_FORCE_MAX:
        # exact mode: the exact answer is unique (canonical distances, ties by index), so a scan
        # of every sample gives it; cheaper than the index for small memories (speed only)
        for c in range(0, len(uniq), _CHUNK):
            res[c : c + _CHUNK] = _exact_many(mem, uniq[c : c + _CHUNK], k)
        slow = np.zeros(len(uniq), dtype=bool)
    elif k >= mem._n or not mem._checks:
        slow = np.ones(len(uniq), dtype=bool)
    else:
        slow = np.array([bool(mem._dupmap.get((q + 0.0).tobytes())) for q in uniq]) if mem._dupmap \
            else np.zeros(len(uniq), dtype=bool)
        fast = np.flatnonzero(~slow)
        if len(fast):
            got, ok = _approx_many(mem, np.ascontiguousarray(uniq[fast]), k)
            res[fast[ok]] = got[ok]
            slow[fast[~ok]] = True
    for i in np.flatnonzero(slow):
        res[i] = mem._knn(np.ascontiguousarray(uniq[i]), k)
    out[:] = res[inverse]
    return out


def _exact_many(mem, Q: np.ndarray, k: int) -> np.ndarray:
    """The exact k nearest of each row of Q by a scan of every stored sample: canonical squared
    distances (coordinates summed in index order), the k smallest by (distance, index)."""
    n_all = mem._n
    xt = mem._alpha[:n_all].T  # (n, N)
    d = np.subtract(xt[:, None, :], np.ascontiguousarray(Q.T)[:, :, None],
                    out=_SCRATCH.get("ex", (Q.shape[1], len(Q), n_all)))
    d *= d
    dist = _seq_sum(d)  # (B, N)
    kk = min(k, n_all)
    kth = np.partition(dist, kk - 1, axis=1)[:, kk - 1]
    keep = dist <= kth[:, None]
    kd, _ = _compact(keep, dist, np.inf)
    ki, _ = _compact(keep, np.broadcast_to(np.arange(n_all), dist.shape), _PAD)
    order = np.lexsort((ki, kd), axis=-1)[:, :kk]
    return np.take_along_axis(ki, order, axis=1)


def _approx_many(mem, Q: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The approximate search of ``KnnSearch._knn_approx`` for the rows of Q (none of which has an
    exact stored copy). Returns (B, k) indices and whether each row stayed in the common case
    (False: answer it with the one-query search)."""
    B, n = Q.shape
    QT = np.ascontiguousarray(Q.T)
    n_all, ns = mem._n, mem._ns
    nb = n_all - ns
    ok = np.ones(B, dtype=bool)
    if nb:
        d = np.subtract(mem._buf_t[:, :nb][:, None, :], QT[:, :, None], out=_SCRATCH.get("bd", (n, B, nb)))
        d *= d
        bd = _seq_sum(d)
    else:
        bd = np.empty((B, 0))
    bound = np.partition(bd, k - 1, axis=1)[:, k - 1] if nb >= k else np.full(B, np.finfo(np.float64).max)
    sel = np.empty((B, 0), dtype=np.int64)  # kept node ids at the height above, left-aligned
    cnt = np.zeros(B, dtype=np.int64)
    if mem._height >= 0:
        fan = mem._fan
        for h in range(mem._height, -1, -1):
            roots = mem._root_groups[h]
            r = len(roots)
            width = int(cnt.max()) + r if B else 0
            if width == 0:
                sel, cnt = np.empty((B, 0), dtype=np.int64), np.zeros(B, dtype=np.int64)
                continue
            # candidate groups per row: its kept nodes, then the root groups, then padding
            col = np.arange(width)
            groups = np.full((B, width), -1, dtype=np.int64)
            if sel.shape[1]:
                take = col[None, : sel.shape[1]] < cnt[:, None]
                groups[:, : sel.shape[1]][take] = sel[take]
            if r:
                j = col[None, :] - cnt[:, None]
                is_root = (j >= 0) & (j < r)
                groups[is_root] = roots[j[is_root]]
            valid = groups >= 0
            boxes = mem._boxes[h]
            b4 = boxes.reshape(3, n, boxes.shape[2] // fan, fan)
            # rows lo and -hi (the third row of every box is 0.0, the max's floor)
            g = np.take(b4[:2], np.where(valid, groups, 0), axis=2,
                        out=_SCRATCH.get("g", (2, n, B, width, fan)))  # (2, n, B, width, fan)
            g[0] -= QT[:, :, None, None]
            g[1] += QT[:, :, None, None]   # boxes hold -hi: -hi - (-q)
            lb = np.maximum(g[0], g[1], out=g[0])
            np.maximum(lb, 0.0, out=lb)
            lb *= lb
            lb = _seq_sum(lb)  # (B, width, fan)
            lb[~valid] = np.inf
            lb = lb.reshape(B, width * fan)
            keep = lb <= bound[:, None]
            cap = mem._widths[h]
            kcount = keep.sum(axis=1)
            pos, newcnt = _compact(keep, np.broadcast_to(np.arange(width * fan), keep.shape), -1)
            over = np.flatnonzero(kcount > cap)
            if len(over):
                key = np.where(keep[over], lb[over], np.inf)
                order = np.argsort(key, axis=1, kind="stable")[:, :cap]
                pos = pos[:, :cap].copy()  # (over rows hold more than cap entries: width > cap)
                pos[over] = order
                newcnt = np.minimum(newcnt, cap)
                pos = pos[:, : int(newcnt.max())]
            validp = np.arange(pos.shape[1])[None, :] < newcnt[:, None]
            gsel = np.take_along_axis(groups, np.where(validp, pos // fan, 0), axis=1)
            sel = np.where(validp, gsel * fan + pos % fan, -1)
            cnt = newcnt
    leaf = mem._leaf
    if sel.shape[1]:
        validl = np.arange(sel.shape[1])[None, :] < cnt[:, None]
        sl = np.where(validl, sel, 0)
        p = np.take(mem._pts.reshape(n, mem._pts.shape[1] // leaf, leaf), sl, axis=1,
                    out=_SCRATCH.get("p", (n, B, sl.shape[1], leaf)))  # (n, B, S, leaf)
        p -= QT[:, :, None, None]
        p *= p
        ld = _seq_sum(p)  # (B, S, leaf); empty leaf slots are NaN
        ld[~validl] = np.inf
        li = mem._pidx.reshape(-1, leaf)[sl]  # (B, S, leaf)
        li = np.where(validl[:, :, None], li, _PAD)
        mem.leaves_scanned += int(cnt.sum())
        cd = np.concatenate((bd, ld.reshape(B, -1)), axis=1)
        ci = np.concatenate((np.broadcast_to(np.arange(ns, n_all), (B, nb)), li.reshape(B, -1)), axis=1)
    else:
        cd, ci = bd, np.broadcast_to(np.arange(ns, n_all), (B, nb))
    cd = np.where(np.isnan(cd), np.inf, cd)  # empty slots: never among the answer
    if cd.shape[1] < k:
        return np.zeros((B, k), dtype=np.int64), np.zeros(B, dtype=bool)
    kth = np.partition(cd, k - 1, axis=1)[:, k - 1]
    ok &= kth < np.inf  # fewer than k samples scanned: the one-query search decides
    keep = cd <= kth[:, None]
    kd, kc = _compact(keep, cd, np.inf)
    ki, _ = _compact(keep, np.ascontiguousarray(ci), _PAD)
    order = np.lexsort((ki, kd), axis=-1)[:, :k]
    got = np.take_along_axis(ki, order, axis=1)
    # rows with a duplicate group among the candidates: the one-query tail on the row's candidates
    # (the group's samples replace its code, then the k-th distance and the order again)
    for i in np.flatnonzero(ok & np.any(ki < -1, axis=1)):
        rd, ri = kd[i, : kc[i]], ki[i, : kc[i]]
        rd, ri = mem._expand_groups(rd, ri, k)
        rk = np.partition(rd, k - 1)[k - 1]
        sel_i = rd <= rk
        rd, ri = rd[sel_i], ri[sel_i]
        got[i] = ri[np.lexsort((ri, rd))[:k]]
    return got, ok
