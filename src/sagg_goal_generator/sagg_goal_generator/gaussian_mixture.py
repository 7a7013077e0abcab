"""Gaussian mixtures fitted by expectation-maximisation, for the ``alp-gmm`` teacher. ROS-free.

The EM of a Gaussian mixture (Dempster, Laird & Rubin 1977, J. R. Stat. Soc. B 39(1); Bishop 2006,
*Pattern Recognition and Machine Learning*, Sec. 9.2.2), step for step as scikit-learn's
``GaussianMixture`` does it with the defaults that ALP-GMM's reference implementation uses
(Portelas et al. 2019; TeachMyAgent ``ALPGMM``: ``GaussianMixture(n_components=k,
covariance_type=..., random_state=...)``): responsibilities initialised from a k-means partition,
``reg_covar`` added to each covariance's diagonal, ``10·eps`` added to each component's weight
sum, iterations until the mean log-likelihood changes by less than ``tol``, at most ``max_iter``,
the best of ``inits`` initialisations kept; AIC and BIC as scikit-learn counts parameters.

Why not scikit-learn itself: its EM loops over the components in Python, and in the fixed context
its fits (the reference's 2..10 components, once every 250 goals) cost about as much as the learning
(docs/notes/teachers.md). The numpy functions below (:func:`em` and its steps) are the definition,
every step handling all components at once (still ~25 numpy calls per iteration); :func:`fit` runs
the same EM compiled (``em_kernel.c``, :func:`em_compiled`), much cheaper again
(docs/notes/compiled-loop.md). ``test/test_gaussian_mixture.py`` checks both against scikit-learn's
``GaussianMixture`` started from the same parameters, and against each other.

The k-means partition is SciPy's ``kmeans2`` (k-means++ seeding, Arthur & Vassilvitskii 2007, then
Lloyd iterations), drawn from the caller's ``numpy.random.Generator``; scikit-learn's ``KMeans``
(also k-means++, Lloyd to convergence) would give a slightly different partition: a different
initialisation of the same EM, not a different model.
"""
from __future__ import annotations

import inspect
import math
import warnings
from dataclasses import dataclass

import numpy as np

from .compiled import em_kernel

COVARIANCES = ("full", "diag")
_LOG_2PI = math.log(2.0 * math.pi)
_TINY = 10.0 * np.finfo(float).eps  # scikit-learn's guard on a component's weight sum


class MixtureFitError(ValueError):
    """A covariance is not positive definite (a component collapsed onto fewer dimensions than the
    data have, ``reg_covar`` too small): scikit-learn's 'ill-defined empirical covariance'."""


@dataclass
class Mixture:
    """A fitted mixture: weights (K,), means (K, D), covariances (K, D, D) (diagonal: (K, D)), the
    precision Cholesky factors (same shapes), the mean log-likelihood of the data, iterations."""

    weights: np.ndarray
    means: np.ndarray
    covariances: np.ndarray
    precisions_cholesky: np.ndarray
    covariance: str
    lower_bound: float
    iterations: int
    converged: bool

    def full_covariances(self) -> np.ndarray:
        """(K, D, D) whatever the covariance type."""
        if self.covariance == "full":
            return self.covariances
        return np.stack([np.diag(c) for c in self.covariances])


def kmeans_responsibilities(data: np.ndarray, k: int, rng: np.random.Generator, iterations: int = 10) -> np.ndarray:
    """One-hot responsibilities (N, k) of a k-means partition of ``data`` (SciPy's ``kmeans2``,
    k-means++ seeding, ``iterations`` Lloyd steps: SciPy's default; EM refines the partition). A
    cluster left empty keeps its seed and gives an all-zero column (EM then treats it as
    scikit-learn treats an empty component)."""
    # lazy (heavy): scipy (the goal generator node starts without it unless alp-gmm fits)
    from scipy.cluster.vq import kmeans2

    # SciPy >= 1.15 names the generator `rng`, older ones (Ubuntu 24.04's 1.11) `seed`: the same draws
    key = "rng" if "rng" in inspect.signature(kmeans2).parameters else "seed"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "One of the clusters is empty": handled as said above
        _, labels = kmeans2(np.asarray(data, float), k, iter=iterations, minit="++", check_finite=False, **{key: rng})
    resp = np.zeros((len(data), k))
    resp[np.arange(len(data)), labels] = 1.0
    return resp


def gaussian_parameters(data: np.ndarray, resp: np.ndarray, reg_covar: float, covariance: str):
    """The M-step's estimates (Bishop 2006 eqs. 9.24-9.26; scikit-learn's
    ``_estimate_gaussian_parameters``): ``N_k = Σ_n r_nk + 10·eps``, means ``Σ_n r_nk x_n / N_k``,
    covariances ``Σ_n r_nk (x_n − μ_k)(x_n − μ_k)ᵀ / N_k + reg_covar·I`` (diagonal: the diagonal of
    it). Returns (N_k, means, covariances), weights unnormalised."""
    nk = resp.sum(axis=0) + _TINY
    means = (resp.T @ data) / nk[:, None]
    if covariance == "full":
        diff = data[None, :, :] - means[:, None, :]                        # (K, N, D)
        cov = np.matmul(np.swapaxes(diff * resp.T[:, :, None], 1, 2), diff) / nk[:, None, None]
        d = data.shape[1]
        cov[:, np.arange(d), np.arange(d)] += reg_covar
    else:
        avg_x2 = (resp.T @ (data * data)) / nk[:, None]
        avg_x_means = means * (resp.T @ data) / nk[:, None]
        cov = avg_x2 - 2.0 * avg_x_means + means ** 2 + reg_covar
    return nk, means, cov


def precision_cholesky(cov: np.ndarray, covariance: str) -> np.ndarray:
    """Cholesky factors of the precisions (scikit-learn's ``_compute_precision_cholesky``): full,
    ``(L⁻¹)ᵀ`` of each covariance's lower factor ``L``; diagonal, ``1/√σ²``. Raises
    :class:`MixtureFitError` when a covariance is not positive definite."""
    if covariance == "full":
        try:
            chol = np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise not_positive_definite(covariance) from None
        eye = np.broadcast_to(np.eye(cov.shape[-1]), cov.shape)
        return np.swapaxes(np.linalg.solve(chol, eye), -1, -2)
    if np.any(cov <= 0.0):
        raise not_positive_definite(covariance)
    return 1.0 / np.sqrt(cov)


def not_positive_definite(covariance: str) -> MixtureFitError:
    """The error of a fit whose covariance (``full``) or variance (``diag``) is not positive: a
    component collapsed onto fewer dimensions than the data has."""
    if covariance == "full":
        return MixtureFitError("a mixture component's covariance is not positive definite "
                               "(collapsed component); increase reg_covar")
    return MixtureFitError("a mixture component's variance is not positive; increase reg_covar")


def weighted_log_prob(data: np.ndarray, weights: np.ndarray, means: np.ndarray, prec_chol: np.ndarray,
                      covariance: str) -> np.ndarray:
    """``log π_k + log N(x_n | μ_k, Σ_k)`` for every point and component, (N, K) (Bishop 2006 eq.
    9.7 inside the log; scikit-learn's ``_estimate_log_gaussian_prob`` + ``log weights``)."""
    d = data.shape[1]
    if covariance == "full":
        log_det = np.log(np.diagonal(prec_chol, axis1=-2, axis2=-1)).sum(axis=-1)       # (K,)
        y = np.matmul(data, prec_chol) - np.matmul(means[:, None, :], prec_chol)       # (K, N, D)
        maha = np.square(y).sum(axis=-1).T
    else:
        log_det = np.log(prec_chol).sum(axis=1)
        prec = prec_chol ** 2
        maha = (np.sum(means ** 2 * prec, axis=1)[None, :] - 2.0 * (data @ (means * prec).T)
                + (data * data) @ prec.T)
    return -0.5 * (d * _LOG_2PI + maha) + log_det[None, :] + np.log(weights)[None, :]


def _logsumexp_rows(a: np.ndarray) -> np.ndarray:
    top = a.max(axis=1)
    return top + np.log(np.exp(a - top[:, None]).sum(axis=1))


def em(data: np.ndarray, resp: np.ndarray, covariance: str = "full", reg_covar: float = 1e-6,
       tol: float = 1e-3, max_iter: int = 100, start: tuple | None = None) -> Mixture:
    """Expectation-maximisation of a Gaussian mixture (Dempster, Laird & Rubin 1977; Bishop 2006
    Sec. 9.2.2, the four steps on p. 438-439), from the initial responsibilities ``resp`` (N, K),
    or from ``start`` = (weights, means, precision Cholesky factors) when given (as scikit-learn's
    ``weights_init`` / ``means_init`` / ``precisions_init``). Each iteration: E-step (responsibilities
    from the current parameters), M-step (:func:`gaussian_parameters`, weights normalised), then the
    mean log-likelihood of the E-step; stops when it changed by less than ``tol`` (scikit-learn's
    test, ``abs(change) < tol``), else after ``max_iter`` iterations."""
    data = np.asarray(data, float)
    n = len(data)
    if start is None:
        nk, means, cov = gaussian_parameters(data, resp, reg_covar, covariance)
        weights = nk / n
        prec_chol = precision_cholesky(cov, covariance)
    else:
        weights, means, prec_chol = (np.array(x, float) for x in start)
        cov = None
    lower_bound, converged, it = -np.inf, False, 0
    for it in range(1, max_iter + 1):
        prev = lower_bound
        wlp = weighted_log_prob(data, weights, means, prec_chol, covariance)
        norm = _logsumexp_rows(wlp)
        log_resp = wlp - norm[:, None]
        nk, means, cov = gaussian_parameters(data, np.exp(log_resp), reg_covar, covariance)
        weights = nk / nk.sum()
        prec_chol = precision_cholesky(cov, covariance)
        lower_bound = float(norm.mean())
        if abs(lower_bound - prev) < tol:
            converged = True
            break
    return Mixture(weights, means, cov, prec_chol, covariance, lower_bound, it, converged)


def em_compiled(data: np.ndarray, resp: np.ndarray, covariance: str = "full", reg_covar: float = 1e-6,
                tol: float = 1e-3, max_iter: int = 100) -> Mixture:
    """:func:`em` from the responsibilities ``resp``, computed by the compiled ``em_kernel.em`` (the
    same steps; the Mahalanobis distances by forward substitution with the covariances' Cholesky
    factors). Raises :class:`MixtureFitError` where :func:`em` does."""
    data = np.ascontiguousarray(data, dtype=float)
    resp = np.ascontiguousarray(resp, dtype=float)
    k, d = resp.shape[1], data.shape[1]
    shape = (k, d, d) if covariance == "full" else (k, d)
    weights, means, cov, prec = np.empty(k), np.empty((k, d)), np.empty(shape), np.empty(shape)
    out = em_kernel.em(data, resp, covariance == "full", reg_covar, tol, max_iter, weights, means, cov, prec)
    if out is None:  # a covariance not positive definite
        raise not_positive_definite(covariance)
    it, converged, bound = out
    return Mixture(weights, means, cov, prec, covariance, bound, it, converged)


def n_parameters(k: int, d: int, covariance: str) -> int:
    """Free parameters of a mixture of ``k`` Gaussians in ``d`` dimensions (scikit-learn's
    ``_n_parameters``): covariances ``k·d(d+1)/2`` (diagonal ``k·d``), means ``k·d``, weights
    ``k − 1``."""
    cov = k * d * (d + 1) // 2 if covariance == "full" else k * d
    return cov + k * d + k - 1


def information_criterion(data: np.ndarray, mixture: Mixture, criterion: str) -> float:
    """AIC (Akaike 1974) ``−2 log L + 2p`` or BIC (Schwarz 1978) ``−2 log L + p log N`` of
    ``mixture`` on ``data``, log L the total log-likelihood (scikit-learn's ``aic`` / ``bic``)."""
    data = np.asarray(data, float)
    n, d = data.shape
    log_l = float(_logsumexp_rows(weighted_log_prob(data, mixture.weights, mixture.means,
                                                    mixture.precisions_cholesky, mixture.covariance)).sum())
    p = n_parameters(len(mixture.weights), d, mixture.covariance)
    return -2.0 * log_l + (2.0 * p if criterion == "aic" else p * math.log(n))


def fit(data: np.ndarray, k: int, rng: np.random.Generator, covariance: str = "full", inits: int = 1,
        reg_covar: float = 1e-6, tol: float = 1e-3, max_iter: int = 100) -> Mixture:
    """A mixture of ``k`` Gaussians fitted to ``data``: ``inits`` k-means initialisations (from
    ``rng``), each refined by :func:`em` (compiled: :func:`em_compiled`), the one of largest final
    mean log-likelihood kept (scikit-learn's ``n_init``; ties: the first)."""
    if covariance not in COVARIANCES:
        raise ValueError(f"covariance: got {covariance!r}; allowed: {', '.join(COVARIANCES)}")
    best = None
    for _ in range(inits):
        m = em_compiled(data, kmeans_responsibilities(data, k, rng), covariance, reg_covar, tol, max_iter)
        if best is None or m.lower_bound > best.lower_bound:
            best = m
    return best
