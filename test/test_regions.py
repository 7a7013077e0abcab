"""The region tree's split choice (sagg_common.regions.choose_split, Sec. 2.4.4) evaluates its
candidates all at once (split_qualities); here against the per-candidate loop it replaced, kept as
the reference: the same candidates from the same stream, the same choice, the same quality to
1e-12 relative (the sums are taken in another order)."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_common.regions import SplitChoice, choose_split, split_qualities, split_quality


def per_candidate(points, values, n_candidates, zeta, rng):
    lo, hi = points.min(axis=0), points.max(axis=0)
    dims = np.flatnonzero(hi > lo)
    if dims.size == 0:
        return None
    best, best_key = None, None
    for _ in range(n_candidates):
        j = int(dims[rng.integers(dims.size)])
        v = float(rng.uniform(lo[j], hi[j]))
        if v <= lo[j]:
            v = float(np.nextafter(lo[j], hi[j]))
        mask = points[:, j] < v
        q = split_quality(values[mask], values[~mask], zeta)
        key = (q, int(mask.sum()) * int((~mask).sum()))
        if best_key is None or key > best_key:
            best_key, best = key, SplitChoice(j, v, q, int(mask.sum()), int((~mask).sum()))
    return best


@pytest.mark.parametrize("zeta", [2, 5, 20])
def test_choose_split_chooses_what_the_per_candidate_loop_chooses(zeta):
    r = np.random.default_rng(zeta)
    for i in range(400):
        n, d = int(r.integers(2, 70)), int(r.integers(1, 5))
        pts = r.uniform(size=(n, d))
        pts[r.random(n) < 0.2] = pts[0]                      # duplicated points (the rest posture)
        vals = -r.uniform(size=n) * (r.random(n) < 0.6)      # many maximal competences (0)
        want = per_candidate(pts, vals, 20, zeta, np.random.default_rng(i))
        got = choose_split(pts, vals, 20, zeta, np.random.default_rng(i))
        if want is None:
            assert got is None
            continue
        assert (got.dim, got.value, got.left_count, got.right_count) == \
               (want.dim, want.value, want.left_count, want.right_count)
        assert got.quality == pytest.approx(want.quality, rel=1e-12, abs=1e-15)


def test_split_qualities_of_hand_made_sides():
    values = np.array([-1.0, -1.0, 0.0, 0.0, -0.5, -0.5])
    left = np.array([[True], [True], [True], [True], [False], [False]])
    q, nl, nr = split_qualities(values, left, 4)
    # left: older (-1, -1), recent (0, 0): interest 2/4 = 0.5; right: h = 1, |-0.5 - -0.5| = 0
    assert (nl[0], nr[0]) == (4, 2) and q[0] == pytest.approx(4 * 2 * 0.5)


def test_identical_points_cannot_be_split():
    assert choose_split(np.ones((10, 2)), np.zeros(10), 20, 20, np.random.default_rng(0)) is None
