"""The cached neighbour sets M_i of the fixed-context reaching phase (sagg_low_level.neighbour_sets)
and the one-call least-spread selection: speed only, so both must equal the plain computation bit
for bit."""
from __future__ import annotations

import numpy as np

from sagg_low_level.fixed_context import least_spread_set, set_spread
from sagg_low_level.memory import SampleMemory
from sagg_low_level.neighbour_sets import NeighbourSets


def _add(mem, rng, count, grid=False):
    for _ in range(count):
        # grid points make exact distance ties, which must be broken by index as the memory does
        a = np.round(rng.uniform(0, 1, 3) * 4) / 4 if grid else rng.uniform(0, 1, 3)
        mem.add(a, a, a[:2])


def test_cached_sets_equal_the_memory_search_as_samples_arrive():
    rng = np.random.default_rng(3)
    mem = SampleMemory(3, 3, 2)
    sets = NeighbourSets(mem, 9, max_entries=40)
    _add(mem, rng, 5)  # fewer samples than k at first
    asked = 0
    for step in range(120):
        _add(mem, rng, int(rng.integers(0, 25)), grid=step % 3 == 0)
        # mostly the same few samples (as goals of one region share neighbours), some new ones
        pool = len(mem) if step % 10 == 0 else min(len(mem), 30)
        for i in rng.integers(0, pool, 6):
            got = sets.get(int(i))
            want = mem.neighbours(mem.alpha[int(i)], 9)
            np.testing.assert_array_equal(got, want)
            asked += 1
    # the cache answered most queries, and the bound held (the oldest sets were dropped)
    assert sets.hits > asked // 2 and sets.searches > 40
    assert len(sets) == 40


def test_least_spread_set_in_one_call_equals_per_set_spreads():
    rng = np.random.default_rng(4)
    theta = rng.uniform(0, 1, (200, 7))
    for _ in range(50):
        sets = [rng.choice(200, 16, replace=False) for _ in range(10)]
        want = int(np.argmin([set_spread(theta[s]) for s in sets]))
        assert least_spread_set(sets, theta) == want
    # ties go to the first set, as argmin over the list did
    s = rng.choice(200, 16, replace=False)
    assert least_spread_set([s, s.copy(), s[::-1].copy()], theta) == 0


def test_cached_sets_stay_exact_with_ties_and_dropped_entries():
    """Grid points (exact distance ties, broken by index as the memory does), a small cache that
    keeps dropping its oldest sets and re-finding them, samples arriving one at a time and in
    bursts: every answer equals the memory's exact search."""
    rng = np.random.default_rng(11)
    mem = SampleMemory(3, 3, 2)
    sets = NeighbourSets(mem, 6, max_entries=7)
    _add(mem, rng, 3, grid=True)
    for step in range(300):
        _add(mem, rng, int(rng.integers(0, 3 if step % 5 else 40)), grid=step % 2 == 0)
        for i in rng.integers(0, len(mem), 3):
            np.testing.assert_array_equal(sets.get(int(i)), mem.neighbours(mem.alpha[int(i)], 6))
    assert len(sets) == 7 and sets.hits > 0 and sets.searches > 7
