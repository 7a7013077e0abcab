"""The canonical squared distance of the sample memory, shared by every search path.

Every squared distance is summed over the coordinates in index order, sequentially (coordinate 0, 1,
..., n-1), whichever path found the point (buffer, leaves, trajectory cache, brute force): distances
are bit-identical across paths, which makes ties exact and results independent of the index.
Layouts are dimension-major ((n, points)) so numpy's inner loops run over points, not over the
7-30 coordinates.
"""

from __future__ import annotations

import numpy as np

__all__ = ["squared_distances", "sum_squares_rows"]


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
    return sum_squares_rows(xt - q[:, None])


def sum_squares_rows(d: np.ndarray) -> np.ndarray:
    """Canonical squared norms of the columns of the C-contiguous coordinate differences ``d`` (n, c),
    overwritten (squared in place): coordinates summed in index order, sequentially. Differences
    of many (query, point) pairs laid out as columns give their canonical distances in one call."""
    d *= d
    if d.shape[1] == 1:
        s = d[0].copy()
        for j in range(1, d.shape[0]):
            s += d[j]
        return s
    return np.add.reduce(d, axis=0)
