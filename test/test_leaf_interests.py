"""RegionTree.interests() (kept up to date by sagg_common.leaf_interests) equals a fresh read of
every leaf's interest, byte for byte, through points, splits, hand-set interests and restores."""
import numpy as np

from sagg_common.region_arrays import restore_tree, tree_arrays
from sagg_common.regions import RegionTree


def _tree(seed: int, dim: int = 2) -> RegionTree:
    return RegionTree(np.zeros(dim), np.ones(dim), g_max=6, zeta=8, n_candidates=5,
                      rng=np.random.default_rng(seed))


def _fresh(tree: RegionTree) -> np.ndarray:
    return np.array([r.interest for r in tree.leaves()])


def test_interests_equal_a_fresh_read_after_every_change():
    rng = np.random.default_rng(0)
    tree = _tree(1)
    checked = 0
    for t in range(1500):
        tree.add(rng.uniform(0, 1, 2), float(rng.normal()))
        if t % 3 == 0 or t < 50:  # reads between a few points, and after each one early on
            assert tree.interests().tobytes() == _fresh(tree).tobytes()
            checked += 1
        if t % 97 == 0:  # an interest set by hand is seen at the next read
            leaf = tree.leaves()[int(rng.integers(len(tree.leaves())))]
            leaf.interest = float(rng.uniform(0, 5))
            assert tree.interests().tobytes() == _fresh(tree).tobytes()
    assert len(tree.splits) > 150 and checked > 500
    got = tree.interests()
    got[:] = -1.0  # a copy: changing it changes nothing
    assert tree.interests().tobytes() == _fresh(tree).tobytes()


def test_interests_of_a_restored_tree_and_after_restoring_in_place():
    rng = np.random.default_rng(2)
    tree = _tree(3, dim=3)
    for _ in range(400):
        tree.add(rng.uniform(0, 1, 3), float(rng.normal()))
    tree.interests()
    copy = _tree(3, dim=3)
    copy.interests()  # read once before the restore replaces its leaves
    restore_tree(copy, tree_arrays(tree))
    assert copy.interests().tobytes() == _fresh(copy).tobytes() == tree.interests().tobytes()
    again = _tree(3, dim=3)
    again.interests()
    restore_tree(again, tree_arrays(tree))
    for _ in range(60):  # points and splits on the restored leaves before the next read
        again.add(rng.uniform(0, 1, 3), float(rng.normal()))
    assert len(again.splits) > 0
    assert again.interests().tobytes() == _fresh(again).tobytes()
    for _ in range(200):  # and keeps in step with further points (its own splits: a fresh split stream)
        copy.add(rng.uniform(0, 1, 3), float(rng.normal()))
        assert copy.interests().tobytes() == _fresh(copy).tobytes()
    assert len(copy.splits) > 10  # splits after the restore (the history is restored separately)
