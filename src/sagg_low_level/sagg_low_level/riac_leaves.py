"""ACTUATOR-RIAC's leaf table: the leaves of a :class:`~sagg_common.regions.RegionTree` over
(context, action) as numpy arrays (context bounds, interests), kept in step with the tree point by
point, so that choosing a region compatible with the current context costs one compiled call (the
box test, knn_kernel.boxes_holding) instead of a Python walk over the tree and one ``Region.interest``
read per compatible leaf.
ROS-free.

Speed only, never results: :meth:`RiacLeaves.compatible` returns exactly the leaves (and their
interests, bit for bit) that a walk down the region tree finds, in the walk's order
(test/test_riac_leaves.py): the walk descends by the context coordinate at context splits
(``x < value`` left, else right) and takes both children at action splits, depth first from the
right child, i.e. the compatible leaves in reverse left-to-right order. ``RegionTree`` keeps its
leaf list in left-to-right order (a split replaces a leaf by its left and right child in place), so
the compatible leaves are those whose context box holds x (lower ≤ x < upper, the root box's upper
bound inclusive: no split value reaches it), reversed.
"""
from __future__ import annotations

import numpy as np

from sagg_common.regions import Region, RegionTree

from .compiled import knn_kernel


class RiacLeaves:
    """Leaf bounds (first ``context_dims`` coordinates) and interests of ``tree`` as arrays.

    Every point must reach the tree through :meth:`add` (or the table is rebuilt with
    :meth:`rebuild`): a leaf's interest is re-read after each point it receives, a split replaces
    the parent's row by its two children's."""

    def __init__(self, tree: RegionTree, context_dims: int):
        if not 0 <= context_dims <= tree.dim:
            raise ValueError(f"context_dims: got {context_dims}; allowed: 0..{tree.dim}")
        self.tree = tree
        self.n = context_dims
        self.rebuild()

    def rebuild(self) -> None:
        """Build the arrays from the tree's leaves as they are (e.g. after a restore)."""
        leaves = self.tree.leaves()
        # (context_dims, leaves): one contiguous row per coordinate, so a test is n vector compares
        self._lower = np.array([r.lower[:self.n] for r in leaves]).reshape(len(leaves), self.n).T.copy()
        self._upper = np.array([self._open_upper(r) for r in leaves]).reshape(len(leaves), self.n).T.copy()
        self._interest = np.array([r.interest for r in leaves], dtype=float)
        # row of each leaf by region id (ids are small consecutive integers); leaf ids in row order
        self._ids = np.array([r.id for r in leaves], dtype=np.int64)
        self._row = np.full(2 * max(len(leaves), 8) + int(self._ids.max()) + 1, -1, dtype=np.int64)
        self._row[self._ids] = np.arange(len(leaves))
        self._splits = len(self.tree.splits)

    def _open_upper(self, r: Region) -> np.ndarray:
        """Context upper bounds, +inf where the bound is the root box's (closed there)."""
        up = r.upper[:self.n]
        return np.where(up >= self.tree.upper[:self.n], np.inf, up)

    def add(self, point, value: float) -> Region | None:
        """``tree.add(point, value)`` and the table updated (the changed leaf's interest, or the
        split leaf's row replaced by its children's)."""
        leaf = self.tree.add(point, value)
        if leaf is None:
            return None
        if len(self.tree.splits) == self._splits:
            self._interest[self._row[leaf.id]] = leaf.interest
            return leaf
        self._splits = len(self.tree.splits)
        left, right = leaf.children
        i = int(self._row[leaf.id])
        self._row[leaf.id] = -1
        n = self.n
        self._lower = np.concatenate((self._lower[:, :i], np.stack((left.lower[:n], right.lower[:n]), axis=1),
                                      self._lower[:, i + 1:]), axis=1)
        self._upper = np.concatenate((self._upper[:, :i],
                                      np.stack((self._open_upper(left), self._open_upper(right)), axis=1),
                                      self._upper[:, i + 1:]), axis=1)
        self._interest = np.concatenate((self._interest[:i], [left.interest, right.interest],
                                         self._interest[i + 1:]))
        self._ids = np.concatenate((self._ids[:i], [left.id, right.id], self._ids[i + 1:]))
        if right.id >= len(self._row):
            self._row = np.concatenate((self._row, np.full(len(self._row) + 2, -1, dtype=np.int64)))
        self._row[self._ids[i + 2:]] += 1
        self._row[left.id], self._row[right.id] = i, i + 1
        return leaf

    def __len__(self) -> int:
        return len(self._interest)

    def interests(self) -> np.ndarray:
        """The leaves' interests in ``tree.leaves()`` order (a copy)."""
        return self._interest.copy()

    def compatible(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows (into ``tree.leaves()``) of the leaves whose context box holds ``x`` (which must lie in
        the root box's context part), in the tree walk's order (see the module docstring), and
        their interests."""
        # lower <= x < upper in every context coordinate, the rows in decreasing order: one compiled
        # call (knn_kernel.boxes_holding, cheaper than a numpy test of every leaf:
        # docs/notes/compiled-loop.md); test/test_riac_leaves.py checks it against the tree walk
        out = np.empty(len(self._interest), dtype=np.int64)
        m = knn_kernel.boxes_holding(np.ascontiguousarray(x, dtype=float), self._lower, self._upper, out)
        rows = out[:m]
        return rows, self._interest[rows]
