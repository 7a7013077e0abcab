"""The compiled inner loops (knn_kernel.c: the neighbour searches; reach_kernel.c: the local model's
small linear algebra), built with the package by its setup.py, imported in one place so that a
source checkout without its build step says what to do; and the thin wrappers the learners call.

The wrapped routines compute what the Python functions of :mod:`sagg_low_level.local_model` define
(their docstrings cite the paper), in another order of operations: the same quantities to ~1e-15
relative on well-conditioned problems, the same rank cut on rank-deficient ones
(test/test_reach_kernel.py). Each is one C call instead of 15-40 numpy calls.
"""
from __future__ import annotations

import numpy as np

try:
    from . import knn_kernel, reach_kernel
except ImportError as exc:  # a source checkout used without its build step
    raise ImportError("sagg_low_level's compiled kernels (knn_kernel.c, reach_kernel.c) are not built: run "
                      "`make setup`, `pip install -e src/sagg_low_level` or `colcon build`") from exc

__all__ = ["knn_kernel", "reach_kernel", "jacobian", "jacobians", "pinv_step", "reach_step", "reach_steps"]


def jacobians(delta_alpha: np.ndarray, delta_y: np.ndarray, idx: np.ndarray, rcond: float) -> np.ndarray:
    """``local_model.local_jacobian(delta_alpha[row], delta_y[row], rcond)`` for every row of ``idx``
    (B, k; one row may be given as (k,)): (B, m, n). ``delta_alpha`` (N, n) and ``delta_y`` (N, m): the
    memory's arrays. ValueError when a set holds a non-finite value."""
    idx = np.ascontiguousarray(np.atleast_2d(idx), dtype=np.int64)
    out = np.empty((idx.shape[0], np.shape(delta_y)[1], np.shape(delta_alpha)[1]))
    reach_kernel.jacobians(np.ascontiguousarray(delta_alpha, dtype=float), np.ascontiguousarray(delta_y, dtype=float),
                           idx, rcond, out)
    return out


def jacobian(delta_alpha: np.ndarray, delta_y: np.ndarray, idx: np.ndarray | None, rcond: float) -> np.ndarray:
    """``local_model.local_jacobian(delta_alpha[idx], delta_y[idx], rcond)`` (every row when ``idx`` is
    None): (m, n). One row of :func:`jacobians` (the kernel takes a 1-D ``idx`` as one row: the same
    routine, the same floats), without the stacking (a call per micro-action)."""
    c = np.ascontiguousarray
    rows = np.arange(len(delta_alpha), dtype=np.int64) if idx is None else c(idx, dtype=np.int64)
    out = np.empty((np.shape(delta_y)[1], np.shape(delta_alpha)[1]))
    reach_kernel.jacobians(c(delta_alpha, dtype=float), c(delta_y, dtype=float), rows, rcond, out)
    return out


def reach_steps(jacs: np.ndarray, dys: np.ndarray, alphas: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                rcond: float, damping: float, clamp: bool) -> np.ndarray:
    """Row by row, ``local_model.clamped_step(jacs[b], dys[b], alphas[b], lower, upper, rcond,
    damping)`` (``clamp``) or ``local_model.pseudo_inverse_step(jacs[b], dys[b], rcond, damping)``:
    (B, n). A row gives the same floats in any stack (one C routine per row)."""
    c = np.ascontiguousarray
    out = np.empty(np.shape(alphas))
    reach_kernel.steps(c(jacs, dtype=float), c(dys, dtype=float), c(alphas, dtype=float), c(lower, dtype=float),
                       c(upper, dtype=float), rcond, damping, clamp, out)
    return out


def reach_step(jac: np.ndarray, dy: np.ndarray, alpha: np.ndarray, lower: np.ndarray, upper: np.ndarray,
               rcond: float, damping: float, clamp: bool) -> np.ndarray:
    """One row of :func:`reach_steps`: (n,) (the kernel reads flat buffers: a (m, n) ``jac`` is a
    stack of one)."""
    return reach_steps(jac, dy, alpha, lower, upper, rcond, damping, clamp)


def pinv_step(jac: np.ndarray, dy: np.ndarray, rcond: float, damping: float = 0.0) -> np.ndarray:
    """``local_model.pseudo_inverse_step(jac, dy, rcond, damping)``: (n,), no joint limits."""
    n = np.shape(jac)[1]
    return reach_step(jac, dy, np.zeros(n), np.full(n, -np.inf), np.full(n, np.inf), rcond, damping, False)
