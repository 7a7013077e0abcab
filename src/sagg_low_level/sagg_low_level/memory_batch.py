"""Many k-nearest-neighbour queries of a frozen memory at once, with the answers of one query at a time.

:func:`neighbours_many` returns, row for row, exactly what ``memory.neighbours(q, k)`` returns (the
same sample indices in the same order), for a frozen memory: the evaluation reaches all its test
goals together (:mod:`sagg_low_level.reach_batch`) and asks one query per test goal and step.
Identical query rows are searched once. In approximate mode (``checks > 0``, the paper's FLANN-like
search) each row is the memory's own search, one compiled walk per row
(:meth:`KnnSearch._knn_approx`; cheaper than a numpy replay of that walk for all rows at once).
In exact mode (``checks = 0``) a small memory is scanned whole for all rows (the exact answer is
unique: canonical distances, ties by index), a large one answers row by row.
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
    # identical rows are searched once: the first of each, by its bytes (cheaper than
    # np.unique(axis=0) on the evaluation's 100 rows; equal rows give equal answers, so the order of
    # the distinct rows does not matter)
    slot: dict[bytes, int] = {}  # a row's bytes -> its distinct row's number
    rows: list[int] = []  # the first row of each distinct one
    inverse = np.empty(len(qs), dtype=np.intp)
    for i, row in enumerate(qs):
        key = row.tobytes()
        j = slot.get(key)
        if j is None:
            j = slot[key] = len(rows)
            rows.append(i)
        inverse[i] = j
    uniq = qs[rows] if len(rows) < len(qs) else qs
    res = np.empty((len(uniq), out.shape[1]), dtype=np.int64)
    if not mem._checks and mem._n * mem._sd <= BRUTE_FORCE_MAX:
        # exact mode: the exact answer is unique (canonical distances, ties by index), so a scan
        # of every sample gives it; cheaper than the index for small memories (speed only)
        for c in range(0, len(uniq), _CHUNK):
            res[c : c + _CHUNK] = _exact_many(mem, uniq[c : c + _CHUNK], k)
    else:  # the memory's own search, one query at a time (approximate: one compiled walk each)
        for i in range(len(uniq)):
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
