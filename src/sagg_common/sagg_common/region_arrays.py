"""A region tree and its split history as arrays, and back (the checkpoints of the goal generator
and of the ACTUATOR-RIAC learner store their trees this way). ROS-free."""
from __future__ import annotations

import numpy as np

from sagg_common.regions import Region


def tree_arrays(tree) -> dict[str, np.ndarray]:
    """A RegionTree as arrays (every region, depth first from the root)."""
    regions = []
    stack = [tree.root]
    while stack:
        r = stack.pop()
        regions.append(r)
        if r.children is not None:
            stack.extend(reversed(r.children))
    d = tree.dim
    counts = np.array([r.count if r.children is None else 0 for r in regions], np.int64)
    pts = [r.filled_points for r in regions if r.children is None and r.count]
    vals = [r.filled_values for r in regions if r.children is None and r.count]
    return {
        "region_id": np.array([r.id for r in regions], np.int64),
        "region_lower": np.array([r.lower for r in regions], float).reshape(-1, d),
        "region_upper": np.array([r.upper for r in regions], float).reshape(-1, d),
        "region_split_dim": np.array([r.split_dim for r in regions], np.int64),
        "region_split_value": np.array([r.split_value for r in regions], float),
        "region_children": np.array([[c.id for c in r.children] if r.children else [-1, -1] for r in regions],
                                    np.int64).reshape(-1, 2),
        "region_count": counts,
        "points": np.concatenate(pts) if pts else np.empty((0, d)),
        "values": np.concatenate(vals) if vals else np.empty(0),
        "leaf_order": np.array([r.id for r in tree.leaves()], np.int64),
        "tree_ints": np.array([tree._next_id, tree.n_added], np.int64),
    }


_SPLIT_INTS = ("stamp", "region", "dim", "left", "right")
_SPLIT_BOXES = ("left_lower", "left_upper", "right_lower", "right_upper")


def splits_arrays(splits: list[dict], d: int) -> dict[str, np.ndarray]:
    """The split history as arrays (JSON would grow by ~1 kB per split and be rewritten at every
    checkpoint). A missing stamp (None) is stored as -1 with ``split_has_stamp`` false."""
    k = len(splits)
    out = {f"split_{n}": np.array([-1 if s[n] is None else s[n] for s in splits], np.int64).reshape(k)
           for n in _SPLIT_INTS}
    out["split_has_stamp"] = np.array([s["stamp"] is not None for s in splits], bool).reshape(k)
    out["split_value"] = np.array([s["value"] for s in splits], float).reshape(k)
    out["split_quality"] = np.array([s["quality"] for s in splits], float).reshape(k)
    for n in _SPLIT_BOXES:
        out[f"split_{n}"] = np.array([s[n] for s in splits], float).reshape(k, d)
    return out


def splits_from_arrays(z) -> list[dict]:
    """Inverse of :func:`splits_arrays` (the dicts of ``RegionTree.splits``, same keys and order)."""
    out = []
    for i in range(len(z["split_value"])):
        s = {n: int(z[f"split_{n}"][i]) for n in _SPLIT_INTS}
        if not z["split_has_stamp"][i]:
            s["stamp"] = None
        s["value"] = float(z["split_value"][i])
        s["quality"] = float(z["split_quality"][i])
        for n in _SPLIT_BOXES:
            s[n] = z[f"split_{n}"][i].tolist()
        out.append({k: s[k] for k in ("stamp", "region", "dim", "value", "quality", "left", "right",
                                      *_SPLIT_BOXES)})
    return out


def restore_tree(tree, z) -> None:
    """Rebuild ``tree`` (a fresh RegionTree with the same bounds and parameters) from
    :func:`tree_arrays` output."""
    ids = z["region_id"]
    by_id: dict[int, Region] = {}
    off = 0
    for i, rid in enumerate(ids.tolist()):
        n = int(z["region_count"][i])
        cap = max(8, 2 * n)
        r = Region(rid, z["region_lower"][i].copy(), z["region_upper"][i].copy(),
                   np.empty((cap, tree.dim)), np.empty(cap), zeta=tree.zeta)
        if int(z["region_children"][i][0]) < 0:
            r.points[:n] = z["points"][off:off + n]
            r.values[:n] = z["values"][off:off + n]
            r.count = n
            r._dirty = True  # interest recomputed from the values (a pure function of them)
            off += n
        else:
            r.points, r.values = np.empty((0, tree.dim)), np.empty(0)
            r.split_dim, r.split_value = int(z["region_split_dim"][i]), float(z["region_split_value"][i])
        by_id[rid] = r
    for i, rid in enumerate(ids.tolist()):
        left, right = (int(c) for c in z["region_children"][i])
        if left >= 0:
            by_id[rid].children = (by_id[left], by_id[right])
    tree.root = by_id[int(ids[0])]
    tree._leaves = [by_id[int(i)] for i in z["leaf_order"]]
    tree._next_id, tree.n_added = (int(v) for v in z["tree_ints"])
