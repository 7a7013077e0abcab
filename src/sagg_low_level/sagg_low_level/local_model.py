"""Local linear models from the sample memory (paper Sec. 3.2-3.3, 3.6.1). ROS-free."""
from __future__ import annotations

import numpy as np


def local_jacobian(delta_alpha: np.ndarray, delta_y: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Least-squares Jacobian on a neighbourhood: paper Sec. 3.3, ``J(α) = Δy / Δα`` in the vicinity
    of α (equation ``ẏ = J(α) \\hat{α̇}``).

    Solves ``min_J Σ_i ||J Δα_i − Δy_i||²`` over the k neighbour samples (minimum-norm solution
    when under-determined). ``delta_alpha`` is (k, n), ``delta_y`` is (k, m); returns J (m, n).
    """
    jt, *_ = np.linalg.lstsq(delta_alpha, delta_y, rcond=rcond)
    return jt.T


def pseudo_inverse_step(jac: np.ndarray, dy_next: np.ndarray, rcond: float) -> np.ndarray:
    """Joint displacement for a desired effector displacement: paper Sec. 3.3, equation
    (jacobianPseudo), ``Δα = J⁺(α) · Δy_next`` with the Moore-Penrose pseudo-inverse.

    ``rcond`` cuts singular values below ``rcond × σ_max`` (vague in the paper, which bypasses
    singularities with noise; our choice, exposed as the learner parameter ``pinv_rcond``).
    """
    return np.linalg.pinv(jac, rcond=rcond) @ dy_next


def desired_displacement(y_current: np.ndarray, goal: np.ndarray, v: float) -> np.ndarray:
    """Reaching direction of paper Sec. 3.6.1: ``Δy_next = v · (y_g − y_c)/||y_g − y_c||``.

    The paper's text writes ``y_c − y_g``, which points away from the goal: a sign typo. ``v`` is
    "bounded by v_max"; our choice is to shorten the step to the remaining distance so the effector
    does not overshoot the goal: the step length is ``min(v, ||y_g − y_c||)``.
    """
    d = goal - y_current
    dist = float(np.sqrt(d @ d))
    if dist == 0.0:
        return np.zeros_like(d)
    return d * (min(v, dist) / dist)
