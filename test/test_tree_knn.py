"""TreeKnn (sagg_low_level.tree_knn): the exact k nearest of a growing memory, many queries per call,
must be the memory's own exact answer bit for bit (indices and order, ties by index)."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_low_level.memory import SampleMemory, SampleTable
from sagg_low_level.tree_knn import TreeKnn, split_levels


def _want(mem, qs, k):
    return np.array([mem.neighbours(q, k) for q in qs]).reshape(len(qs), -1)


@pytest.mark.parametrize("dim", [1, 2, 3, 7, 24])
def test_equals_the_memory_search_as_samples_arrive(dim):
    rng = np.random.default_rng(dim)
    mem = SampleMemory(dim, 1, 1)
    knn = TreeKnn(mem, min_recent=8, rebuild_share=0.25, leafsize=4)
    assert knn.query(rng.uniform(0, 1, (3, dim)), 5).shape == (3, 0)  # empty memory
    for step in range(60):
        for _ in range(int(rng.integers(0, 30))):
            # clustered points, some duplicated, some on a coarse grid (exact distance ties)
            kind = rng.integers(0, 4)
            if kind == 0 and len(mem):
                a = mem.alpha[int(rng.integers(len(mem)))]
            elif kind == 1:
                a = np.round(rng.uniform(0, 1, dim) * 3) / 3
            else:
                a = rng.uniform(0, 1, dim) ** 3
            mem.add(a, [0.0], [0.0])
        for k in (1, 3, 16):
            qs = np.concatenate((rng.uniform(0, 1, (4, dim)),
                                 mem.alpha[rng.integers(0, len(mem), 4)] if len(mem) else np.empty((0, dim)),
                                 np.round(rng.uniform(0, 1, (2, dim)) * 3) / 3))
            np.testing.assert_array_equal(knn.query(qs, k), _want(mem, qs, k))
            for q in qs[:: len(qs) // 3]:  # one query per call
                np.testing.assert_array_equal(knn.query(q[None], k), _want(mem, q[None], k))
    assert knn._nt > 0 and knn.leaves_scanned > 0  # the tree was built and searched


def test_duplicates_beyond_the_candidates_are_ranked_by_index():
    mem = SampleMemory(2, 1, 1)
    for i in range(300):
        mem.add([0.5, 0.5] if i % 3 else [i / 300, 0.0], [0.0], [0.0])
    knn = TreeKnn(mem, min_recent=4)
    q = np.array([[0.5, 0.5], [0.5, 0.49], [0.1, 0.0]])
    np.testing.assert_array_equal(knn.query(q, 30), _want(mem, q, 30))


def test_over_an_index_free_table_with_the_same_digest():
    rng = np.random.default_rng(11)
    mem, table = SampleMemory(7, 7, 2), SampleTable(7, 7, 2, capacity=1)
    knn = TreeKnn(table, min_recent=16)
    for _ in range(40):
        for _ in range(int(rng.integers(1, 40))):
            a = rng.uniform(0, 1, 7) ** 2
            assert mem.add(a, a, a[:2]) == table.add(a, a, a[:2])
        qs = np.concatenate((rng.uniform(0, 1, (3, 7)), table.alpha[rng.integers(0, len(table), 3)]))
        np.testing.assert_array_equal(knn.query(qs, 16), _want(mem, qs, 16))
    assert table.digest() == mem.digest() and len(table) == len(mem)
    np.testing.assert_array_equal(table.delta_y, mem.delta_y)
    with pytest.raises(ValueError):
        table.add(np.full(7, np.nan), np.zeros(7), np.zeros(2))


def test_bad_queries_are_refused():
    mem = SampleMemory(2, 1, 1)
    mem.add([0.0, 0.0], [0.0], [0.0])
    knn = TreeKnn(mem)
    for q in ([[np.nan, 0.0]], [[0.0, np.inf]], [[0.0, 0.0, 0.0]]):
        with pytest.raises(ValueError):
            knn.query(np.array(q), 1)


@pytest.mark.parametrize("n, leafsize", [(1, 1), (2, 1), (3, 1), (5, 1), (17, 2), (300, 16), (1000, 3)])
def test_the_kd_tree_partitions_the_samples_into_exact_boxes(n, leafsize):
    """kd_build: every sample once in tree order, each node the two halves of its parent, each
    box the exact bounds of its members (an empty leaf, as with 3 or 5 samples in leaves of 1: no
    box), leaves of at most leafsize samples; the search over it is the exact one."""
    from sagg_low_level.compiled import knn_kernel
    rng = np.random.default_rng(n)
    x = np.round(rng.uniform(0, 1, (n, 3)) * 5) / 5  # a coarse grid: equal coordinates at splits
    depth = split_levels(n, leafsize)
    perm, pts_t, lo, hi, ns, ne = TreeKnn._arrays(n, 3, depth)
    knn_kernel.kd_build(x, depth, perm, pts_t, lo, hi, ns, ne)
    np.testing.assert_array_equal(np.sort(perm), np.arange(n))
    np.testing.assert_array_equal(pts_t, x[perm].T)
    nodes = len(ns)
    for i in range(nodes):
        members = x[perm[ns[i]:ne[i]]]
        if len(members):
            np.testing.assert_array_equal(lo[i], members.min(axis=0))
            np.testing.assert_array_equal(hi[i], members.max(axis=0))
        if i < nodes // 2:
            assert (ns[2 * i + 1], ne[2 * i + 1], ns[2 * i + 2], ne[2 * i + 2]) == (
                ns[i], ns[i] + (ne[i] - ns[i]) // 2, ns[i] + (ne[i] - ns[i]) // 2, ne[i])
        else:
            assert ne[i] - ns[i] <= leafsize
        if not len(members):  # an empty node: a box no query is near
            assert np.all(lo[i] == np.inf) and np.all(hi[i] == -np.inf)
    empty_leaves = sum(ne[i] == ns[i] for i in range(nodes // 2, nodes))
    assert empty_leaves == (n in (3, 5)) * ((1 << depth) - n)
    mem = SampleMemory(3, 1, 1)
    for a in x:
        mem.add(a, [0.0], [0.0])
    knn = TreeKnn(mem, min_recent=0, rebuild_share=0.0, leafsize=leafsize)
    qs = np.concatenate((x[: min(n, 4)], rng.uniform(0, 1, (4, 3))))
    for k in sorted({1, min(3, n), n}):
        np.testing.assert_array_equal(knn.query(qs, k), _want(mem, qs, k))


def test_kd_query_refuses_mismatched_arrays():
    from sagg_low_level.compiled import knn_kernel
    mem = SampleMemory(2, 1, 1)
    for i in range(200):
        mem.add([i / 200, (i % 7) / 7], [0.0], [0.0])
    knn = TreeKnn(mem, min_recent=8)
    knn.query(np.zeros((1, 2)), 3)  # builds the tree
    out = np.empty((1, 3), dtype=np.int64)
    perm, pts_t, lo, hi, ns, ne = knn._tree
    levels, recent = knn._split_levels, knn._recent_t
    with pytest.raises(ValueError):  # a query of another dimension
        knn_kernel.kd_query(np.zeros((1, 3)), 3, perm, pts_t, lo, hi, ns, ne, levels, recent, 0, out)
    with pytest.raises(ValueError):  # more neighbours than samples
        knn_kernel.kd_query(np.zeros((1, 2)), 500, perm, pts_t, lo, hi, ns, ne, levels, recent, 0,
                            np.empty((1, 500), dtype=np.int64))
    bad = ne.copy()
    bad[-1] = len(perm) + 5
    with pytest.raises(IndexError):  # a leaf beyond the samples
        knn_kernel.kd_query(np.zeros((1, 2)), 3, perm, pts_t, lo, hi, ns, bad, levels, recent, 0, out)
