"""StoredKnn (sagg_low_level.stored_knn): the exact k nearest of stored samples, kept from one query to
the next and brought up to date with the samples stored since, must be TreeKnn's answer (the memory's
exact one) bit for bit: indices and order, ties by index, whatever was kept."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_low_level.compiled import knn_kernel
from sagg_low_level.memory import SampleMemory, SampleTable
from sagg_low_level.stored_knn import StoredKnn
from sagg_low_level.tree_knn import TreeKnn


def _sample(rng, mem, dim):
    """Clustered points, some duplicated, some on a coarse grid (exact distance ties)."""
    kind = rng.integers(0, 4)
    if kind == 0 and len(mem):
        return mem.alpha[int(rng.integers(len(mem)))]
    if kind == 1:
        return np.round(rng.uniform(0, 1, dim) * 3) / 3
    return rng.uniform(0, 1, dim) ** 3


@pytest.mark.parametrize("dim,limit", [(1, 4096), (2, 4096), (7, 4096), (7, 5), (24, 4096)])
def test_equals_the_exact_search_as_samples_arrive(dim, limit):
    rng = np.random.default_rng(dim + limit)
    mem = SampleMemory(dim, 1, 1)
    knn = TreeKnn(mem, min_recent=8, rebuild_share=0.25, leafsize=4)
    stored = StoredKnn(knn, refresh_limit=limit)
    for step in range(80):
        for _ in range(int(rng.integers(0, 25))):
            mem.add(_sample(rng, mem, dim), [0.0], [0.0])
        if not len(mem):
            continue
        # mostly rows asked before (kept answers merged with the new samples), some new, a repeat
        rows = rng.integers(0, min(len(mem), 40 + step), 6)
        rows = np.append(rows, rows[0])
        k = 16
        np.testing.assert_array_equal(stored.query(rows, k), knn.query(mem.alpha[rows], k))
    assert stored.kept > 0 and stored.asked > 0
    if limit == 5:  # the limit sends rows with many samples stored since to the index again
        assert stored.asked > stored._slots


def test_the_kept_answers_hold_while_the_memory_is_smaller_than_k():
    rng = np.random.default_rng(3)
    table = SampleTable(3, 1, 1)
    knn = TreeKnn(table, min_recent=2)
    stored = StoredKnn(knn)
    for _ in range(30):
        table.add(rng.uniform(0, 1, 3), [0.0], [0.0])
        rows = np.arange(len(table))
        np.testing.assert_array_equal(stored.query(rows, 20), knn.query(table.alpha[rows], 20))
    assert stored.kept > 0


def test_another_k_forgets_what_was_kept():
    rng = np.random.default_rng(5)
    mem = SampleMemory(4, 1, 1)
    for _ in range(200):
        mem.add(rng.uniform(0, 1, 4), [0.0], [0.0])
    knn = TreeKnn(mem)
    stored = StoredKnn(knn)
    rows = np.array([3, 7, 150])
    for k in (10, 4, 10, 10):
        np.testing.assert_array_equal(stored.query(rows, k), knn.query(mem.alpha[rows], k))
    assert stored.kept == 3 and stored.asked == 9


def test_bad_rows_and_arrays_are_refused():
    mem = SampleMemory(2, 1, 1)
    for i in range(5):
        mem.add([i, 0.0], [0.0], [0.0])
    stored = StoredKnn(TreeKnn(mem))
    for rows in ([5], [-1]):
        with pytest.raises(ValueError):
            stored.query(np.array(rows), 2)
    out, miss = np.empty((1, 2), dtype=np.int64), np.empty(1, dtype=np.int64)
    slot_of = np.full(5, -1, dtype=np.int64)
    n0 = cnt = np.zeros(1, dtype=np.int64)
    with pytest.raises(ValueError):  # k wider than the kept answers
        knn_kernel.stored_refresh(mem.alpha, np.array([0]), 2, 10, slot_of, n0, cnt,
                                  np.zeros((1, 1), dtype=np.int64), np.zeros((1, 1)), out, miss)
    with pytest.raises(IndexError):  # a row beyond the memory
        knn_kernel.stored_refresh(mem.alpha, np.array([9]), 2, 10, slot_of, n0, cnt,
                                  np.zeros((1, 2), dtype=np.int64), np.zeros((1, 2)), out, miss)
