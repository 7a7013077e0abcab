"""The goal generator's split history rebuilt from /sagg/regions snapshots."""
from __future__ import annotations

import numpy as np


class SplitTracker:
    """Rebuilds the goal generator's split history (``RegionTree.splits`` format: region, dim, value,
    left, right, stamp) from successive /sagg/regions snapshots.

    A snapshot is published on every split, but a reliable depth-1 writer may coalesce several; the
    leaves that replaced a region are then split back into a tree by guillotine cuts (ids of
    never-seen intermediate regions are negative). The leaves at every observed time are exact."""

    def __init__(self, lower, upper):
        self.leaves: dict[int, tuple[np.ndarray, np.ndarray]] = {0: (np.asarray(lower, float),
                                                                     np.asarray(upper, float))}
        self.splits: list[dict] = []
        self._synthetic = -1
        self.inconsistent = 0

    def update(self, regions: list[tuple[int, np.ndarray, np.ndarray]], stamp: int) -> None:
        new = {rid: (np.asarray(lo, float), np.asarray(hi, float)) for rid, lo, hi in regions}
        removed = [r for r in self.leaves if r not in new]
        added = [r for r in new if r not in self.leaves]
        for rid in removed:
            lo, hi = self.leaves[rid]
            kids = [a for a in added if np.all(new[a][0] >= lo) and np.all(new[a][1] <= hi)]
            self._decompose(rid, lo, hi, kids, new, stamp)
        self.leaves = new

    def _decompose(self, rid, lo, hi, kids, boxes, stamp) -> None:
        if len(kids) < 2:
            self.inconsistent += 1
            return
        for d in range(len(lo)):
            for v in sorted({float(boxes[k][0][d]) for k in kids if boxes[k][0][d] > lo[d]}):
                left = [k for k in kids if boxes[k][1][d] <= v]
                right = [k for k in kids if boxes[k][0][d] >= v]
                if left and right and len(left) + len(right) == len(kids):
                    ids = []
                    for side in (left, right):
                        if len(side) == 1:
                            ids.append(side[0])
                        else:
                            ids.append(self._synthetic)
                            self._synthetic -= 1
                    self.splits.append({"stamp": int(stamp), "region": int(rid), "dim": d, "value": v,
                                        "left": int(ids[0]), "right": int(ids[1])})
                    llo, lhi = lo, hi.copy()
                    lhi[d] = v
                    rlo, rhi = lo.copy(), hi
                    rlo[d] = v
                    if len(left) > 1:
                        self._decompose(ids[0], llo, lhi, left, boxes, stamp)
                    if len(right) > 1:
                        self._decompose(ids[1], rlo, rhi, right, boxes, stamp)
                    return
        self.inconsistent += 1
