"""local_model.pinv and the clamped step against their numpy references, byte for byte."""
from __future__ import annotations

import numpy as np
import pytest

from sagg_low_level.local_model import clamped_step, pinv, pseudo_inverse_step


def _matrices(rng):
    """Full-rank, rank-deficient, tiny-singular-value and zero matrices, in several layouts."""
    out = []
    for m, n in ((2, 7), (2, 15), (3, 8), (2, 2), (7, 2), (1, 5), (2, 1)):
        a = rng.normal(size=(m, n))
        out += [a, np.asfortranarray(a), rng.normal(size=(n, m)).T]
        if min(m, n) > 1:
            b = a.copy()
            b[1] = 2.0 * b[0]  # rank-deficient
            out.append(b)
            c = a.copy()
            c[1] = b[0] * 2.0 + 1e-9 * rng.normal(size=n)  # one tiny singular value
            out.append(c)
        out.append(np.zeros((m, n)))
        wide = rng.normal(size=(m, 2 * n))
        out.append(wide[:, ::2])  # non-contiguous
    return out


@pytest.mark.parametrize("rcond", [0.0, 1e-10, 1e-2, 0.5, 1.0])
def test_pinv_equals_numpy_bytes(rcond):
    rng = np.random.default_rng(7)
    for a in _matrices(rng):
        assert pinv(a, rcond).tobytes() == np.linalg.pinv(a, rcond=rcond).tobytes()
        dy = rng.normal(size=a.shape[0])
        assert pseudo_inverse_step(a, dy, rcond).tobytes() == (np.linalg.pinv(a, rcond=rcond) @ dy).tobytes()


def _clamped_reference(jac, dy_next, alpha, lower, upper, rcond):
    """clamped_step as written before the fast path (numpy's pinv, flatnonzero every round)."""
    n = jac.shape[1]
    free = np.ones(n, dtype=bool)
    dalpha = np.zeros(n)
    target = dy_next
    cols = jac
    for _ in range(n):
        step = np.linalg.pinv(cols, rcond=rcond) @ target
        idx = np.flatnonzero(free)
        new = alpha[idx] + step
        over = (new > upper[idx]) | (new < lower[idx])
        dalpha[idx] = step
        if not over.any():
            break
        hit = idx[over]
        dalpha[hit] = np.minimum(np.maximum(new[over], lower[hit]), upper[hit]) - alpha[hit]
        free[hit] = False
        if not free.any():
            break
        target = dy_next - jac[:, ~free] @ dalpha[~free]
        cols = jac[:, free]
    return dalpha


def test_clamped_step_equals_reference_bytes():
    rng = np.random.default_rng(3)
    hits = 0
    for trial in range(400):
        n = int(rng.integers(1, 16))
        jac = rng.normal(size=(2, n)).T.copy().T  # F-ordered like local_jacobian's jt.T
        lower, upper = np.full(n, -1.0), np.full(n, 1.0)
        alpha = rng.uniform(-1.0, 1.0, n)
        alpha[rng.random(n) < 0.3] = 1.0  # some joints at a limit
        dy = rng.normal(size=2) * (0.1 if trial % 2 else 3.0)
        got = clamped_step(jac, dy, alpha, lower, upper, 1e-2)
        ref = _clamped_reference(jac, dy, alpha, lower, upper, 1e-2)
        assert got.tobytes() == ref.tobytes()
        hits += bool(np.any(np.abs(alpha + got) >= 1.0))
    assert hits > 50  # the clamping rounds were exercised
