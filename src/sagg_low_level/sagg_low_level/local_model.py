"""Local linear models from the sample memory (paper Sec. 3.2-3.3, 3.6.1). ROS-free."""
from __future__ import annotations

import math
from typing import Generator

import numpy as np


def local_jacobian(delta_alpha: np.ndarray, delta_y: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """Least-squares Jacobian on a neighbourhood: paper Sec. 3.3, ``J(α) = Δy / Δα`` in the vicinity
    of α (equation ``ẏ = J(α) \\hat{α̇}``).

    Solves ``min_J Σ_i ||J Δα_i − Δy_i||²`` over the k neighbour samples (minimum-norm solution
    when under-determined). ``delta_alpha`` is (k, n), ``delta_y`` is (k, m); returns J (m, n).

    Parameters
    ----------
    delta_alpha : ndarray, shape (k, n)
        Joint displacements Δα of the k neighbour samples; n = joints.
    delta_y : ndarray, shape (k, m)
        Their effector displacements Δy; m = task dimensions.
    rcond : float, optional
        Relative cut-off of the small singular values of ``delta_alpha``
        (``numpy.linalg.lstsq``; learner parameter ``jacobian_rcond``).

    Returns
    -------
    ndarray, shape (m, n)
        The Jacobian J, with ``Δy ≈ J Δα``.
    """
    jt, *_ = np.linalg.lstsq(delta_alpha, delta_y, rcond=rcond)
    return jt.T


def damped_steps(jacs: np.ndarray, dys: np.ndarray, damping: float) -> np.ndarray:
    """Damped least-squares joint steps for a stack of Jacobians (B, m, n) and desired effector
    displacements (B, m): ``Δα = J^T (J J^T + λ² I)^{-1} Δy``, the joint step minimising
    ``||J Δα − Δy||² + λ² ||Δα||²`` (the "singularity-robust inverse" of Nakamura & Hanafusa 1986,
    J. Dyn. Sys. Meas. Control 108(3); Wampler 1986, IEEE Trans. SMC 16(1)).

    Per singular value σ of J the gain is σ/(σ² + λ²) instead of J⁺'s 1/σ: directions in which
    the arm barely moves its tip (σ ≪ λ, near a singularity such as the unfolded arm) get small
    joint steps instead of J⁺'s huge ones, and ||Δα|| ≤ ||Δy||/(2λ) always; where σ ≫ λ it is
    J⁺'s step. No singular value needs cutting (the gain vanishes with σ), so ``pinv_rcond`` plays
    no part. Each row is computed with the same operations whatever the stack size (one row
    alone gives the same floats; the batched evaluation relies on it, test/test_eval_batch.py).

    Parameters
    ----------
    jacs : array_like, shape (B, m, n)
        A stack of B Jacobians (m task dimensions, n joints).
    dys : array_like, shape (B, m)
        The desired effector displacement Δy of each row.
    damping : float
        λ > 0 (the callers use this function only then).

    Returns
    -------
    ndarray, shape (B, n)
        The damped joint step Δα of each row.
    """
    jacs = np.asarray(jacs, dtype=float)
    m = jacs.shape[-2]
    gram = np.matmul(jacs, np.swapaxes(jacs, -1, -2)) + (damping * damping) * np.eye(m)
    x = np.linalg.solve(gram, np.asarray(dys, dtype=float)[..., None])   # (B, m, 1)
    return (jacs * x).sum(axis=-2)


def pinv(a: np.ndarray, rcond: float) -> np.ndarray:
    """``numpy.linalg.pinv(a, rcond=rcond)`` of one real 2-D matrix, bit for bit, with less overhead.

    The same steps as numpy's: the same SVD call (``full_matrices=False``), singular values at or
    below ``rcond × σ_max`` dropped, the others inverted (the same IEEE divisions ``1 / σ``), and
    the same product ``Vᵀ · (σ⁺ ⊙ Uᵀ)`` on operands of the same layouts (tested in
    test/test_local_model_pinv.py). A stack of matrices: use ``numpy.linalg.pinv``.

    Parameters
    ----------
    a : ndarray, shape (p, q)
        A real matrix.
    rcond : float
        Singular values at or below ``rcond × σ_max`` count as 0.

    Returns
    -------
    ndarray, shape (q, p)
        The pseudo-inverse a⁺.
    """
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    sv = s.tolist()
    cutoff = rcond * max(sv)  # svd raises on NaN input, so the σ are real numbers
    inv = np.array([1.0 / x if x > cutoff else 0.0 for x in sv])
    return np.matmul(vt.T, np.multiply(inv[:, None], u.T))


def pseudo_inverse_step(jac: np.ndarray, dy_next: np.ndarray, rcond: float,
                        damping: float = 0.0) -> np.ndarray:
    """Joint displacement for a desired effector displacement: paper Sec. 3.3, equation
    (jacobianPseudo), ``Δα = J⁺(α) · Δy_next`` with the Moore-Penrose pseudo-inverse.

    ``rcond`` cuts singular values below ``rcond × σ_max`` (vague in the paper, which bypasses
    singularities with noise; our choice, exposed as the learner parameter ``pinv_rcond``).
    With ``damping`` λ > 0 (learner parameter ``reach_damping``; the paper's J⁺ is λ = 0) the
    damped least-squares step of :func:`damped_steps` instead.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Local Jacobian J(α); m = task dimensions, n = joints.
    dy_next : ndarray, shape (m,)
        Desired effector displacement Δy_next.
    rcond : float
        Relative singular-value cut-off of J⁺ (``pinv_rcond``); unused when ``damping`` > 0.
    damping : float, optional
        λ of the damped step (0: the paper's J⁺).

    Returns
    -------
    ndarray, shape (n,)
        The joint displacement Δα (joint limits not considered).
    """
    if damping:
        return damped_steps(jac[None], dy_next[None], damping)[0]
    return pinv(jac, rcond) @ dy_next


def clamped_step(jac: np.ndarray, dy_next: np.ndarray, alpha: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray, rcond: float, damping: float = 0.0) -> np.ndarray:
    """Pseudo-inverse step that respects joint limits by clamping and re-solving (the "joint
    clamping" loop of Baerlocher & Boulic 2004, "An inverse kinematics architecture enforcing an
    arbitrary number of strict priority levels", The Visual Computer 20(6); see also Flacco, De Luca
    & Khatib 2012, "Motion control of redundant robots under joint constraints: saturation in the
    null space", ICRA).

    Starts from the paper's ``Δα = J⁺ Δy_next`` (Sec. 3.3). Every joint that this step would carry
    beyond its limit is clamped: it moves exactly to its limit (``Δα_i = bound_i − α_i``, 0 when it
    is already there), its column leaves the problem, and the remaining joints are re-solved for
    the displacement still missing, ``Δα_free = J_free⁺ (Δy_next − J_clamped Δα_clamped)``; until no
    free joint violates a limit (at most n rounds). Without limits in the way it is exactly
    ``J⁺ Δy_next``. A joint at its limit whose solution moves it back inside stays free, so the
    arm can leave a limit again. Every solve is :func:`pseudo_inverse_step` with ``damping``.
    A step that leaves no joint beyond its limit is returned as it is, without the rounds (their
    first round would return the same floats; most steps are such, and skipping saves the rounds' cost);
    the others start the rounds with it.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Local Jacobian J(α); m = task dimensions, n = joints.
    dy_next : ndarray, shape (m,)
        Desired effector displacement Δy_next.
    alpha : ndarray, shape (n,)
        Current joint posture α.
    lower, upper : ndarray, shape (n,)
        Joint limits.
    rcond : float
        Relative singular-value cut-off of J⁺ (``pinv_rcond``); unused when ``damping`` > 0.
    damping : float, optional
        λ of the damped solves (0: the paper's J⁺).

    Returns
    -------
    ndarray, shape (n,)
        The joint displacement Δα: a joint that a round carries past a limit stops at that limit,
        the others are re-solved.
    """
    step = pseudo_inverse_step(jac, dy_next, rcond, damping)
    new = alpha + step
    if not ((new > upper) | (new < lower)).any():
        return step
    rounds = clamp_rounds(jac, dy_next, alpha, lower, upper)
    next(rounds)  # its first solve, J⁺ Δy_next, is the step above
    answer = step
    try:
        while True:
            cols, target = rounds.send(answer)
            answer = pseudo_inverse_step(cols, target, rcond, damping)
    except StopIteration as done:
        return done.value


def clamp_rounds(jac: np.ndarray, dy_next: np.ndarray, alpha: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray) -> Generator[tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """The rounds of :func:`clamped_step` as a coroutine (the solve of each round is the caller's):
    yields ``(cols, target)`` (the free joints' columns of J and the
    displacement they must produce), receives ``J_free⁺ · target``, returns Δα.

    Parameters
    ----------
    jac : ndarray, shape (m, n)
        Local Jacobian J(α); m = task dimensions, n = joints.
    dy_next : ndarray, shape (m,)
        Desired effector displacement Δy_next.
    alpha : ndarray, shape (n,)
        Current joint posture α.
    lower, upper : ndarray, shape (n,)
        Joint limits.

    Yields
    ------
    cols : ndarray, shape (m, f)
        The columns of J of the f free joints (all n in the first round).
    target : ndarray, shape (m,)
        The displacement the free joints must produce.

    Receives
    --------
    step : ndarray, shape (f,)
        ``J_free⁺ · target``, the free joints' solve (e.g. by :func:`pseudo_inverse_step`).

    Returns
    -------
    ndarray, shape (n,)
        The joint displacement Δα (the value of the generator's ``StopIteration``).
    """
    n = jac.shape[1]
    free = np.ones(n, dtype=bool)
    dalpha = np.zeros(n)
    idx = np.arange(n)  # the free joints
    target, cols = dy_next, jac
    a, lo, up = alpha, lower, upper  # their rows (all of them in the first round)
    for _ in range(n):
        step = yield cols, target
        new = a + step
        over = (new > up) | (new < lo)
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
        idx = free.nonzero()[0]
        a, lo, up = alpha[idx], lower[idx], upper[idx]
    return dalpha


def norm(x: np.ndarray) -> float:
    """``float(np.linalg.norm(x))`` of a 1-D float vector, the same float (numpy computes
    sqrt(x·x) there too) without its argument handling (it runs several times per micro-action).

    Parameters
    ----------
    x : ndarray, shape (p,)
        A 1-D float vector.

    Returns
    -------
    float
        Its Euclidean norm.
    """
    return math.sqrt(x.dot(x))


def desired_displacement(y_current: np.ndarray, goal: np.ndarray, v: float) -> np.ndarray:
    """Reaching direction of paper Sec. 3.6.1: ``Δy_next = v · (y_g − y_c)/||y_g − y_c||``.

    The paper's text writes ``y_c − y_g``, which points away from the goal: a sign typo. ``v`` is
    "bounded by v_max"; our choice is to shorten the step to the remaining distance so the effector
    does not overshoot the goal: the step length is ``min(v, ||y_g − y_c||)``.

    Parameters
    ----------
    y_current : ndarray, shape (m,)
        The effector's position y_c; m = task dimensions.
    goal : ndarray, shape (m,)
        The (sub)goal y_g.
    v : float
        Desired speed, task units per micro-action (learner parameter ``v``), > 0.

    Returns
    -------
    ndarray, shape (m,)
        Δy_next, of length ``min(v, ||y_g − y_c||)``; zeros when y_c = y_g.
    """
    d = goal - y_current
    dist = norm(d)
    if dist == 0.0:
        return np.zeros_like(d)
    return d * (min(v, dist) / dist)
