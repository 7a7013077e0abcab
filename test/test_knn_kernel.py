"""The compiled approximate neighbour search (sagg_low_level/knn_kernel.c) against the numpy walk it
replaced, kept here as its reference: the same answers (indices and order) and the same
leaves-scanned count, bit for bit, on random memories of every shape the learner uses (1-15 dims,
small and large leaves and fan-outs, several box heights, exact duplicates of the rest posture and
of stored samples, grid-valued samples with distance ties), and None exactly when the walk scanned
fewer than k samples. Whole learning runs are bit-identical before/after (checked against b65b5de on
eleven set-ups: docs/notes/peer-quality.md, session 10)."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_low_level.memory import SampleMemory
from sagg_low_level.memory_distance import _sqdist_cols
from sagg_low_level.memory_search import _kth

_FMAX = np.finfo(np.float64).max


def reference_knn_approx(mem: SampleMemory, q: np.ndarray, k: int):
    """KnnSearch._knn_approx as numpy code (before the compiled search, ``self`` renamed ``mem``);
    returns (answer or None, leaves scanned)."""
    scanned0 = mem.leaves_scanned
    try:
        return _walk(mem, q, k), mem.leaves_scanned - scanned0
    finally:
        mem.leaves_scanned = scanned0


def _walk(mem: SampleMemory, q: np.ndarray, k: int):
    n_all, ns = mem._n, mem._ns
    nb = n_all - ns
    bd = _sqdist_cols(mem._buf_t[:, :nb], q) if nb else np.empty(0)
    # nodes farther than an upper bound of the k-th distance cannot contribute; with no bound
    # yet, the largest float still drops the empty (infinite) padding boxes
    bound = _kth(bd, k) if nb >= k else _FMAX
    sel = None  # kept node ids at the height above (= their children's group ids here)
    if mem._height >= 0:
        q4 = mem._q3[:, :, :, None]  # (3, n, 1, 1)
        q4[0, :, 0, 0] = q
        np.negative(q, out=q4[1, :, 0, 0])
        fan, leaf, n = mem._fan, mem._leaf, mem._sd
        for h in range(mem._height, -1, -1):
            # candidates: whole F-groups of slots (gathered as contiguous runs): the children
            # of the kept nodes and the root groups at this height
            roots = mem._root_groups[h]
            groups = roots if sel is None else np.concatenate((sel, roots)) if len(roots) else sel
            if not len(groups):
                sel = None
                continue
            boxes = mem._boxes[h]
            g = boxes.reshape(3, n, boxes.shape[2] // fan, fan).take(groups, axis=2)
            g -= q4
            lb = np.maximum.reduce(g, axis=0)  # = g.max(axis=0), no Python wrapper
            lb *= lb
            lb = np.add.reduce(lb, axis=0).ravel()  # squared box distances, canonical order
            keep = (lb <= bound).nonzero()[0]
            cap = mem._widths[h]
            if len(keep) > cap:
                keep = keep[lb[keep].argsort(kind="stable")[:cap]]
            sel = groups[keep // fan] * fan + keep % fan
        if mem._dupmap:
            dups = mem._dupmap.get((q + 0.0).tobytes())
            if dups:
                extra = np.array([mem._ginfo[g][1] for g in dups], dtype=np.int64)
                sel = extra if sel is None else np.union1d(sel, extra)
    if sel is None or not len(sel):
        cd, ci = bd, np.arange(ns, n_all)
    else:
        mem.leaves_scanned += len(sel)
        p = mem._pts.reshape(n, mem._pts.shape[1] // leaf, leaf).take(sel, axis=1)
        p -= q[:, None, None]
        p *= p
        # canonical order, as every other path; empty leaf slots are NaN and never selected
        cd = np.concatenate((bd, np.add.reduce(p, axis=0).ravel()))
        ci = np.concatenate((np.arange(ns, n_all), mem._pidx.reshape(-1, leaf).take(sel, axis=0).ravel()))
    if len(cd) < k:
        return None
    # a group code stands for >= 1 sample at its distance, so this k-th value bounds the answer
    kth = _kth(cd, k)
    if not kth <= np.inf:  # NaN: fewer than k samples scanned
        return None
    keep = cd <= kth
    cd, ci = cd[keep], ci[keep]
    if mem._ngroups and ci.min() < -1:
        cd, ci = mem._expand_groups(cd, ci, k)
        kth = _kth(cd, k)
        keep = cd <= kth
        cd, ci = cd[keep], ci[keep]
    return ci[np.lexsort((ci, cd))[:k]]


def _memory(rng, n, checks, leaf, fan, buffer_size, beam, size, grid):
    mem = SampleMemory(n, n, 2, checks=checks, leaf_size=leaf, fanout=fan, buffer_size=buffer_size,
                       beam_ratio=beam)
    rest = rng.uniform(-1, 1, n)
    for _ in range(size):
        if rng.random() < 0.1:
            a = rest  # the rest posture: exact duplicates, stored as groups in the blocks
        elif grid:
            a = np.round(rng.uniform(-1, 1, n) * 4) / 4  # few distinct values: distance ties
        else:
            a = rest + rng.normal(0, 0.3, n)
        mem.add(a, np.zeros(n), np.zeros(2))
    return mem, rest


def _queries(rng, mem, rest, count):
    n = mem.state_dim
    for _ in range(count):
        u = rng.random()
        if u < 0.2:
            yield rest.copy()
        elif u < 0.4:
            yield mem.alpha[int(rng.integers(len(mem)))].copy()  # a stored sample (maybe a group's)
        else:
            yield rest + rng.normal(0, 0.3, n)


@pytest.mark.parametrize("seed", range(6))
def test_compiled_walk_gives_the_numpy_walks_answers(seed):
    rng = np.random.default_rng(seed)
    heights = set()
    compared = nones = 0
    for _ in range(6):
        n = int(rng.choice([1, 2, 3, 7, 15]))
        mem, rest = _memory(rng, n, checks=int(rng.choice([1, 2, 4, 32])), leaf=int(rng.choice([2, 4, 32])),
                            fan=int(rng.choice([2, 4, 16])), buffer_size=int(rng.choice([64, 256])),
                            beam=float(rng.choice([0.5, 1.0])), size=int(rng.integers(10, 3000)),
                            grid=bool(rng.random() < 0.3))
        heights.add(mem._height)
        for q in _queries(rng, mem, rest, 60):
            k = int(rng.integers(1, min(len(mem), 70)))
            want, scanned = reference_knn_approx(mem, q, k)
            before = mem.leaves_scanned
            got = mem._knn_approx(q, k)
            assert mem.leaves_scanned - before == scanned
            if want is None:
                assert got is None
                nones += 1
            else:
                assert got is not None and got.dtype == np.int64
                assert np.array_equal(got, want), (n, k, got, want)
            compared += 1
    assert compared == 360 and len(heights) >= 2


def test_compiled_walk_answers_none_when_fewer_than_k_samples_were_scanned():
    # one sample per leaf slot scanned at most: checks=1 leaf of 2 with a tiny buffer, k above that
    rng = np.random.default_rng(3)
    mem = SampleMemory(2, 2, 2, checks=1, leaf_size=2, fanout=2, buffer_size=2)
    for a in rng.uniform(-1, 1, (9, 2)):
        mem.add(a, np.zeros(2), np.zeros(2))
    q = np.array([0.1, 0.2])
    want, scanned = reference_knn_approx(mem, q, 6)
    assert want is None
    before = mem.leaves_scanned
    assert mem._knn_approx(q, 6) is None and mem.leaves_scanned - before == scanned
    # the memory's public search then answers exactly (the same as an exact memory)
    exact = SampleMemory(2, 2, 2)
    for a in mem.alpha:
        exact.add(a, np.zeros(2), np.zeros(2))
    assert np.array_equal(mem.neighbours(q, 6), exact.neighbours(q, 6))
