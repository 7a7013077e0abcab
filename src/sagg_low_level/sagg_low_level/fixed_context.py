"""Low-level learner with a fixed (reset) context: motor synergies θ → outcome y (paper Sec. 4.4,
Algorithm 4 inside Algorithm 1; used for the quadruped, Sec. 4, and the fishing rod, Sec. 5). ROS-free.

Every experiment starts from the same rest state, runs the synergy π_θ and yields one outcome y
(or nothing: a fishing cast whose float never touches the water, which is discarded and counted).
Like :class:`~sagg_low_level.learner.EvolvingContextLearner`, the learner is a coroutine:
:meth:`FixedContextLearner.run` yields :class:`Observe` (answer: the rest outcome y_rest),
:class:`Execute` (answer: y, or None when the trial produced no outcome) and
:class:`~sagg_low_level.learner_shared.GoalRequest` (answer: ``(goal_seq, position)``). The in-process
driver answers from a simulator object, the synergy learner node from ROS topics, so both produce
the same samples for the same seeds.

Internally θ is normalised to [0, 1] per dimension by its bounds and, when ``competence_rescale``,
y is rescaled to [0, 1] per dimension by Y's extent (paper Sec. 4.3): neighbour searches, the local
model and the exploration noise all work in these units (our choice: amplitudes and phases, or u, v
and φ, have different units and must weigh the same, as the paper does for the competence).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Generator

import numpy as np

from sagg_common.competence import competence, competence_toward, gamma, is_reached
from sagg_common.params import GOAL_STRATEGIES, SHARED_SCHEMA, Param, Schema
from sagg_common.params import ConfigError
from sagg_common.regions import RegionTree
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED
from sagg_common.rng import stream, uniform_in
from sagg_common.synergy import PostureSynergy, SinusoidSynergy, VelocitySynergy

from .compiled import jacobian, pinv_step
from .learner_shared import (EPS_SIM, RIAC_SPLITTING, GoalRequest, Observe, ReportSource, riac_region, riac_tree,
                             task_space)
from .memory import SampleTable
from .memory_distance import squared_distances
from .riac_leaves import RiacLeaves
from .stored_knn import StoredKnn
from .tree_knn import TreeKnn

SCHEMA: Schema = SHARED_SCHEMA + (
    Param("l", "int", 10,
          "l: nearest neighbours of the goal in Y whose θ seed the candidate sets (Sec. 4.4.1). "
          "Not given in the paper; our choice.", low=1, high=10_000),
    Param("m", "int", 0,
          "m: nearest neighbours in θ of each of the l samples; the set of least θ spread is used for "
          "the local model (Sec. 4.4.1). The paper gives none. 0 = 2·(dim(θ) + 1): twice the "
          "parameters of the affine model per task dimension, so the least-squares fit is "
          "over-determined (with dim(θ) + 1 it interpolates the set exactly and its conditioning "
          "decides the step; docs/notes/fixed-context-speed.md).",
          low=0, high=100_000),
    Param("q", "int", 10,
          "q: budget of exploratory experiments per exploration phase (Alg. 4). Not given for the "
          "synergy setups; our choice.", low=1, high=100_000),
    Param("lambda", "float", 0.5,
          "λ > 0 of the exploration noise θ_c + λ·rand(n)·D(y_g, y_c) (Sec. 4.4.2), in normalised θ "
          "units per unit of D (explore_length). Not given in the paper; our choice.",
          low=0.0, high=1e6, low_open=True),
    Param("explore_length", "float", 0.0,
          "Length that D(y_g, y_c) is measured in for the exploration noise λ·rand(n)·D (Sec. 4.4.2). "
          "0 = the competence's units (Y's extent per dimension when competence_rescale, Sec. 4.3): "
          "the synergy set-ups. The fixed-context arm fills in its total length (the radius of its "
          "reachable set), so that λ is joint noise per arm length whatever box Y the goals are drawn "
          "from; in Y's units the same metric distance would give a different joint noise for each "
          "box Y (docs/notes/fixed-context-speed.md, finding 5).",
          low=0.0, high=1e9),
    Param("rounds", "int", 1,
          "Timeout of a goal: at most this many rounds of (one reaching experiment + an exploration "
          "phase when inefficient) per goal (Alg. 1 'timeout'; no value in the paper: ours 1).",
          low=1, high=10_000),
    Param("outcome_competence", "str", "goal",
          "Competence Γ recorded (when the generator's count_reached) at each outcome of a goal's "
          "experiments, reach and exploration: 'goal' (default, Alg. 4 read literally: 'Compute the "
          "competence Γ_{y_i}; UpdateRegions(R, y_i, Γ_{y_i}); if Γ_{y_i} > Γ_{y_k}' uses one Γ_{y_i} "
          "for the region update and for the comparison with the best experiment, which only means "
          "something as the competence of y_i toward the current goal, Sec. 2.4.1's Γ(C(y_g, y_i)); "
          "recorded at y_i) or 'maximal' (Sec. 2.5: 'we can consider y' as another goal reached "
          "with the highest level of competence', 0; with it a region inside the reachable area "
          "holds a window of zeros and its interest is 0, docs/notes/fixed-context-speed.md).",
          choices=("goal", "maximal")),
    Param("stop_when_reached", "bool", False,
          "True: end the exploration phase as soon as one of its experiments reaches the goal "
          "(C > ε_sim; Sec. 2.4.1 'a reaching attempt ... is considered terminated ... [when] the goal "
          "has effectively been reached'). False (default): Alg. 4 read literally, its FOR loop runs "
          "the q experiments and Alg. 2's 'while Γ ≤ ε_C' is tested after it returns (the rounds "
          "loop). Measured on config/arm7_ratio15.yaml: True stops refining at C > ε_sim = -0.05 "
          "(a few hundredths of the arm's length) and raised the 20k error of both SAGG strategies."),
    Param("blocking_w", "int", 3,
          "Blocking (Sec. 3.7.6) applied to Alg. 4's exploration: after w consecutive exploratory "
          "experiments that do not come closer to the goal than the best so far, the phase stops and "
          "the goal is declared unreached ('if the system is not coming closer to the goal even after "
          "some low-level explorations, the exploration toward this precise goal stops'). In the "
          "fixed context every experiment is a whole movement from rest toward the goal, so the "
          "count is per experiment. Default 3: the paper's value (w = 3, 'typically w >= 2'); Alg. 4 "
          "has no other timeout than its budget q. 0 disables it (Alg. 4 alone: always q). The "
          "evolving context's learner has the same key, counted per exploration phase of a reach "
          "(default 0 there).",
          low=0, high=100_000),
    Param("goal_competence", "str", "best",
          "Outcome the goal's competence Γ is computed from: 'best' (the closest outcome of the "
          "attempt, the θ_k Alg. 4 keeps) or 'last' (the last experiment). Vague in the paper.",
          choices=("best", "last")),
    Param("min_samples", "int", 0,
          "Fewest stored outcomes before the inverse model is used; before, reaching experiments draw "
          "θ uniformly (bootstrap, our choice). 0 = dim(θ) + 1.", low=0, high=1_000_000),
    Param("jacobian_rcond", "float", 1e-10,
          "Relative singular-value cut-off of the least-squares forward model on the chosen set.",
          low=0.0, high=1.0),
    Param("pinv_rcond", "float", 1e-2,
          "Relative singular-value cut-off of the pseudo-inverse (Sec. 3.3 reused in Sec. 4.4.1).",
          low=0.0, high=1.0),
    Param("eps_c", "float", 0.01,
          "ε_C: a goal closer than this to the rest outcome has competence 0 (rescaled units when "
          "competence_rescale).", low=0.0, high=1e9),
    EPS_SIM,
    Param("competence_rescale", "bool", True,
          "Rescale each task dimension to [0, 1] by Y's extent before distances (Sec. 4.3: u, v and "
          "φ have different units). The fixed-context arm defaults to false: its Y is metric in both "
          "dimensions and its competence is on plain distances (Sec. 3.5)."),
    Param("riac.g_max", "int", 30, "ACTUATOR-RIAC: points per θ region before a split.",
          low=2, high=1_000_000),
    *RIAC_SPLITTING,
    Param("riac.p_random", "float", 0.2,
          "ACTUATOR-RIAC: share of experiments with θ drawn uniformly instead of by region interest.",
          low=0.0, high=1.0),
    Param("riac.neighbours", "int", 0,
          "ACTUATOR-RIAC: nearest samples in θ of the local forward model that predicts y. "
          "0 = dim(θ) + 1.", low=0, high=100_000),
    Param("eval.goals", "int", 100, "Number of test goals (Sec. 4.6, 5.3).", low=1, high=100_000),
    Param("eval.seed", "int", 0,
          "Seed of the test-goal set; independent of the run seed.", low=0),
    Param("eval.pool", "int", 1000,
          "Synergy executions that estimate the reachable outcome set the test goals are picked "
          "from (the reachable area is unknown beforehand, Sec. 4.2; our choice).", low=1, high=10_000_000),
    Param("eval.pool_rounds", "int", 8,
          "Rounds of the reachable-outcome-set estimate the test goals are spread over "
          "(sagg_low_level.outcome_set: re-draw synergies from sparse outcome cells and perturb "
          "them); 0 = plain uniformly random synergies (where ACTUATOR-RANDOM samples).",
          low=0, high=1000),
)


# Synergy parameters: the learner turns θ into a joint trajectory, so it knows the synergy (the bridge
# only runs trajectories). Defaults = the simulated quadruped (sagg_sim_bridge.quadruped; the tests
# check they agree); config/fishing.yaml sets the fishing rod's.
QUADRUPED_JOINTS = [f"{leg}_{j}" for leg in ("fl", "fr", "hl", "hr") for j in ("hip_abd", "hip_flex", "knee")]
QUADRUPED_REST = [0.0, 0.35, -0.7, 0.0, 0.35, -0.7, 0.0, -0.35, 0.7, 0.0, -0.35, 0.7]

SYNERGY_SCHEMA: Schema = (
    Param("joints", "str_list", QUADRUPED_JOINTS,
          "Joint names of the synergy, in the order of the trajectory's joint_names."),
    Param("rest_posture", "float_list", QUADRUPED_REST,
          "Rest posture (rad), one per joint: the sinusoids' centre (synergy.kind 'sinusoid')."),
    Param("synergy.kind", "str", "sinusoid",
          "'sinusoid': θ = amplitudes + phases, joint i tracks rest_i + am_i·sin(ωt + ph_i) (Sec. 4.2); "
          "'velocity': θ ∈ [0,1]^n scaled to joint velocities tracked for synergy.duration, then stop "
          "(Sec. 5.1); 'posture': the arm in the fixed context (context = fixed): θ = absolute joint "
          "targets within joint_limits.*, one position command on /<controller>/commands after a "
          "return to rest_posture, outcome = the settled tip (PointStamped on task_topic).",
          choices=("sinusoid", "velocity", "posture")),
    Param("joint_limits.lower", "float_list", [-math.pi / 2] * 8,
          "Lower joint limits (rad), one per joint: the lower bounds of θ (synergy.kind 'posture')."),
    Param("joint_limits.upper", "float_list", [math.pi / 2] * 8,
          "Upper joint limits (rad), one per joint: the upper bounds of θ (synergy.kind 'posture')."),
    Param("synergy.omega", "float", 2 * math.pi,
          "ω (rad/s) of the sinusoids; fixed (Sec. 4.2; no value in the paper: ours 1 Hz).",
          low=0.0, high=1e4, low_open=True),
    Param("synergy.duration", "float", 3.0,
          "Duration (s) of one experiment's trajectory (Sec. 4.2: fixed, no value; Sec. 5.1: 2 s).",
          low=0.0, high=3600.0, low_open=True),
    Param("synergy.rate", "float", 50.0,
          "Trajectory points per second sent to the controller (our choice).", low=0.0, high=10_000.0,
          low_open=True),
    Param("synergy.amplitude_max", "float_list", [0.2, 0.5, 0.5] * 4,
          "Upper bound (rad) of each joint's amplitude am_i (lower bound 0); the paper gives none.",
          low=0.0, high=10.0),
    Param("synergy.velocity_lower", "float_list", [-1.5] * 4,
          "Joint velocity (rad/s) that θ_i = 0 stands for (synergy.kind 'velocity'; our choice).",
          low=-100.0, high=100.0),
    Param("synergy.velocity_upper", "float_list", [1.5] * 4,
          "Joint velocity (rad/s) that θ_i = 1 stands for (synergy.kind 'velocity'; our choice).",
          low=-100.0, high=100.0),
)



def synergy_from_params(p: dict):
    """The synergy (θ → trajectory) described by resolved SYNERGY_SCHEMA parameters."""
    n = len(p["joints"])
    if len(set(p["joints"])) != n:
        raise ConfigError(f"parameter 'joints': got {p['joints']!r}; allowed: distinct joint names")
    names = {"sinusoid": ("rest_posture", "synergy.amplitude_max"),
             "velocity": ("synergy.velocity_lower", "synergy.velocity_upper"),
             "posture": ("rest_posture", "joint_limits.lower", "joint_limits.upper")}[p["synergy.kind"]]
    for name in names:
        if len(p[name]) != n:
            raise ConfigError(f"parameter '{name}': got {len(p[name])} values; allowed: one per joint ({n})")
    try:
        if p["synergy.kind"] == "posture":
            return PostureSynergy(p["joints"], p["joint_limits.lower"], p["joint_limits.upper"], p["rest_posture"])
        if p["synergy.kind"] == "sinusoid":
            return SinusoidSynergy(p["joints"], p["rest_posture"], p["synergy.amplitude_max"],
                                   p["synergy.omega"], p["synergy.duration"], p["synergy.rate"])
        return VelocitySynergy(p["joints"], p["synergy.velocity_lower"], p["synergy.velocity_upper"],
                               p["synergy.duration"], p["synergy.rate"])
    except ValueError as exc:
        raise ConfigError(f"parameter {exc}") from exc


@dataclass
class Execute:
    """Request one experiment: run synergy θ from the rest state. Answer: the outcome y, or None
    when the trial has no outcome (e.g. the float never touched the water). ``kind`` is "reach",
    "explore" or "babble"."""

    theta: np.ndarray
    kind: str


@dataclass
class ThetaSpace:
    """What the learner knows of the synergy: the bounds of θ (the driver knows the rest)."""

    lower: np.ndarray
    upper: np.ndarray

    def __post_init__(self):
        self.lower = np.asarray(self.lower, dtype=float)
        self.upper = np.asarray(self.upper, dtype=float)
        if self.lower.shape != self.upper.shape or self.lower.ndim != 1 or not len(self.lower):
            raise ValueError("theta bounds: lower and upper must be equal-length non-empty vectors")
        if not (np.all(np.isfinite(self.lower)) and np.all(np.isfinite(self.upper))
                and np.all(self.upper > self.lower)):
            raise ValueError("theta bounds: allowed: finite, every upper > lower")

    @property
    def n(self) -> int:
        return len(self.lower)


def set_spread(theta_norm: np.ndarray) -> float:
    """σ(M_j) of Sec. 4.4.1: the standard deviation of the synergy parameters of a neighbour set.
    The paper does not say how the std of vectors is taken; ours: the RMS over dimensions of the
    per-dimension standard deviations (normalised θ), i.e. the RMS distance to the set's mean / √n:
    ``np.sqrt(np.mean(np.var(theta_norm, axis=0)))``, computed by :func:`set_spreads` (one set)."""
    return float(set_spreads(np.asarray(theta_norm, dtype=float)[None])[0])


def least_spread_set(candidate_sets: list[np.ndarray] | np.ndarray, theta_norm: np.ndarray) -> int:
    """``M_k = argmin_i σ(M_i)`` (Sec. 4.4.1, equation M_k); ties: the first (closest goal neighbour).
    ``candidate_sets``: index arrays, or one 2-D array of equal-sized sets by row."""
    if not isinstance(candidate_sets, np.ndarray) and len({len(s) for s in candidate_sets}) != 1:
        return int(np.argmin([set_spread(theta_norm[s]) for s in candidate_sets]))
    # equal-sized sets (always, in the learner): all spreads in one call; the same sums in the same
    # order as set_spread per set (numpy reduces a non-last axis row after row)
    return int(np.argmin(set_spreads(theta_norm[np.asarray(candidate_sets)])))


def set_spreads(stacked: np.ndarray) -> np.ndarray:
    """``np.sqrt(np.mean(np.var(stacked, axis=1), axis=1))`` for sets stacked (l, m, n): σ(M_i) of
    every set, bit for bit (the same reductions numpy's var and mean make, without their
    wrappers' overhead; tested in test/test_fixed_context.py)."""
    m, n = stacked.shape[1], stacked.shape[2]
    mean = np.add.reduce(stacked, axis=1, keepdims=True)
    mean /= m
    x = stacked - mean
    np.square(x, out=x)
    var = np.add.reduce(x, axis=1)
    var /= m
    ms = np.add.reduce(var, axis=1)
    ms /= n
    return np.sqrt(ms)


def local_inverse(theta_norm: np.ndarray, y_scaled: np.ndarray, goal: np.ndarray,
                  jacobian_rcond: float, pinv_rcond: float) -> np.ndarray:
    """Local linear inverse model on the chosen set M_k (Sec. 4.4.1, "estimate a local linear inverse
    model ((u,v,φ) → θ) by using a pseudo-inverse as introduced in the reaching experiment").

    Fits the forward model ``Δy = J Δθ`` by least squares on the set's deviations from its means
    (:func:`~sagg_low_level.local_model.local_jacobian`), then ``θ_g = θ_r + J⁺ (y_g − y_r)`` from the
    set member r whose outcome is closest to the goal (our choice of linearisation point; eq.
    jacobianPseudo of Sec. 3.3, :func:`~sagg_low_level.local_model.pseudo_inverse_step`); both
    computed by the compiled routines of :mod:`sagg_low_level.compiled`. Normalised θ, rescaled y
    in, normalised θ out (unclipped)."""
    dth = theta_norm - _mean_rows(theta_norm)
    dy = y_scaled - _mean_rows(y_scaled)
    jac = jacobian(dth, dy, None, jacobian_rcond)
    r = int(np.argmin(np.add.reduce((y_scaled - goal) ** 2, axis=1)))
    return theta_norm[r] + pinv_step(jac, goal - y_scaled[r], pinv_rcond)


def _mean_rows(x: np.ndarray) -> np.ndarray:
    """``x.mean(axis=0)`` of a 2-D array, bit for bit (numpy's mean: the sum, divided by the count)."""
    s = np.add.reduce(x, axis=0)
    s /= len(x)
    return s


def exploration_theta(theta_c: np.ndarray, distance: float, lam: float,
                      rng: np.random.Generator) -> np.ndarray:
    """Exploration around the closest reached outcome (Sec. 4.4.2, equation θ_{t+1}):
    ``θ_{t+1} = θ_c + λ · rand(n) · D(y_g, y_c)`` with rand in [−1, 1]^n; normalised θ (unclipped)."""
    return theta_c + lam * rng.uniform(-1.0, 1.0, theta_c.shape) * distance


@dataclass
class _Attempt:
    """What one goal attempt of :class:`FixedContextLearner` has found so far: the goal, its scaled
    form ``g``, the competence toward it (``comp``), the best outcome (by distance to the goal)
    and the last, and whether the blocking test stopped it."""

    goal_seq: int
    goal: np.ndarray
    g: np.ndarray
    comp: Callable
    best_y: np.ndarray | None = None
    best_c: float | None = None
    d_best: float = math.inf
    last_y: np.ndarray | None = None
    last_c: float | None = None
    blocked: bool = False

    def seen(self, y: np.ndarray, c: float, d: float) -> None:
        """An outcome ``y`` of competence ``c`` at distance ``d`` from the goal: the last, and the
        best when closer than every earlier one."""
        self.last_y, self.last_c = y, c
        if self.best_y is None or d < self.d_best:
            self.best_y, self.best_c, self.d_best = y, c, d


class FixedContextLearner(ReportSource):
    """Goal-directed optimisation of synergies with a fixed context (Alg. 1 + Alg. 4) and the
    ACTUATOR-RANDOM / ACTUATOR-RIAC baselines over θ."""

    def __init__(self, params: dict, theta_space: ThetaSpace, task_dim: int | None = None):
        self.p = params
        self.space = theta_space
        self.strategy = params["strategy"]
        self.task_lower, self.task_upper, self.mdim = task_space(params, task_dim)
        n = theta_space.n
        self.scale = (self.task_upper - self.task_lower) if params["competence_rescale"] else np.ones(self.mdim)
        self.l_nb = params["l"]
        self.m_nb = params["m"] or 2 * (n + 1)
        self.min_samples = params["min_samples"] or n + 1
        # two memories of the same samples (same insertion order, so index i is one experiment):
        # by normalised θ (m-neighbour sets, ACTUATOR-RIAC's forward model) and by rescaled y
        # (l neighbours of the goal, closest reached outcome y_c); searched exactly (SampleMemory's
        # exact k-NN answers) by a tree index suited to these few dimensions
        self.by_theta = SampleTable(n, n, self.mdim)
        self.by_y = SampleTable(self.mdim, n, self.mdim)
        self.theta_index = TreeKnn(self.by_theta)
        self.y_index = TreeKnn(self.by_y)
        # the θ-neighbour sets of stored samples (the seeds of Sec. 4.4.1), the same answers as
        # theta_index, kept from one reach to the next (a seed is mostly an earlier seed)
        self.theta_sets = StoredKnn(self.theta_index)
        self._span = theta_space.upper - theta_space.lower
        self.last_norm_theta: np.ndarray | None = None  # normalised θ of the newest sample
        self.rng = stream(params["seed"], "fixed_context_learner")
        self.y_rest = np.zeros(self.mdim)
        self.experiments = 0       # stored experiments (with an outcome): the learning clock
        self.trials = 0            # every executed experiment, discarded ones included
        self.discarded = 0         # experiments without an outcome (not stored)
        self._init_reports()
        self.goals_done = 0
        self.exploration_phases = 0
        self.goals_reached = 0     # goals whose best outcome reached them (C > ε_sim)
        self.goals_blocked = 0     # goals not reached and stopped by the blocking test (blocking_w)
        self.on_sample: Callable[[int], None] | None = None
        self.riac_tree: RegionTree | None = None

    # ------------------------------------------------------------------ units
    def norm_theta(self, theta) -> np.ndarray:
        return (np.asarray(theta, dtype=float) - self.space.lower) / self._span

    def denorm_theta(self, theta_norm) -> np.ndarray:
        t = np.clip(np.asarray(theta_norm, dtype=float), 0.0, 1.0)
        return self.space.lower + t * self._span

    def scale_y(self, y) -> np.ndarray:
        return np.asarray(y, dtype=float) / self.scale

    def distance(self, a, b) -> float:
        """D(a, b) in the competence metric (rescaled per dimension when competence_rescale)."""
        d = (np.asarray(a, dtype=float) - np.asarray(b, dtype=float)) / self.scale
        return math.sqrt(float(d @ d))

    # --------------------------------------------------------------- memory
    def __len__(self) -> int:
        return len(self.by_theta)

    @property
    def memory_bytes(self) -> int:
        """Bytes held by the two sample memories and their search indexes."""
        return int(self.by_theta.nbytes + self.by_y.nbytes + self.theta_index.nbytes + self.y_index.nbytes
                   + self.theta_sets.nbytes)

    @property
    def thetas(self) -> np.ndarray:
        """Stored synergies θ (raw units), in experiment order."""
        return self.by_theta.delta_alpha

    @property
    def outcomes(self) -> np.ndarray:
        """Stored outcomes y (task units), in experiment order."""
        return self.by_theta.delta_y

    def add_sample(self, theta, y) -> int:
        """Store one experiment (θ, y) in the memory M (Alg. 1: 'update M and M⁻¹')."""
        theta = np.asarray(theta, dtype=float)
        y = np.asarray(y, dtype=float)
        self.last_norm_theta = self.norm_theta(theta)  # = by_theta.alpha[i] (read-only to callers)
        i = self.by_theta.add(self.last_norm_theta, theta, y)
        self.by_y.add(self.scale_y(y), theta, y)
        return i

    def closest(self, goal) -> int | None:
        """Index of the stored outcome y_c closest to ``goal`` (None while the memory is empty)."""
        if not len(self):
            return None
        return int(self.y_index.query(self.scale_y(goal)[None], 1)[0, 0])

    def inverse(self, goal) -> np.ndarray | None:
        """Reaching phase (Sec. 4.4.1): θ_g from the local inverse model on the neighbour set of least
        θ spread; None while the memory holds fewer than min_samples outcomes."""
        if len(self) < self.min_samples:
            return None
        g = self.scale_y(goal)
        return self._inverse_from(g, self.y_index.query(g[None], self.l_nb)[0])

    def _inverse_from(self, g: np.ndarray, seeds: np.ndarray) -> np.ndarray:
        """:meth:`inverse` for the rescaled goal ``g`` given L, its l nearest outcomes ``seeds``."""
        tn = self.by_theta.alpha                                        # normalised θ of every sample
        sets = self.theta_sets.query(seeds, self.m_nb)                  # M_i: m neighbours in θ, by row
        best = sets[least_spread_set(sets, tn)]
        ys = self.by_y.alpha[best]
        return self.denorm_theta(local_inverse(tn[best], ys, g, self.p["jacobian_rcond"],
                                               self.p["pinv_rcond"]))

    def _closer(self, g: np.ndarray, c: int, j: int) -> int:
        """Of stored outcomes c < j, the one closer to the rescaled goal ``g`` in the memory's
        canonical distance, ties to the older: ``closest`` after sample j was added, when c was the
        closest before (the 1-nearest of all = the nearer of the old 1-nearest and the new one)."""
        d = squared_distances(self.by_y.alpha[[c, j]], g)
        return j if d[1] < d[0] else c

    def predict(self, theta) -> np.ndarray | None:
        """Forward prediction of y at θ from the local linear model of the nearest samples in θ
        (ACTUATOR-RIAC's predictor; task units); None while the memory is too small."""
        k = self.p["riac.neighbours"] or self.space.n + 1
        if len(self) < 2:
            return None
        tq = self.norm_theta(theta)
        idx = self.theta_index.query(tq[None], k)[0]
        tn = self.by_theta.alpha[idx]
        ys = self.by_y.alpha[idx]
        jac = jacobian(tn - tn.mean(axis=0), ys - ys.mean(axis=0), None, self.p["jacobian_rcond"])
        return (ys[0] + jac @ (tq - tn[0])) * self.scale

    # ------------------------------------------------------------- helpers
    def _report(self, kind, goal_seq, target, comp, y) -> None:
        self._emit_report(kind, goal_seq, target, np.array(y, dtype=float), self.y_rest.copy(), comp,
                          self.experiments)

    def _execute(self, theta, kind: str) -> Generator:
        """Run one experiment, store it when it has an outcome. Returns y or None."""
        theta = np.clip(np.asarray(theta, dtype=float), self.space.lower, self.space.upper)
        y = yield Execute(theta, kind)
        self.trials += 1
        if y is None:
            self.discarded += 1
            return None
        y = np.asarray(y, dtype=float)
        if y.shape != (self.mdim,) or not np.all(np.isfinite(y)):
            self.discarded += 1
            return None
        idx = self.add_sample(theta, y)
        self.experiments += 1
        if self.on_sample is not None:
            self.on_sample(idx)
        return y

    def _uniform_theta(self) -> np.ndarray:
        return uniform_in(self.rng, self.space.lower, self.space.upper)

    def competence_of(self, goal, y) -> float:
        return competence(goal, y, self.y_rest, self.p["eps_c"], self.scale if self.p["competence_rescale"] else None)

    def competence_toward(self, goal) -> Callable[[np.ndarray], float]:
        """``y -> competence_of(goal, y)`` (the same floats), for the outcomes of one goal."""
        return competence_toward(goal, self.y_rest, self.p["eps_c"],
                                 self.scale if self.p["competence_rescale"] else None)

    # ------------------------------------------------------------ main loop
    def run(self) -> Generator:
        """The learner's whole life: yields requests, receives answers, never returns."""
        y_rest = yield Observe()
        self.y_rest = np.asarray(y_rest, dtype=float)
        if self.strategy in GOAL_STRATEGIES:
            while True:
                yield from self._goal_attempt()
        else:
            yield from self._actuator_babbling(riac=self.strategy == "actuator-riac")

    def explore_distance(self, goal, y) -> float:
        """D(y_g, y) of the exploration noise (Sec. 4.4.2) in the unit ``explore_length`` (0: the
        competence's units, :meth:`distance`)."""
        length = self.p["explore_length"]
        if length <= 0:
            return self.distance(goal, y)
        d = np.asarray(goal, dtype=float) - np.asarray(y, dtype=float)
        return math.sqrt(float(d @ d)) / length

    def outcome_gamma(self, c: float) -> float:
        """Γ recorded at an outcome whose competence toward the current goal is ``c`` (parameter
        ``outcome_competence``): Γ(c) of Sec. 2.4.1 (Alg. 4's Γ_{y_i}), or 0 (Sec. 2.5)."""
        if self.p["outcome_competence"] == "maximal":
            return 0.0
        return gamma(c, self.p["eps_sim"])

    def _goal_attempt(self) -> Generator:
        """One goal (Alg. 1 inner loop with Alg. 4): reach with the inverse model
        (:meth:`_reach_round`); when that does not come closer than the closest known outcome
        (Inefficient, Sec. 4.4.2), explore q synergies around the best θ with noise ∝ its distance
        to the goal, keeping the best (:meth:`_explore_round`). The attempt ends early when an
        experiment reaches the goal (``stop_when_reached``) or after ``blocking_w`` consecutive
        experiments without progress (Sec. 3.7.6; the goal is then unreached)."""
        goal_seq, goal = yield GoalRequest(self.reports_sent)
        goal = np.asarray(goal, dtype=float)
        at = _Attempt(goal_seq, goal, self.scale_y(goal), self.competence_toward(goal))
        eps_sim = self.p["eps_sim"]
        for _ in range(self.p["rounds"]):
            y, d_y, c_before, d_before = yield from self._reach_round(at)
            if y is not None and is_reached(at.last_c, eps_sim):
                break
            # Inefficient(M⁻¹, ỹ_j, y_j): the reach did not beat the closest known outcome
            if y is not None and d_y <= d_before:
                continue
            yield from self._explore_round(at, None if y is None else c_before)
            if at.blocked or (at.best_y is not None and is_reached(at.best_c, eps_sim)):
                break
        self._end_attempt(at)

    def _reach_round(self, at: "_Attempt") -> Generator:
        """One reach toward the goal with the inverse model (Sec. 4.4.1): θ from the l nearest
        outcomes' local inverse (uniform while the memory is small), executed and reported.
        Returns (y or None, D(y_g, y), index of the closest known outcome before it or None, its
        distance to the goal)."""
        # y_c, the closest known outcome (its index), and θ from the inverse model; L's first
        # member is y_c (same search, same order)
        if len(self) >= self.min_samples:
            seeds = self.y_index.query(at.g[None], self.l_nb)[0]
            c_before = int(seeds[0])
            theta = self._inverse_from(at.g, seeds)
        else:
            c_before = self.closest(at.goal)
            theta = self._uniform_theta()
        d_before = math.inf if c_before is None else self.distance(at.goal, self.outcomes[c_before])
        y = yield from self._execute(theta, "reach")
        d_y = math.inf
        if y is not None:
            c_y = at.comp(y)
            d_y = self.distance(at.goal, y)
            at.seen(y, c_y, d_y)
            self._report(KIND_REACHED, at.goal_seq, y, self.outcome_gamma(c_y), y)
        return y, d_y, c_before, d_before

    def _explore_round(self, at: "_Attempt", c_before: int | None) -> Generator:
        """One exploration phase (Sec. 4.4.2): q synergies around the best experiment k so far
        (``c_before``: the closest known outcome before the reach, None when the reach gave no
        outcome or nothing was stored), each with noise ∝ the best outcome's distance to the goal,
        the best kept; stops early when reached (``stop_when_reached``) or blocked (``at.blocked``)."""
        goal, eps_sim, w = at.goal, self.p["eps_sim"], self.p["blocking_w"]
        self.exploration_phases += 1
        k = self.closest(goal) if c_before is None else self._closer(at.g, c_before, len(self) - 1)
        # the best experiment k so far: its normalised θ (= norm_theta(thetas[k]), as stored), y_k,
        # D(y_g, y_k) and the exploration distance D of Sec. 4.4.2
        if k is None:  # nothing stored yet: bootstrap with uniform draws
            tn_k, y_k, d_k = None, None, math.inf
        else:
            tn_k, y_k = self.by_theta.alpha[k].copy(), self.outcomes[k].copy()
            d_k, e_k = self.distance(goal, y_k), self.explore_distance(goal, y_k)
        idle = 0  # consecutive exploratory experiments without progress (blocking, Sec. 3.7.6)
        for _ in range(self.p["q"]):
            if tn_k is None:
                theta_i = self._uniform_theta()
            else:
                theta_i = self.denorm_theta(exploration_theta(tn_k, e_k, self.p["lambda"], self.rng))
            y_i = yield from self._execute(theta_i, "explore")
            if y_i is None:
                continue
            c_i = at.comp(y_i)
            self._report(KIND_EXPLORATION, at.goal_seq, y_i, self.outcome_gamma(c_i), y_i)
            d_i = self.distance(goal, y_i)
            if y_k is None or d_i < d_k:
                tn_k, y_k, d_k = self.last_norm_theta, y_i, d_i
                e_k = self.explore_distance(goal, y_k)
                idle = 0
            else:
                idle += 1
            at.seen(y_i, c_i, d_i)
            if self.p["stop_when_reached"] and is_reached(c_i, eps_sim):
                return
            if w and idle >= w:
                at.blocked = True
                return

    def _end_attempt(self, at: "_Attempt") -> None:
        """The goal's own report (Alg. 1: competence of the best or the last outcome, the rest
        outcome when the attempt had none) and the attempt's statistics: reached, else blocked,
        else its budget (q, rounds) ran out."""
        eps_sim = self.p["eps_sim"]
        final, c = (at.best_y, at.best_c) if self.p["goal_competence"] == "best" else (at.last_y, at.last_c)
        if final is None:  # no outcome at all in this attempt: the rest outcome stands in
            final = self.y_rest
            c = at.comp(final)
        self._report(KIND_GOAL, at.goal_seq, at.goal, gamma(c, eps_sim), final)
        self.goals_done += 1
        reached = at.best_y is not None and is_reached(at.best_c, eps_sim)
        self.goals_reached += reached
        self.goals_blocked += at.blocked and not reached

    def _actuator_babbling(self, riac: bool) -> Generator:
        """ACTUATOR-RANDOM (θ uniform in its bounds) and ACTUATOR-RIAC (θ regions of the normalised
        synergy space chosen by the progress of the prediction error of y, as RIAC; Sec. 4.5).
        Apart from the evolving context's (Sec. 3.8) because the experiment differs: a whole
        synergy from rest predicted as y, no return to rest to schedule, regions over θ alone."""
        n = self.space.n
        if riac:
            self.riac_tree = riac_tree(self.p, np.zeros(n), np.ones(n))
            self.riac_leaves = RiacLeaves(self.riac_tree, 0)  # every point goes through it
        while True:
            if riac:
                theta = self._riac_choice()
                predicted = self.predict(theta)
            else:
                theta = self._uniform_theta()
            y = yield from self._execute(theta, "babble")
            if y is None:
                continue
            if riac:
                # RIAC's value: minus the prediction error of y (rescaled units); interest = its progress
                err = self.distance(y, self.y_rest if predicted is None else predicted)
                self.riac_leaves.add(np.clip(self.norm_theta(theta), 0.0, 1.0), -err)
                self.last_competence = -err
            self._report(KIND_EXPLORATION, 0, y, 0.0, y)

    def _riac_choice(self) -> np.ndarray:
        """ACTUATOR-RIAC: a leaf with probability ∝ interest − min (as SAGG-RIAC mode 1), θ uniform in
        it; with probability ``riac.p_random`` (or while there is one leaf) θ uniform."""
        # every leaf is a candidate (θ has no context); interests() = [r.interest for r in leaves]
        region = riac_region(self.rng, self.p["riac.p_random"], self.riac_tree.leaves(),
                             lambda: (None, self.riac_leaves.interests()))
        if region is None:
            return self._uniform_theta()
        return self.denorm_theta(uniform_in(self.rng, region.lower, region.upper))


class Driver:
    """Steps a :class:`FixedContextLearner` in-process: answers its requests from callables.

    ``execute(theta, kind)`` runs one experiment and returns y or None; ``next_goal()`` returns
    ``(goal_seq, position)``; ``y_rest`` is the rest outcome. The learner node answers the same
    requests from ROS topics instead."""

    def __init__(self, learner: FixedContextLearner, execute, next_goal, y_rest):
        self.learner = learner
        self.execute = execute
        self.next_goal = next_goal
        self._coro = learner.run()
        self._pending = self._coro.send(None)
        self._answer(np.asarray(y_rest, dtype=float))

    def _answer(self, answer) -> None:
        self._pending = self._coro.send(answer)

    def step_until(self, experiments: int) -> None:
        """Advance until the learner has stored ``experiments`` experiments in total."""
        while self.learner.experiments < experiments:
            req = self._pending
            if isinstance(req, Execute):
                self._answer(self.execute(req.theta, req.kind))
            elif isinstance(req, GoalRequest):
                self._answer(self.next_goal())
            else:  # pragma: no cover - protocol error
                raise TypeError(f"unknown learner request {req!r}")


def evaluate_fixed(learner: FixedContextLearner, run_theta: Callable[[np.ndarray], np.ndarray | None],
                   goals: np.ndarray) -> np.ndarray:
    """Test errors of the frozen model (Sec. 4.6, 5.3): for each test goal one synergy θ_g from the
    reaching phase (no exploration, no learning), run from rest; error = Euclidean distance in task
    units between goal and outcome. A trial without outcome (no water contact) scores the distance
    to the rest outcome (our choice: as if nothing happened). Before the model exists (too few
    samples) the score is the distance to the rest outcome too."""
    out = []
    for g in np.asarray(goals, dtype=float):
        theta = learner.inverse(g)
        y = None if theta is None else run_theta(theta)
        if y is None:
            y = learner.y_rest
        out.append(float(np.linalg.norm(g - np.asarray(y, dtype=float))))
    return np.array(out)


def spread_goals(outcomes: np.ndarray, n: int, rng: np.random.Generator, lower, upper,
                 bins: int = 8) -> np.ndarray:
    """``n`` test goals spread approximately uniformly over the reached part of Y: the outcomes are
    binned on a grid of ``bins`` cells per dimension over their bounding box; goals are drawn cell by
    cell (occupied cells in random order, round robin), one random outcome of the cell each time, so
    rarely reached areas weigh as much as common ones (Sec. 4.6: 'covering approximately uniformly
    the reachable part of the task space'). Outcomes outside Y are ignored."""
    pts = np.asarray(outcomes, dtype=float)
    lower = np.asarray(lower, dtype=float)
    upper = np.asarray(upper, dtype=float)
    pts = pts[np.all((pts >= lower) & (pts <= upper), axis=1)]
    if len(pts) == 0:
        raise ValueError("eval.pool: no outcome inside the task space to build test goals from")
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    cells = np.minimum((bins * (pts - lo) / span).astype(int), bins - 1)
    keys = np.ravel_multi_index(cells.T, (bins,) * pts.shape[1])
    groups = [np.flatnonzero(keys == k) for k in np.unique(keys)]
    order = rng.permutation(len(groups))
    chosen = []
    used = [set() for _ in groups]
    while len(chosen) < n:
        progressed = False
        for gi in order:
            free = [i for i in groups[gi] if i not in used[gi]]
            if not free:
                continue
            i = int(free[int(rng.integers(len(free)))])
            used[gi].add(i)
            chosen.append(i)
            progressed = True
            if len(chosen) == n:
                break
        if not progressed:  # fewer distinct outcomes than n: reuse
            chosen.extend(int(i) for i in rng.integers(0, len(pts), n - len(chosen)))
    return pts[np.array(chosen)]
