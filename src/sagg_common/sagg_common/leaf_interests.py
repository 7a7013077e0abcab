"""The interests of a region tree's leaves as one array, kept up to date instead of re-read leaf by
leaf at every goal choice (the read path of :meth:`sagg_common.regions.RegionTree.interests`).

Speed only, never results: :meth:`LeafInterests.get` returns exactly ``np.array([r.interest for r in
tree.leaves()])``. Between two reads only the leaves that received a point (:meth:`touched`) can
have another interest, and a split replaces one leaf by its two children in place (:meth:`split`);
so a read refreshes only those leaves, where the list comprehension reads every leaf (a noticeable
share of a long SAGG-RIAC run, whose tree holds thousands of leaves). Anything else that changes
interests is noticed and answered by a full read: another leaf list (a restored tree), or an
interest set by hand (``Region.interest = v``, counted by ``Region.interest_sets``). ROS-free.
"""
from __future__ import annotations

import numpy as np


class LeafInterests:
    """The array of the leaves' interests of one tree, in ``tree.leaves()`` order."""

    def __init__(self, tree):
        self.tree = tree
        self._values: np.ndarray | None = None  # None: read every leaf next time

    def _build(self) -> np.ndarray:
        leaves = self.tree.leaves()
        self._values = np.array([r.interest for r in leaves])
        self._of = leaves  # the list it was read from (a restore assigns a new one)
        self._count = len(leaves)
        self._sets = type(self.tree.root).interest_sets
        # row of each leaf by region id (ids are small consecutive integers)
        self._ids = np.array([r.id for r in leaves], dtype=np.int64)
        self._row = np.full(2 * max(len(leaves), 8) + int(self._ids.max()) + 1, -1, dtype=np.int64)
        self._row[self._ids] = np.arange(len(leaves))
        self._touched: dict[int, object] = {}
        return self._values

    def _current(self) -> bool:
        """The array describes the tree's leaf list (not one it had before a restore)."""
        if self._values is not None and self._of is not self.tree.leaves():
            self._values = None
        return self._values is not None

    def touched(self, leaf) -> None:
        """``leaf`` received a point."""
        if self._current():
            self._touched[leaf.id] = leaf

    def split(self, parent, left, right) -> None:
        """``parent`` (a leaf) was replaced by ``left`` and ``right`` in the leaf list."""
        if not self._current():
            return
        i = int(self._row[parent.id])
        self._row[parent.id] = -1
        self._touched.pop(parent.id, None)
        self._values = np.concatenate((self._values[:i], [0.0, 0.0], self._values[i + 1:]))
        self._ids = np.concatenate((self._ids[:i], [left.id, right.id], self._ids[i + 1:]))
        if right.id >= len(self._row):
            self._row = np.concatenate((self._row, np.full(len(self._row) + 2, -1, dtype=np.int64)))
        self._row[self._ids[i + 2:]] += 1
        self._row[left.id], self._row[right.id] = i, i + 1
        self._count += 1
        self._touched[left.id] = left
        self._touched[right.id] = right

    def get(self) -> np.ndarray:
        """``np.array([r.interest for r in tree.leaves()])``, a fresh array."""
        leaves = self.tree.leaves()
        if (not self._current() or self._count != len(leaves)
                or self._sets != type(self.tree.root).interest_sets):
            return self._build().copy()
        if self._touched:
            for rid, r in self._touched.items():
                self._values[self._row[rid]] = r.interest
            self._touched.clear()
        return self._values.copy()
