"""``alp-gmm``: goals from a Gaussian mixture over absolute learning progress. ROS-free.

Portelas, Colas, Hofmann & Oudeyer, "Teacher algorithms for curriculum learning of Deep RL in
continuously parameterized environments", CoRL 2019 (arXiv:1910.07224), Sec. 4.1 "ALP-GMM", and
its reference implementation (the ``ALPGMM`` teacher of flowersteam's teachDeepRL / TeachMyAgent,
``teachers/algos/alp_gmm.py``), whose defaults are the parameters' defaults here:

- every attempted goal gets an absolute learning progress (:func:`absolute_learning_progress`):
  its competence against that of the nearest earlier goal;
- every ``fit_every`` goals (after ``bootstrap`` uniform goals) mixtures of ``k_min..k_max``
  Gaussians are fitted over the last ``fit_every`` (goal, ALP) points and the one with the best
  information criterion is kept (:func:`fit_mixture`);
- a goal is uniform in Y with probability ``random_share``, else drawn from a component chosen in
  proportion to its mean ALP (:func:`component_probabilities`), without its ALP coordinate,
  clipped to Y.

Competence here is the paper's C in [-1, 0] (sagg_common.competence); the reference normalises
rewards to [0, 1] first: ALP is a difference, so the shift changes nothing. Only goal reports
(``KIND_GOAL``: an attempted goal and its competence) feed the teacher, as only sampled tasks feed
the reference's; reached points and exploration samples do not.

The mixtures are fitted by :mod:`.gaussian_mixture` (the EM of scikit-learn's ``GaussianMixture``,
which the reference uses, with all components in each step at once, much cheaper; why and how it is
checked against scikit-learn: that module's docstring). The chosen mixture is kept as plain arrays
(weights, means, covariances), so a checkpoint is arrays + JSON (no pickle) and a resumed teacher
draws exactly what an uninterrupted one draws. The k-means initialisations of a fit draw from a
generator seeded by an integer drawn from the named stream ``alp_gmm.fit`` (sagg_common.rng), one
per number of components, never a global RNG.
"""
from __future__ import annotations

import numpy as np

from sagg_common.journal import restore_rng, rng_state
from sagg_common.params import ConfigError, Param, Schema
from sagg_common.regions import proportional
from sagg_common.report_kinds import KIND_GOAL
from sagg_common.rng import choice_index, stream

from . import gaussian_mixture
from .compiled import em_kernel
from .teacher import Teacher
from .modes import MODE_GLOBAL, MODE_INITIAL, MODE_REGION

NAME = "alp-gmm"
P = "alp_gmm."

SCHEMA: Schema = (
    Param(P + "fit_every", "int", 250,
          "Goals between two fits of the mixture; each fit uses the last this many (goal, ALP) points "
          "(Portelas et al. 2019 Sec. 4.1; reference fit_rate = 250).", low=2, high=1_000_000),
    Param(P + "bootstrap", "int", 250,
          "Uniform goals before the first fit (reference nb_bootstrap, default fit_rate). At least "
          "fit_every.", low=2, high=1_000_000),
    Param(P + "k_min", "int", 2, "Fewest Gaussians tried at a fit (reference potential_ks = 2..10).",
          low=1, high=100),
    Param(P + "k_max", "int", 10, "Most Gaussians tried at a fit (reference potential_ks = 2..10). At "
          "most fit_every.", low=1, high=100),
    Param(P + "criterion", "str", "aic",
          "Information criterion that picks the number of Gaussians (reference gmm_fitness_func = "
          "'aic'; 'bic' offered).", choices=("aic", "bic")),
    Param(P + "covariance", "str", "full",
          "Covariance of each Gaussian (reference covariance_type = 'full'; 'diag' offered).",
          choices=("full", "diag")),
    Param(P + "em_inits", "int", 1, "EM initialisations per fit, the best kept (reference nb_em_init = 1).",
          low=1, high=100),
    Param(P + "em_tol", "float", 1e-3,
          "EM stops when the mean log-likelihood of the fitted points changes by less than this "
          "(the reference's GaussianMixture default, tol = 1e-3).", low=0.0, high=1e6, low_open=True),
    Param(P + "em_max_iter", "int", 100,
          "Most EM iterations per initialisation (the reference's GaussianMixture default, "
          "max_iter = 100).", low=1, high=100_000),
    Param(P + "reg_covar", "float", 1e-6,
          "Added to the diagonal of every covariance, keeping it positive definite (the reference's "
          "GaussianMixture default, reg_covar = 1e-6; in the units of the fitted points: Y's, or "
          "[0, 1] with unit_goals, and ALP's).", low=0.0, high=1e6, low_open=True),
    Param(P + "random_share", "float", 0.2,
          "Probability of a uniform goal in Y after the bootstrap (reference random_task_ratio = 0.2).",
          low=0.0, high=1.0),
    Param(P + "min_history", "int", 6,
          "A goal's ALP is 0 until at least this many earlier goals are in the history (reference: "
          "ALP computed once its dataset holds more than 5).", low=1, high=1_000_000),
    Param(P + "history", "int", 10000,
          "Earlier goals kept for the nearest-neighbour ALP, the oldest forgotten (the reference keeps "
          "all, alp_max_size = None; bounded here so a goal's cost is bounded; our choice).",
          low=1, high=1_000_000),
    Param(P + "unit_goals", "bool", False,
          "Nearest neighbours and the mixture in Y scaled to [0, 1] per dimension (true) or in Y's "
          "own units (false, as the reference, whose tasks are raw parameters). With Y in "
          "different units per dimension, true weighs them alike."),
)


def check_params(params: dict) -> None:
    """Cross-parameter checks (each parameter's own range is the schema's): ConfigError naming the
    parameter.

    Parameters
    ----------
    params : dict
        The generator's parameters by name (the ``alp_gmm.*`` ones are read).

    Raises
    ------
    ConfigError
        ``bootstrap`` < ``fit_every``, ``k_min`` > ``k_max``, or ``k_max`` > ``fit_every``.
    """
    if params[P + "bootstrap"] < params[P + "fit_every"]:
        raise ConfigError(f"{P}bootstrap: got {params[P + 'bootstrap']}; allowed: at least "
                         f"{P}fit_every ({params[P + 'fit_every']})")
    if params[P + "k_min"] > params[P + "k_max"]:
        raise ConfigError(f"{P}k_min: got {params[P + 'k_min']}; allowed: at most {P}k_max "
                         f"({params[P + 'k_max']})")
    if params[P + "k_max"] > params[P + "fit_every"]:
        raise ConfigError(f"{P}k_max: got {params[P + 'k_max']}; allowed: at most {P}fit_every "
                         f"({params[P + 'fit_every']}: a fit has that many points)")


def absolute_learning_progress(goal, competence: float, past_goals: np.ndarray, past_competences: np.ndarray,
                               min_history: int) -> float:
    """ALP of one attempted goal (Portelas et al. 2019, Sec. 4.1, "alp_new = |r_new - r_old|").

    ``r_old`` is the competence of the earlier goal nearest (Euclidean) to ``goal`` among
    ``past_goals`` (rows; ``past_competences`` theirs). 0 while fewer than ``min_history`` earlier
    goals are known (reference: ALP is computed once its dataset holds more than 5 tasks). Ties of
    distance: the first such row. The search is the compiled ``em_kernel.nearest`` (the row sums of
    squared differences in the same order as numpy's for goals of up to 4 dimensions, the first
    minimum: the same row; in numpy the search of a long history costs much more).

    Parameters
    ----------
    goal : array_like, shape (m,)
        The attempted goal, in the teacher's space (Y, or Y scaled to [0, 1] with
        ``unit_goals``); m = task dimensions.
    competence : float
        Its competence.
    past_goals : ndarray, shape (H, m)
        The H earlier goals kept, in the same space.
    past_competences : ndarray, shape (H,)
        Their competences.
    min_history : int
        Fewest earlier goals for a non-zero ALP.

    Returns
    -------
    float
        The ALP ``|competence − r_old|``, >= 0.
    """
    if len(past_goals) < min_history:
        return 0.0
    past, g = np.ascontiguousarray(past_goals, dtype=float), np.ascontiguousarray(goal, dtype=float)
    if past.shape[1] <= 4:
        nearest = em_kernel.nearest(past, g)
    else:  # einsum sums more terms in its own order: numpy's search, so that the row stays numpy's
        d = past - g
        nearest = int(np.argmin(np.einsum("ij,ij->i", d, d)))
    return abs(float(competence) - float(past_competences[nearest]))


def component_probabilities(alp_means: np.ndarray) -> np.ndarray:
    """Probability of choosing each Gaussian: proportional to its mean ALP (Portelas et al. 2019,
    Sec. 4.1; reference ``proportional_choice`` with eps = 0); uniform when every mean is 0. A mean
    below 0 (possible only numerically: ALP >= 0) counts as 0.

    Parameters
    ----------
    alp_means : array_like, shape (K,)
        Mean ALP of each of the K Gaussians (the last coordinate of their means).

    Returns
    -------
    ndarray, shape (K,)
        Probability of each Gaussian, summing to 1.
    """
    return proportional(np.clip(np.asarray(alp_means, float), 0.0, None))


def fit_mixture(data: np.ndarray, k_min: int, k_max: int, criterion: str, covariance: str, em_inits: int,
                random_state: int, tol: float = 1e-3, max_iter: int = 100,
                reg_covar: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit one Gaussian mixture per k in ``k_min..k_max`` to ``data`` (rows: goal then ALP) and keep
    the one of least ``criterion`` (AIC or BIC; Portelas et al. 2019 Sec. 4.1, reference: AIC).
    Returns (weights (k,), means (k, D), covariances (k, D, D), full matrices whatever the type).
    Each k's k-means initialisations draw from ``numpy.random.default_rng((random_state, k))``.

    Parameters
    ----------
    data : ndarray, shape (N, D)
        The N fitted points (rows: goal then ALP), D = m + 1 (m = task dimensions).
    k_min, k_max : int
        The numbers of Gaussians tried, ``1 <= k_min <= k_max <= N``.
    criterion : {'aic', 'bic'}
        Information criterion that picks the mixture.
    covariance : {'full', 'diag'}
        Covariance type of the Gaussians.
    em_inits : int
        EM initialisations per number of Gaussians, the best kept.
    random_state : int
        Seed of the k-means initialisations.
    tol : float, optional
        EM stops when the mean log-likelihood changes by less than this.
    max_iter : int, optional
        Most EM iterations per initialisation.
    reg_covar : float, optional
        Added to the diagonal of every covariance.

    Returns
    -------
    weights : ndarray, shape (K,)
        Mixture weights; K = the number of Gaussians kept.
    means : ndarray, shape (K, D)
        Their means.
    covariances : ndarray, shape (K, D, D)
        Their covariance matrices.

    Raises
    ------
    MixtureFitError
        A covariance is not positive definite (:mod:`.gaussian_mixture`).
    """
    best, best_score = None, np.inf
    for k in range(k_min, k_max + 1):
        m = gaussian_mixture.fit(data, k, np.random.default_rng((random_state, k)), covariance, em_inits,
                                 reg_covar, tol, max_iter)
        score = gaussian_mixture.information_criterion(data, m, criterion)
        if score < best_score:  # ties: the fewest Gaussians
            best, best_score = m, score
    return best.weights.copy(), best.means.copy(), np.array(best.full_covariances(), float)


def sampling_factor(cov: np.ndarray) -> np.ndarray:
    """The factor F with ``x = μ + z F``, z standard normal, of ``numpy.random.Generator.multivariate_normal``
    (its default ``method='svd'``: ``F = (U √S)ᵀ`` of the SVD of the covariance), computed once per
    fit instead of once per goal (the covariance changes only with a fit, so an SVD per draw is wasted).

    Parameters
    ----------
    cov : ndarray, shape (D, D)
        A covariance matrix (symmetric, positive semi-definite).

    Returns
    -------
    ndarray, shape (D, D)
        The factor F.
    """
    u, s, _ = np.linalg.svd(cov)
    return (u * np.sqrt(s)).T


def gaussian_draw(rng: np.random.Generator, mean: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """``rng.multivariate_normal(mean, cov)`` given ``factor = sampling_factor(cov)``: the same draw from
    the same stream, bit for bit (the same standard normals, the same product; test/test_teachers.py).

    Parameters
    ----------
    rng : numpy.random.Generator
        The stream drawn from (the generator's goal stream).
    mean : ndarray, shape (D,)
        Mean of the Gaussian.
    factor : ndarray, shape (D, D)
        :func:`sampling_factor` of its covariance.

    Returns
    -------
    ndarray, shape (D,)
        The draw.
    """
    x = np.dot(rng.standard_normal((1, len(mean))), factor)
    x += mean
    return x[0]


class AlpGmm(Teacher):
    """The ``alp-gmm`` teacher of a :class:`~sagg_goal_generator.core.GoalGenerator`: goal draws from
    the generator's goal stream, fit seeds from the stream ``alp_gmm.fit``.

    Parameters
    ----------
    gen : GoalGenerator
        The generator the teacher chooses goals for (its parameters hold the ``alp_gmm.*``
        ones).

    Raises
    ------
    ConfigError
        Inconsistent ``alp_gmm.*`` parameters (:func:`check_params`).
    """

    def __init__(self, gen):
        p = gen.params
        check_params(p)
        super().__init__(gen)
        self.p = {q.name[len(P):]: p[q.name] for q in SCHEMA}
        self.fit_rng = stream(p["seed"], "alp_gmm.fit")
        # the space of the nearest neighbours and the mixture: Y itself, or Y scaled to [0, 1]
        unit = self.p["unit_goals"]
        self.offset = gen.lower.copy() if unit else np.zeros(gen.dim)
        self.scale = (gen.upper - gen.lower) if unit else np.ones(gen.dim)
        d, h = gen.dim, self.p["history"]
        self.n = 0  # goal reports taken
        self.hist_goals = np.zeros((h, d))  # ring of the last `history` goals (scaled) ...
        self.hist_comp = np.zeros(h)        # ... and their competences
        self.fit_data = np.zeros((self.p["fit_every"], d + 1))  # ring of the last (goal, ALP) rows
        self.fits: list[dict] = []  # every fit (the last one draws goals; all: the report's "where goals went")
        self._factor_fit, self._factor_list = -1, []  # the sampling factors of fit number _factor_fit

    @property
    def mixture(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """The last fit's (weights, means, covariances); None before the first fit."""
        if not self.fits:
            return None
        f = self.fits[-1]
        return f["weights"], f["means"], f["covariances"]

    def _scaled(self, y) -> np.ndarray:
        return (np.asarray(y, float) - self.offset) / self.scale

    # ------------------------------------------------------------------ reports
    def report(self, kind: int, target, competence: float) -> None:
        """Take a goal report (the other kinds are ignored): the goal and its ALP against the nearest
        earlier goal join the history and the fit data; every ``fit_every`` goals from
        ``bootstrap`` on, a new mixture is fitted.

        Parameters
        ----------
        kind : int
            A ``KIND_*`` constant of :mod:`sagg_common.report_kinds` (goal, subgoal, reached,
            exploration).
        target : array_like, shape (m,)
            The goal or subgoal position (goal and subgoal reports), or the reached position
            (reached and exploration reports); m = task dimensions.
        competence : float
            Its competence (Γ for goals and subgoals; for the others, the learner's choice: see
            :meth:`~sagg_goal_generator.core.GoalGenerator.report`).
        """
        if kind != KIND_GOAL:
            return
        x = self._scaled(target)
        h = len(self.hist_comp)
        filled = min(self.n, h)
        alp = absolute_learning_progress(x, competence, self.hist_goals[:filled], self.hist_comp[:filled],
                                         self.p["min_history"])
        self.hist_goals[self.n % h] = x
        self.hist_comp[self.n % h] = competence
        self.fit_data[self.n % len(self.fit_data)] = np.append(x, alp)
        self.n += 1
        if self.n >= self.p["bootstrap"] and self.n % self.p["fit_every"] == 0:
            self._fit()

    def _fit(self) -> None:
        seed = int(self.fit_rng.integers(0, 2**31 - 1))
        p = self.p
        w, m, c = fit_mixture(self.fit_data, p["k_min"], p["k_max"], p["criterion"], p["covariance"],
                              p["em_inits"], seed, p["em_tol"], p["em_max_iter"], p["reg_covar"])
        self.fits.append({"goals": self.n, "weights": w, "means": m, "covariances": c})

    # -------------------------------------------------------------------- goals
    def choose(self) -> tuple[np.ndarray, int]:
        """The next goal (Portelas et al. 2019 Sec. 4.1): uniform in Y during the bootstrap (mode
        ``initial``), with probability ``random_share`` after it or while no mixture is fitted
        (``global``), else drawn from a Gaussian chosen by :func:`component_probabilities`,
        without its ALP coordinate, clipped to Y (``region``).

        Returns
        -------
        goal : ndarray, shape (m,)
            The goal, in Y (m = task dimensions).
        mode : int
            How it was chosen: a ``MODE_*`` constant of :mod:`~sagg_goal_generator.modes`.
        """
        gen, rng = self.gen, self.gen.rng
        if self.n < self.p["bootstrap"]:
            return gen.uniform(gen.lower, gen.upper), MODE_INITIAL
        if rng.random() < self.p["random_share"] or self.mixture is None:
            return gen.uniform(gen.lower, gen.upper), MODE_GLOBAL
        w, means, covs = self.mixture
        i = choice_index(rng, component_probabilities(means[:, -1]))
        x = gaussian_draw(rng, means[i], self._factors()[i])[:-1]
        return np.clip(self.offset + x * self.scale, gen.lower, gen.upper), MODE_REGION

    def _factors(self) -> list[np.ndarray]:
        """The last fit's sampling factors (:func:`sampling_factor` of each covariance), computed once
        per fit: derived from the state, not part of it."""
        if self._factor_fit != len(self.fits):
            self._factor_list = [sampling_factor(c) for c in self.mixture[2]]
            self._factor_fit = len(self.fits)
        return self._factor_list

    # -------------------------------------------------------------------- state
    def state(self) -> tuple[dict[str, np.ndarray], dict]:
        """Arrays (npz) and JSON of the teacher's state (the goal stream is the generator's).

        Returns
        -------
        arrays : dict of str to ndarray
            ``hist_goals`` (H, m) and ``hist_comp`` (H,), the history rings (H = ``history``);
            ``fit_data`` (F, m + 1), the ring of (goal, ALP) rows (F = ``fit_every``); per fit,
            ``fit_goals`` and ``fit_k`` (the goal count and number of Gaussians); the fits'
            Gaussians stacked, ``fit_weights`` (S,), ``fit_means`` (S, m + 1) and
            ``fit_covariances`` (S, m + 1, m + 1), S = the sum of ``fit_k``.
        meta : dict
            ``n`` (goal reports taken) and ``fit_rng`` (the fit stream's state).
        """
        f = self.fits
        arrays = {"hist_goals": self.hist_goals, "hist_comp": self.hist_comp, "fit_data": self.fit_data,
                  "fit_goals": np.array([x["goals"] for x in f], np.int64),
                  "fit_k": np.array([len(x["weights"]) for x in f], np.int64),
                  "fit_weights": np.concatenate([x["weights"] for x in f]) if f else np.zeros(0),
                  "fit_means": (np.concatenate([x["means"] for x in f]) if f
                                else np.zeros((0, self.gen.dim + 1))),
                  "fit_covariances": (np.concatenate([x["covariances"] for x in f]) if f
                                      else np.zeros((0, self.gen.dim + 1, self.gen.dim + 1)))}
        return arrays, {"n": self.n, "fit_rng": rng_state(self.fit_rng)}

    def restore(self, arrays: dict, meta: dict) -> None:
        """Set the state :meth:`state` returned (the sampling factors are recomputed at the next
        draw).

        Parameters
        ----------
        arrays : dict of str to ndarray
            The arrays of :meth:`state` (from the checkpoint's npz).
        meta : dict
            The JSON values of :meth:`state`.

        Raises
        ------
        ValueError
            A history or fit-data array whose shape is not this run's parameters'.
        """
        for key in ("hist_goals", "hist_comp", "fit_data"):
            if arrays[key].shape != getattr(self, key).shape:
                raise ValueError(f"alp-gmm checkpoint: {key} has shape {arrays[key].shape}; this run's "
                                 f"parameters give {getattr(self, key).shape}")
            setattr(self, key, np.array(arrays[key], float))
        self.n = int(meta["n"])
        restore_rng(self.fit_rng, meta["fit_rng"])
        self.fits, start = [], 0
        self._factor_fit = -1
        for n, k in zip(arrays["fit_goals"], arrays["fit_k"]):
            s = slice(start, start + int(k))
            self.fits.append({"goals": int(n), "weights": arrays["fit_weights"][s].copy(),
                              "means": arrays["fit_means"][s].copy(),
                              "covariances": arrays["fit_covariances"][s].copy()})
            start += int(k)

    def snapshot(self) -> dict:
        """JSON for the result: every fit's goal count, weights and means / covariances mapped back
        to Y units (last coordinate: ALP).

        Returns
        -------
        dict
            ``teacher`` (the name) and ``fits``: per fit, ``goals``, ``weights`` (K floats),
            ``means`` (K lists of m + 1) and ``covariances`` (K × (m + 1) × (m + 1) nested lists),
            in Y's units.
        """
        scale, shift = np.append(self.scale, 1.0), np.append(self.offset, 0.0)
        return {"teacher": NAME, "fits": [
            {"goals": f["goals"], "weights": f["weights"].tolist(),
             "means": (shift + f["means"] * scale).tolist(),
             "covariances": (f["covariances"] * np.outer(scale, scale)).tolist()} for f in self.fits]}
