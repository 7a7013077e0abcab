"""The effector's point at the stored postures, rebuilt from the memory's own measurements, and
searchable by point: where ``/sagg/compute_ik`` starts its reach (:mod:`.ik`). ROS-free.

The memory stores displacements (α, Δα, Δy) of consecutive micro-actions, no absolute point. A
point is known where a chain of stored samples leads back to the rest posture, whose point the
learner measures (its *rest point*): :func:`sample_points`. Our choice (the paper keeps no
points), and exact: every Δy is a difference of two measurements, so the sum along a chain is the
last measurement itself (up to float rounding), not a model's prediction.

:class:`KnownPoints` holds the end postures whose point is known, their points relative to the
rest point (so a re-measured rest point needs no rebuild), and a search tree over those points
(scipy's ``cKDTree``). It follows a memory that grows (the learner node serves ``compute_ik``
while it learns): new rows are rebuilt from the last known end onward, and the tree is rebuilt
once the points it does not cover reach a quarter of those it does (searched by brute force
meanwhile). The prior's samples (:mod:`.prior`, another run's) are left out: their chains and
their rest point are not this run's.
"""
from __future__ import annotations

import numpy as np

__all__ = ["SAME_POSTURE", "KnownPoints", "sample_points"]

SAME_POSTURE = 1e-9  # rad: two postures this close (each joint) are one (a + (b - a) may miss b by an ulp)
REBUILD_SHARE = 4    # the tree is rebuilt once the points outside it reach 1/REBUILD_SHARE of those in it
MIN_UNTREED = 256    # ... and at least this many (below, a brute-force scan costs microseconds)


def sample_points(alpha: np.ndarray, delta_alpha: np.ndarray, delta_y: np.ndarray, rest: np.ndarray,
                  rest_point: np.ndarray, previous: tuple[np.ndarray, np.ndarray] | None = None,
                  atol: float = SAME_POSTURE) -> tuple[np.ndarray, np.ndarray]:
    """The effector's point at the start posture of each stored sample, where the samples say it.

    Sample i's start point is known when its posture is the rest posture (then it is the rest
    point), or when it starts where sample i - 1 ended (α_i = α_{i-1} + Δα_{i-1}: consecutive
    micro-actions) and sample i - 1's start point is known (then it is that point + Δy_{i-1}).
    Otherwise (the arm moved without storing a sample: a reach, a return to rest in steps, a
    resume) it is unknown. Our choice, not the paper's; exact, as each Δy is the difference of two
    measurements of the effector: a chain's sum is the last measurement, up to float rounding.

    Parameters
    ----------
    alpha, delta_alpha : ndarray, shape (N, n)
        The samples' postures and joint displacements, in the order they were stored.
    delta_y : ndarray, shape (N, m)
        Their effector displacements.
    rest : ndarray, shape (n,)
        The rest posture.
    rest_point : ndarray, shape (m,)
        The effector's point at rest (zeros: points relative to it).
    previous : (ndarray (n,), ndarray (m,)), optional
        The end posture and end point (NaN: unknown) of the sample stored just before these (None:
        these are the first).
    atol : float
        Two postures are one when no joint differs by more (rad).

    Returns
    -------
    known : ndarray of bool, shape (N,)
        Whether sample i's start point is known.
    start : ndarray, shape (N, m)
        Sample i's start point (NaN where unknown); its end point is ``start + delta_y``.
    """
    alpha, delta_alpha, delta_y = (np.asarray(x, dtype=float) for x in (alpha, delta_alpha, delta_y))
    count, m = delta_y.shape
    if not count:
        return np.zeros(0, dtype=bool), np.zeros((0, m))
    at_rest = np.all(np.abs(alpha - rest) <= atol, axis=1)
    chained = np.zeros(count, dtype=bool)
    chained[1:] = np.all(np.abs(alpha[1:] - (alpha[:-1] + delta_alpha[:-1])) <= atol, axis=1)
    if previous is not None:
        chained[0] = bool(np.all(np.abs(alpha[0] - previous[0]) <= atol))
    anchor = at_rest | ~chained
    anchor[0] = True                       # a chain's first row: its start point comes from outside it
    first = np.flatnonzero(anchor)
    head = np.full((len(first), m), np.nan)
    head[at_rest[first]] = rest_point
    if previous is not None and chained[0] and not at_rest[0]:
        head[0] = previous[1]
    before = np.cumsum(delta_y, axis=0) - delta_y   # Σ Δy of the rows before each row
    chain = np.cumsum(anchor) - 1
    start = head[chain] + (before - before[first][chain])
    return np.isfinite(start).all(axis=1), start


class KnownPoints:
    """The stored end postures whose effector point is known (:func:`sample_points`), searchable
    by point (the module docstring). Follows one memory: :meth:`update` before each search."""

    def __init__(self):
        self._clear(None)

    def _clear(self, memory) -> None:
        self._memory = memory
        self._rows = 0                       # memory rows read so far
        self._last: tuple[np.ndarray, np.ndarray] | None = None  # the last row's end (posture, offset)
        self._postures: list[np.ndarray] = []
        self._offsets: list[np.ndarray] = []
        self._alpha = self._offset = None    # the lists stacked, when the tree was built
        self._tree = None
        self._size = 0                       # points in the tree

    @property
    def known(self) -> int:
        """Stored samples whose end point is known."""
        return sum(len(p) for p in self._postures)

    @property
    def rows(self) -> int:
        """Stored samples read (known or not)."""
        return self._rows

    def update(self, memory, rest: np.ndarray) -> "KnownPoints":
        """Read the rows of ``memory`` not read yet (all of them after the memory was replaced or
        shrank). Returns self.

        Parameters
        ----------
        memory : SampleMemory
            The robot's samples (the learner's memory).
        rest : ndarray, shape (n,)
            The rest posture.
        """
        if memory is not self._memory or len(memory) < self._rows:
            self._clear(memory)
        if len(memory) == self._rows:
            return self
        sl = slice(self._rows, len(memory))
        alpha, dalpha, dy = memory.alpha[sl], memory.delta_alpha[sl], memory.delta_y[sl]
        known, start = sample_points(alpha, dalpha, dy, rest, np.zeros(dy.shape[1]), self._last)
        end_alpha, end = alpha + dalpha, start + dy
        self._postures.append(end_alpha[known])
        self._offsets.append(end[known])
        self._last = (end_alpha[-1], end[-1])
        self._rows = len(memory)
        if self.known - self._size >= max(MIN_UNTREED, self._size // REBUILD_SHARE):
            self._build_tree()
        return self

    def _build_tree(self) -> None:
        self._alpha, self._offset = np.concatenate(self._postures), np.concatenate(self._offsets)
        self._postures, self._offsets = [self._alpha], [self._offset]
        # lazy (heavy): scipy (only a compute_ik request builds the index; the learner node imports this)
        from scipy.spatial import cKDTree
        self._tree = cKDTree(self._offset)
        self._size = len(self._offset)

    def nearest(self, offset: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` known end postures whose points are nearest ``offset`` (a point relative to the
        rest point), nearest first (fewer when fewer are known).

        Parameters
        ----------
        offset : ndarray, shape (m,)
            The point searched, minus the rest point.
        k : int
            How many, >= 1.

        Returns
        -------
        alpha : ndarray, shape (k', n)
            The postures.
        offset : ndarray, shape (k', m)
            Their points, relative to the rest point.
        """
        alpha, points = [], []
        if self._size:
            _, idx = self._tree.query(offset, k=min(k, self._size))
            idx = np.atleast_1d(idx)
            alpha.append(self._alpha[idx])
            points.append(self._offset[idx])
        alpha += self._postures[1:] if self._size else self._postures
        points += self._offsets[1:] if self._size else self._offsets
        if not alpha:
            return np.zeros((0, 0)), np.zeros((0, len(offset)))
        alpha, points = np.concatenate(alpha), np.concatenate(points)
        order = np.argsort(np.linalg.norm(points - offset, axis=1), kind="stable")[:k]
        return alpha[order], points[order]
