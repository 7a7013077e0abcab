"""The compiled local-model routines (reach_kernel.c through sagg_low_level.compiled) against their
Python references in sagg_low_level.local_model, on random cases.

Tolerance: 1e-9 relative to the reference's largest entry. Both sides are backward-stable
solutions of the same problem (a Householder QR or Jacobi SVD here, LAPACK's SVD in numpy), so they
differ by about cond · ε: the sets below have cond < 1e4 (checked), which bounds the difference by
~1e-12; 1e-9 leaves room without hiding a wrong formula (a wrong sign, a missed cut or a missed
clamp is O(1)). Rank-deficient cases are built so that the cut is unambiguous (the singular
values are exactly 0 or far above ``rcond``), where both sides must cut the same directions.
"""
from __future__ import annotations

import numpy as np
import pytest

from sagg_low_level import compiled
from sagg_low_level.local_model import clamped_step, local_jacobian, pseudo_inverse_step

REL = 1e-9


def close(got, want):
    scale = max(float(np.abs(want).max()), 1e-300)
    assert float(np.abs(np.asarray(got) - want).max()) <= REL * scale, (got, want)


def memory_rows(rng, total, n, m):
    return rng.normal(0.0, 0.05, (total, n)), rng.normal(0.0, 0.04, (total, m))


@pytest.mark.parametrize("n, m", [(2, 2), (3, 2), (7, 2), (7, 3), (15, 2), (30, 3), (12, 1)])
def test_jacobian_equals_lstsq_on_random_neighbour_sets(n, m):
    rng = np.random.default_rng(n * 10 + m)
    da, dy = memory_rows(rng, 400, n, m)
    for k in (n, 2 * n, 3 * n + 1):
        for _ in range(10):
            idx = rng.choice(400, k, replace=False)
            assert np.linalg.cond(da[idx]) < 1e4
            close(compiled.jacobian(da, dy, idx, 1e-10), local_jacobian(da[idx], dy[idx], 1e-10))


@pytest.mark.parametrize("case", ["duplicate column", "zero column", "repeated rows", "fewer rows than joints",
                                  "one row", "all zero", "scaled copies"])
def test_jacobian_cuts_what_lstsq_cuts_on_rank_deficient_sets(case):
    rng = np.random.default_rng(hash(case) % 2**32)
    n, m = 7, 2
    da, dy = memory_rows(rng, 50, n, m)
    idx = np.arange(14)
    if case == "duplicate column":
        da[:, 4] = da[:, 1]
    elif case == "zero column":
        da[:, 6] = 0.0
    elif case == "repeated rows":
        da[7:14] = da[0:7]   # 7 distinct rows, rank 7 = n but each twice with other outcomes
        da[3] = da[2]        # rank 6
    elif case == "fewer rows than joints":
        idx = np.arange(4)
    elif case == "one row":
        idx = np.arange(1)
    elif case == "all zero":
        da[:] = 0.0
    elif case == "scaled copies":
        da[:14] = np.outer(rng.normal(size=14), da[0])   # rank 1
    want = local_jacobian(da[idx], dy[idx], 1e-10)
    got = compiled.jacobian(da, dy, idx, 1e-10)
    if case == "all zero":
        assert np.array_equal(got, np.zeros((m, n))) and np.array_equal(want, np.zeros((m, n)))
    else:
        close(got, want)


def test_jacobian_applies_rcond_as_lstsq_does():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(14, 7))
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    s = np.array([1.0, 0.5, 0.2, 0.1, 1e-2, 1e-3, 1e-4])     # (cond 1e4, as the other sets)
    a = (u * s) @ vt
    y = rng.normal(size=(14, 2))
    for rcond in (1e-10, 5e-4, 5e-3, 5e-2, 0.15, 0.3, 0.7):   # cuts 0, 1, 2, 3, 4, 5, 6 values
        close(compiled.jacobian(a, y, np.arange(14), rcond), local_jacobian(a, y, rcond))


def test_many_rows_give_each_rows_floats():
    rng = np.random.default_rng(2)
    da, dy = memory_rows(rng, 300, 7, 2)
    idx = np.stack([rng.choice(300, 14, replace=False) for _ in range(25)])
    many = compiled.jacobians(da, dy, idx, 1e-10)
    assert all(many[b].tobytes() == compiled.jacobian(da, dy, idx[b], 1e-10).tobytes() for b in range(25))


def test_bad_indices_and_shapes_are_refused():
    da, dy = memory_rows(np.random.default_rng(3), 20, 3, 2)
    with pytest.raises(IndexError):
        compiled.jacobian(da, dy, np.array([0, 1, 20]), 1e-10)
    with pytest.raises(IndexError):
        compiled.jacobian(da, dy, np.array([-1, 1, 2]), 1e-10)
    with pytest.raises(ValueError):
        compiled.jacobian(da, dy, np.zeros(0, dtype=np.int64), 1e-10)   # an empty neighbour set
    with pytest.raises(ValueError):
        compiled.reach_steps(np.zeros((1, 2, 3)), np.zeros((1, 2)), np.zeros((1, 4)), np.zeros(3), np.ones(3),
                             1e-2, 0.0, True)


def random_problem(rng, m, n):
    jac = rng.normal(0.0, 1.0, (m, n))
    dy = rng.normal(0.0, 0.05, m)
    lower, upper = -np.ones(n), np.ones(n)
    alpha = rng.uniform(-1.0, 1.0, n)
    alpha[rng.random(n) < 0.3] = rng.choice([-1.0, 1.0])   # some joints at a limit
    return jac, dy, alpha, lower, upper


@pytest.mark.parametrize("damping", [0.0, 0.05, 1.0])
@pytest.mark.parametrize("m, n", [(2, 3), (2, 7), (3, 7), (2, 15), (3, 30), (3, 2), (1, 4)])
def test_steps_equal_pseudo_inverse_and_clamped_steps(damping, m, n):
    rng = np.random.default_rng(100 * m + n)
    clamped_rows = 0
    for _ in range(40):
        jac, dy, alpha, lo, up = random_problem(rng, m, n)
        dy *= 20.0 * rng.random()        # some steps large enough to leave the limits
        plain = pseudo_inverse_step(jac, dy, 1e-2, damping)
        close(compiled.reach_step(jac, dy, alpha, lo, up, 1e-2, damping, False), plain)
        want = clamped_step(jac, dy, alpha, lo, up, 1e-2, damping)
        got = compiled.reach_step(jac, dy, alpha, lo, up, 1e-2, damping, True)
        close(got, want)
        assert np.all(alpha + got <= up + 1e-12) and np.all(alpha + got >= lo - 1e-12)
        clamped_rows += int(not np.array_equal(want, plain))
    assert clamped_rows > 0   # the clamping rounds were exercised


def test_pinv_step_cuts_small_singular_values_and_a_zero_jacobian_gives_no_step():
    rng = np.random.default_rng(4)
    row = rng.normal(size=7)
    rank1 = np.stack([row, 2.0 * row])                       # second singular value exactly 0
    dy = np.array([0.3, -0.1])
    close(compiled.reach_step(rank1, dy, np.zeros(7), -np.ones(7), np.ones(7), 1e-2, 0.0, False),
          pseudo_inverse_step(rank1, dy, 1e-2))
    near = np.stack([row, row + 1e-5 * rng.normal(size=7)])  # σ2/σ1 ~ 1e-5 < rcond: cut
    close(compiled.reach_step(near, dy, np.zeros(7), -np.ones(7), np.ones(7), 1e-2, 0.0, False),
          pseudo_inverse_step(near, dy, 1e-2))
    zero = np.zeros((2, 7))
    for damping in (0.0, 0.5):
        assert np.array_equal(compiled.reach_step(zero, dy, np.zeros(7), -np.ones(7), np.ones(7), 1e-2, damping,
                                                  True), np.zeros(7))


def test_a_step_with_every_joint_clamped_stops_each_at_its_limit():
    jac = np.array([[1.0, 1.0, 1.0], [0.5, -0.5, 0.2]])
    alpha = np.array([0.9, -0.9, 0.95])
    lo, up = -np.ones(3), np.ones(3)
    dy = np.array([50.0, 0.0])   # far beyond what the limits allow
    got = compiled.reach_step(jac, dy, alpha, lo, up, 1e-2, 0.0, True)
    close(got, clamped_step(jac, dy, alpha, lo, up, 1e-2))
    assert np.all(alpha + got <= up + 1e-15) and np.all(alpha + got >= lo - 1e-15)


def test_stacked_steps_give_each_rows_floats():
    rng = np.random.default_rng(5)
    probs = [random_problem(rng, 2, 7) for _ in range(30)]
    jacs, dys, alphas = (np.stack([p[i] for p in probs]) for i in range(3))
    dys *= 10.0
    lo, up = probs[0][3], probs[0][4]
    many = compiled.reach_steps(jacs, dys, alphas, lo, up, 1e-2, 0.3, True)
    for b in range(30):
        assert many[b].tobytes() == compiled.reach_step(jacs[b], dys[b], alphas[b], lo, up, 1e-2, 0.3, True).tobytes()


@pytest.mark.parametrize("rcond", [0.0, 1e-300, 1e-10])
def test_fewer_rows_than_unknowns_with_any_rcond(rcond):
    """k < n (the fixed context's predictor early on, a small `neighbours`) and m > free joints: only
    min(rows, cols) singular values exist; none of the surplus directions may be inverted, whatever
    rcond (found by review: rcond 0 once gave 1e160)."""
    rng = np.random.default_rng(6)
    da, dy = memory_rows(rng, 40, 15, 2)
    for k in (1, 3, 8, 14):
        idx = rng.choice(40, k, replace=False)
        close(compiled.jacobian(da, dy, idx, rcond), local_jacobian(da[idx], dy[idx], rcond))
    jac = rng.normal(size=(3, 2))                    # more task dimensions than joints
    dy3 = rng.normal(size=3)
    for damping in (0.0, 0.4):
        close(compiled.pinv_step(jac, dy3, rcond, damping), pseudo_inverse_step(jac, dy3, rcond, damping))


def test_non_finite_input_is_refused_not_answered():
    da, dy = memory_rows(np.random.default_rng(7), 20, 3, 2)
    da[5, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        compiled.jacobian(da, dy, np.arange(10), 1e-10)
    jac = np.array([[1.0, np.inf, 0.0], [0.0, 1.0, 0.0]])
    with pytest.raises(ValueError, match="NaN"):
        compiled.pinv_step(jac, np.ones(2), 1e-2)
