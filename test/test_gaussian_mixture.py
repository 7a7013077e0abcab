"""The alp-gmm teacher's Gaussian mixtures (sagg_goal_generator/gaussian_mixture.py) against
scikit-learn's ``GaussianMixture``, the implementation ALP-GMM's reference uses.

Both are started from the same parameters (scikit-learn's ``weights_init`` / ``means_init`` /
``precisions_init`` from our first M-step), so both run the same EM: the same number of
iterations, and parameters, log-likelihood and AIC/BIC equal to 1e-9 relative. The tolerance:
the arithmetic is the same, summed in another order (stacked products instead of one component at
a time); rounding differences of ~1e-16 per operation do not grow in EM near its fixed point
(measured: 1e-15 after 47 iterations).
"""
from __future__ import annotations

import numpy as np
import pytest
from sklearn.mixture import GaussianMixture

from sagg_goal_generator import gaussian_mixture as gm
from sagg_goal_generator.alp_gmm import fit_mixture


def dataset(seed: int, n: int, d: int) -> np.ndarray:
    """Points like alp-gmm's: goals uniform in a box, then an ALP column (non-negative, skewed)."""
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(-1.0, 1.0, (n, d - 1)), np.abs(rng.normal(0.0, 0.1, n))])


def sklearn_from_our_start(data, resp, covariance, tol=1e-3):
    nk, means, cov = gm.gaussian_parameters(data, resp, 1e-6, covariance)
    pc = gm.precision_cholesky(cov, covariance)
    prec = np.matmul(pc, np.swapaxes(pc, -1, -2)) if covariance == "full" else pc ** 2
    return GaussianMixture(len(nk), covariance_type=covariance, tol=tol, weights_init=nk / len(data),
                           means_init=means, precisions_init=prec).fit(data)


@pytest.mark.parametrize("implementation", ["numpy", "compiled"])
@pytest.mark.parametrize("covariance", gm.COVARIANCES)
@pytest.mark.parametrize("seed, n, d, k", [(0, 250, 3, 2), (1, 250, 3, 6), (2, 250, 3, 10), (3, 120, 4, 5),
                                           (4, 40, 2, 3), (10, 250, 3, 7)])
def test_em_equals_scikit_learns_from_the_same_start(implementation, covariance, seed, n, d, k):
    """The numpy EM (the reference) and the compiled one (what fit runs) against scikit-learn, and
    the compiled against the numpy one (its precision factors too)."""
    data = dataset(seed, n, d)
    resp = gm.kmeans_responsibilities(data, k, np.random.default_rng(seed))
    ours = (gm.em if implementation == "numpy" else gm.em_compiled)(data, resp, covariance)
    ref = sklearn_from_our_start(data, resp, covariance)
    assert ours.iterations == ref.n_iter_ and ours.converged == ref.converged_
    np.testing.assert_allclose(ours.weights, ref.weights_, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ours.means, ref.means_, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ours.covariances, ref.covariances_, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ours.precisions_cholesky, gm.em(data, resp, covariance).precisions_cholesky,
                               rtol=1e-9, atol=1e-12)
    assert ours.lower_bound == pytest.approx(ref.lower_bound_, rel=1e-9)
    for crit, ref_value in (("aic", ref.aic(data)), ("bic", ref.bic(data))):
        assert gm.information_criterion(data, ours, crit) == pytest.approx(ref_value, rel=1e-9)
    # scikit-learn's parameter count, from its public AIC and score: aic = -2 n score + 2 p
    assert gm.n_parameters(k, d, covariance) == round((ref.aic(data) + 2 * n * ref.score(data)) / 2)


def test_the_compiled_em_names_a_collapsed_component_and_bad_shapes():
    data = dataset(11, 30, 3)
    data[:, 2] = 0.0                        # a flat dimension: with reg_covar 0 the covariance is singular
    resp = gm.kmeans_responsibilities(data, 2, np.random.default_rng(0))
    with pytest.raises(gm.MixtureFitError, match="positive definite"):
        gm.em_compiled(data, resp, "full", reg_covar=0.0)
    for em in (gm.em, gm.em_compiled):  # a zero variance: both EMs name it alike
        with pytest.raises(gm.MixtureFitError, match="variance is not positive"):
            em(data, resp, "diag", reg_covar=0.0)
    with pytest.raises(ValueError, match="shapes"):
        from sagg_goal_generator.compiled import em_kernel
        em_kernel.em(data, resp, True, 1e-6, 1e-3, 100, np.empty(3), np.empty((2, 3)), np.empty((2, 3, 3)),
                     np.empty((2, 3, 3)))


def test_em_started_from_parameters_equals_scikit_learns_start():
    data = dataset(5, 200, 3)
    resp = gm.kmeans_responsibilities(data, 4, np.random.default_rng(5))
    nk, means, cov = gm.gaussian_parameters(data, resp, 1e-6, "full")
    ours = gm.em(data, None, "full", start=(nk / len(data), means, gm.precision_cholesky(cov, "full")))
    ref = sklearn_from_our_start(data, resp, "full")
    assert ours.iterations == ref.n_iter_
    np.testing.assert_allclose(ours.means, ref.means_, rtol=1e-9, atol=1e-12)


def test_em_stops_at_max_iter_and_the_likelihood_never_falls():
    data = dataset(6, 250, 3)
    resp = gm.kmeans_responsibilities(data, 8, np.random.default_rng(6))
    bounds = [gm.em(data, resp, "full", tol=1e-12, max_iter=it).lower_bound for it in range(1, 15)]
    assert all(b2 >= b1 - 1e-12 for b1, b2 in zip(bounds, bounds[1:]))   # EM's monotonicity
    m = gm.em(data, resp, "full", tol=1e-12, max_iter=3)
    assert m.iterations == 3 and not m.converged


def test_kmeans_responsibilities_are_one_hot_and_follow_the_generator():
    data = dataset(7, 100, 3)
    a = gm.kmeans_responsibilities(data, 5, np.random.default_rng(11))
    b = gm.kmeans_responsibilities(data, 5, np.random.default_rng(11))
    assert a.shape == (100, 5) and set(np.unique(a)) <= {0.0, 1.0} and np.all(a.sum(axis=1) == 1.0)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, gm.kmeans_responsibilities(data, 5, np.random.default_rng(12)))


def test_an_empty_cluster_is_a_component_of_tiny_weight_not_an_error():
    data = np.repeat(np.array([[0.0, 0.0, 0.1], [1.0, 1.0, 0.2], [2.0, 0.0, 0.0]]), 10, axis=0)
    resp = np.zeros((30, 4))
    resp[np.arange(30), np.arange(30) // 10] = 1.0   # the 4th column empty
    m = gm.em(data, resp, "full")
    assert np.all(np.isfinite(m.means)) and m.weights[3] < 1e-9 and m.weights.sum() == pytest.approx(1.0)


def test_a_covariance_that_is_not_positive_definite_is_named():
    bad = np.array([[[1.0, 2.0], [2.0, 1.0]]])
    with pytest.raises(gm.MixtureFitError, match="positive definite"):
        gm.precision_cholesky(bad, "full")
    with pytest.raises(gm.MixtureFitError, match="positive"):
        gm.precision_cholesky(np.array([[1.0, 0.0]]), "diag")


def test_fit_mixture_keeps_the_mixture_of_least_criterion():
    data = dataset(8, 250, 3)
    w, means, covs = fit_mixture(data, 2, 6, "aic", "full", 1, 3)
    scores = {}
    for k in range(2, 7):
        m = gm.fit(data, k, np.random.default_rng((3, k)), "full")
        scores[k] = gm.information_criterion(data, m, "aic")
    best = min(scores, key=scores.get)
    assert len(w) == best
    m = gm.fit(data, best, np.random.default_rng((3, best)), "full")
    np.testing.assert_array_equal(means, m.means)
    np.testing.assert_array_equal(covs, m.covariances)


def test_more_initialisations_never_give_a_worse_likelihood():
    data = dataset(9, 250, 3)
    one = gm.fit(data, 6, np.random.default_rng(4), "full", inits=1)
    five = gm.fit(data, 6, np.random.default_rng(4), "full", inits=5)
    assert five.lower_bound >= one.lower_bound   # the first of the five is the one above
