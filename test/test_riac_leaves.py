"""ACTUATOR-RIAC's leaf table (sagg_low_level.riac_leaves): the same compatible leaves, order and
interests as the tree walk it replaced, and the same seeded runs bit for bit."""
import numpy as np

from sagg_lab.riac_speed import bench_riac, walk_compatible
from sagg_common.region_arrays import restore_tree, tree_arrays
from sagg_common.regions import RegionTree
from sagg_low_level.riac_leaves import RiacLeaves

N = 3  # context dims; the tree is over (context, action) = 2N dims


def _tree(seed: int) -> RegionTree:
    return RegionTree(np.r_[np.full(N, -1.0), np.full(N, -0.1)], np.r_[np.full(N, 1.0), np.full(N, 0.1)],
                      g_max=4, zeta=6, n_candidates=5, rng=np.random.default_rng(seed))


def _queries(tree: RegionTree, rng) -> list[np.ndarray]:
    """Random contexts plus the hard ones: the root box's corners and split values hit exactly."""
    qs = [rng.uniform(-1, 1, N) for _ in range(6)] + [np.full(N, 1.0), np.full(N, -1.0)]
    for s in tree.splits[-5:]:
        q = rng.uniform(-1, 1, N)
        if s["dim"] < N:
            q[s["dim"]] = s["value"]
        qs.append(q)
    return qs


def _check_same(table: RiacLeaves, tree: RegionTree, rng) -> int:
    leaves = tree.leaves()
    checked = 0
    for q in _queries(tree, rng):
        rows, it = table.compatible(q)
        walked = walk_compatible(tree, q, N)
        assert [leaves[int(i)] for i in rows] == walked  # same regions, same order (identity)
        assert np.array([r.interest for r in walked]).tobytes() == it.tobytes()
        checked += len(walked)
    return checked


def test_compatible_leaves_equal_the_tree_walk_after_every_point():
    rng = np.random.default_rng(1)
    tree = _tree(2)
    table = RiacLeaves(tree, N)
    seen = 0
    for t in range(600):
        # points on a coarse grid too, so split values and points coincide with bounds
        p = rng.uniform(-1, 1, 2 * N) * np.r_[np.ones(N), np.full(N, 0.1)]
        if t % 3 == 0:
            p[:N] = np.round(p[:N], 1)
        table.add(p, float(rng.normal()))
        seen += _check_same(table, tree, rng)
    assert len(tree.splits) > 100 and len(table) == len(tree.leaves())
    assert seen > 5000
    # both kinds of split occurred (context splits narrow the set, action splits do not)
    dims = {s["dim"] < N for s in tree.splits}
    assert dims == {True, False}


def test_table_of_a_restored_tree_equals_the_incremental_one():
    rng = np.random.default_rng(3)
    tree = _tree(4)
    table = RiacLeaves(tree, N)
    for _ in range(300):
        table.add(rng.uniform(-1, 1, 2 * N) * np.r_[np.ones(N), np.full(N, 0.1)], float(rng.normal()))
    copy = _tree(4)
    restore_tree(copy, tree_arrays(tree))
    rebuilt = RiacLeaves(copy, N)
    for q in _queries(tree, rng):
        r1, i1 = table.compatible(q)
        r2, i2 = rebuilt.compatible(q)
        assert r1.tolist() == r2.tolist() and i1.tobytes() == i2.tobytes()
    # and it keeps in step with further points
    for _ in range(100):
        p = rng.uniform(-1, 1, 2 * N) * np.r_[np.ones(N), np.full(N, 0.1)]
        v = float(rng.normal())
        table.add(p, v)
        rebuilt.add(p, v)
    _check_same(rebuilt, copy, rng)


def test_points_outside_the_root_box_change_nothing():
    tree = _tree(5)
    table = RiacLeaves(tree, N)
    assert table.add(np.full(2 * N, 5.0), 1.0) is None
    assert tree.n_added == 0 and len(table) == 1


def test_actuator_riac_run_is_bit_identical_with_the_walk():
    """A seeded ACTUATOR-RIAC run (7-DOF kinematic arm, small regions so the tree has hundreds of
    leaves) gives the same memory, RIAC splits and goal-tree splits with the table and the walk."""
    lines = []
    res = bench_riac("config/arm15.yaml", 2000, 1000,
                     overrides={"arm.dof": 7, "riac.g_max": 8, "seed": 3}, out=lines.append)
    assert res["identical"] == {"memory_digest": True, "riac_splits": True, "goal_tree_splits": True}
    assert res["rows"][-1]["leaves"] > 150
    assert "bit-identical: memory digest same" in lines[-1]


def test_the_compiled_box_test_refuses_mismatched_arrays():
    import pytest
    from sagg_low_level.compiled import knn_kernel

    lo, up = np.zeros((2, 3)), np.ones((2, 3))
    out = np.empty(3, dtype=np.int64)
    assert knn_kernel.boxes_holding(np.array([0.5, 0.5]), lo, up, out) == 3 and out.tolist() == [2, 1, 0]
    assert knn_kernel.boxes_holding(np.array([0.5, 1.0]), lo, up, out) == 0  # upper bounds are open
    for x, o in ((np.zeros(3), out), (np.zeros(2), np.empty(2, dtype=np.int64))):
        with pytest.raises(ValueError):
            knn_kernel.boxes_holding(x, lo, up, o)
