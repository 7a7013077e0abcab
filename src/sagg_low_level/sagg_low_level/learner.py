"""Low-level learner with evolving context (paper Sec. 3.6, Algorithms 1 and 3) and the actuator
baselines (Sec. 3.8). ROS-free.

The learner is written as a coroutine: :meth:`EvolvingContextLearner.run` yields requests
(:class:`Observe`, :class:`Command`, :class:`GoalRequest`) and receives their answers. An in-process
driver answers from a simulator object and a :class:`~sagg_goal_generator.core.GoalGenerator`; the
learner node answers from ROS topics and a service. Since the algorithm only ever sees those
answers, both ways produce the same samples for the same seeds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Generator, Protocol

import numpy as np

from sagg_common.competence import competence_toward, gamma, is_reached
from sagg_common.params import GOAL_STRATEGIES, SHARED_SCHEMA, Param, Schema
from sagg_common.regions import RegionTree
from sagg_common.report_kinds import KIND_EXPLORATION, KIND_GOAL, KIND_REACHED, KIND_SUBGOAL
from sagg_common.rng import stream, uniform_in

from .compiled import jacobian, reach_step
from .learner_shared import (EPS_SIM, RIAC_SPLITTING, GoalRequest, Observe, ReportSource, riac_region, riac_tree,
                             task_space)
from .learner_shared import Report  # noqa: F401 (re-exported: the nodes and checkpoints import it from here)
from .local_model import desired_displacement, norm
from .memory import SampleMemory
from .prior import Prior, load_prior, neighbour_rows
from .riac_leaves import RiacLeaves

CONTEXT = Param(
    "context", "str", "evolving",
    "Which low level drives an arm: 'evolving' (Sec. 3: micro-actions Δα from the current posture, "
    "the reacher of this module, node 'learner') or 'fixed' (the arm driven like a synergy, Sec. 4.4 / "
    "Alg. 4: θ = absolute joint targets within the joint limits, each experiment one position command "
    "from the rest posture, outcome = the settled tip; node 'fixed_learner' with synergy.kind "
    "'posture'). `sagg experiment` / `sagg run` choose the learner and node from it.",
    choices=("evolving", "fixed"))

SCHEMA: Schema = SHARED_SCHEMA + (CONTEXT,) + (
    Param("v", "float", 2.0, "Desired effector speed, task units per micro-action (Sec. 3.6.1).",
          low=0.0, high=1e9, low_open=True),
    Param("q", "int", 20, "Number of exploratory micro-actions per exploration phase (Sec. 3.6.2).",
          low=1, high=100_000),
    Param("eps_max_ratio", "float", 0.5,
          "ε_max / v: an exploration phase starts when ||Δỹ − Δy_next|| > ε_max (Sec. 3.6.1). "
          "The paper gives no value; ours is half a step.", low=0.0, high=1e6, low_open=True),
    Param("subgoals", "int", 5,
          "l: number of points on the straight path y_i = y_start + (i/l)(y_g − y_start), "
          "i = 1..l; the last is the goal itself, so l − 1 are subgoals (Sec. 3.5). 1 = no subgoals.",
          low=1, high=10_000),
    Param("reset_every", "int", 1, "r: return to the rest posture every r reaching attempts (Sec. 2.4.5).",
          low=1, high=1_000_000_000),
    Param("timeout_factor", "float", 1.5,
          "Distance timeout (Sec. 3.6.2): a (sub)goal may use ceil(factor × D(y_start, y_g) / v) "
          "micro-actions, reaching and exploratory ones alike.", low=0.0, high=1e6, low_open=True),
    Param("timeout_scope", "str", "subgoal",
          "What one distance-timeout counter covers (Sec. 3.6.2: 'a counter is incremented for each "
          "micro-action and reset for each new goal'; vague on whether a subgoal is a new goal). "
          "'subgoal' (our choice): each subgoal and the goal get their own counter and budget "
          "ceil(timeout_factor × D(y_start, y_j) / v) from the effector's actual position when they "
          "start. 'goal': one counter per self-generated goal, budget "
          "ceil(timeout_factor × D(y_start, y_g) / v) from the attempt's start, shared by its "
          "subgoals; once spent, the remaining subgoals are reported unreached without moving.",
          choices=("subgoal", "goal")),
    Param("blocking_w", "int", 0,
          "Blocking timeout (Sec. 3.7.6): stop a (sub)goal after w consecutive exploration phases "
          "(no progress). 0 disables it; the paper uses w = 3 (with q = 5) for large Y. The fixed "
          "context's learner has the same key, counted per exploratory experiment and 3 by default: "
          "a config's value keeps its name but changes its unit under context=fixed.",
          low=0, high=1_000_000),
    Param("blocking_scope", "str", "goal",
          "What the blocking timeout ends. 'goal' (paper, Sec. 3.7.6: 'when w consecutive low-level "
          "explorations are triggered ... we declare a goal as unreached'): the whole attempt; its "
          "remaining subgoals are reported unreached without moving, as when a per-goal distance "
          "budget is spent. 'subgoal': only the current subgoal, the next one starts with a fresh "
          "counter, which lets a blocked attempt spend up to subgoals × w exploration phases.",
          choices=("goal", "subgoal")),
    Param("exploration_respects_timeout", "bool", True,
          "If true (paper) the distance timeout also counts exploratory micro-actions one by one and "
          "cuts an exploration phase short when the budget is spent: Sec. 3.6.2 'during both phases, "
          "a counter is incremented for each micro-action ... a maximal quantity of micro-actions is "
          "fixed for each goal ... allowed to perform up to 1.5 times the distance', Sec. 3.7.6 "
          "'(including explorative movements)'. If false, a started exploration phase always runs "
          "its q micro-actions and the timeout is checked after it (Alg. 1 read literally: the "
          "timeout is tested once per loop iteration)."),
    Param("neighbours", "int", 0,
          "k: nearest stored samples (in α) used for the local Jacobian (Sec. 3.3). 0 = 2 × joints. "
          "Not given in the paper.", low=0, high=100_000),
    Param("neighbour_checks", "int", 32,
          "Approximate nearest neighbours as in the paper (Sec. 3.3, FLANN 'Muja09'): a neighbour "
          "query scans at most this many index leaves (32 samples each) besides the newest samples, "
          "so its cost stays flat as the memory grows (FLANN's 'checks'). 0 = exact k nearest "
          "(cost grows with the memory). Default chosen with memory_bench / sagg bench speed, "
          "against the exact neighbours at 200k samples.",
          low=0, high=1_000_000),
    Param("min_samples", "int", 0,
          "Fewest stored samples before the learner tries the inverse model; with fewer it explores. "
          "0 = number of joints.", low=0, high=1_000_000),
    Param("prior.memory", "str", "",
          "A prior: the sample memory (.npz) of another run of this robot, e.g. a simulation (sagg run "
          "--prior sets it). Its samples are used by the local models beside the robot's own until robot "
          "samples supersede them (prior.radius; sagg_low_level/prior.py). '' = none. Not in the paper."),
    Param("prior.radius", "float", 0.0,
          "A prior sample is no longer used once a robot sample lies within this distance of it in α "
          "(rad). 0 = the largest exploratory micro-action, explore_amplitude × √joints (our choice: "
          "that close, the robot has probed the neighbourhood itself).", low=0.0, high=100.0),
    Param("explore_amplitude", "float", 0.05,
          "Exploratory micro-actions: Δα_i uniform in [−a, a] rad per joint around α (Sec. 3.6.2, "
          "'small random'; our choice). Also the step of ACTUATOR-RANDOM.", low=0.0, high=10.0,
          low_open=True),
    Param("max_joint_step", "float", 0.5,
          "Safety bound on |Δα_i| of any commanded micro-action (rad); larger steps are scaled down.",
          low=0.0, high=100.0, low_open=True),
    Param("jacobian_rcond", "float", 1e-10,
          "Relative cut-off of singular values of the neighbours' Δα matrix in the least-squares "
          "Jacobian (truncated SVD): directions the neighbours barely excite are left out instead of "
          "fitted to noise. Not in the paper.", low=0.0, high=1.0),
    Param("reach_noise", "float", 0.01,
          "Uniform noise ±a (rad) added to every reaching micro-action Δα = J⁺Δy_next. The paper "
          "bypasses singularities 'by adding noise in the joint configurations' (Sec. 3.3) without a "
          "value. Without it the neighbours' Δα collapse onto J⁺'s row space (every attempt starts "
          "at rest with r = 1), the least-squares Jacobian fits curvature along unexcited "
          "directions and reaching stalls (0 against 0.01 on the 15-DOF arm: "
          "docs/notes/early-results.md).",
          low=0.0, high=10.0),
    Param("reach_limits", "str", "clamp",
          "How a reaching micro-action respects the joint limits, in learning and in the evaluation's "
          "reaching from rest alike (one function, reach_step). 'clamp' (default): joint clamping "
          "with re-solving (Baerlocher & Boulic 2004, The Visual Computer 20(6); Flacco, De Luca & "
          "Khatib 2012, ICRA): every joint the step Δα = J⁺Δy_next would carry past a limit stops "
          "at the limit and the other joints are re-solved for the missing displacement, so a "
          "saturated joint no longer stalls the reach (docs/notes/reaching-joint-limits.md). 'clip': the paper's plain "
          "Δα = J⁺Δy_next (Sec. 3.3), clipped to the limits afterwards (a saturated joint stalls the "
          "reach: more test goals missed on config/arm7_ratio15.yaml, "
          "docs/notes/reaching-joint-limits.md).", choices=("clamp", "clip")),
    Param("reach_damping", "float", 0.0,
          "Damped least-squares reaching (the 'singularity-robust inverse' of Nakamura & Hanafusa "
          "1986 and Wampler 1986; local_model.damped_steps), in learning and in the evaluation's "
          "reaching alike: Δα = J^T (J J^T + λ² I)^{-1} Δy_next, the step minimising "
          "||J Δα − Δy_next||² + λ²||Δα||², with λ = reach_damping × v / (a √n) (a = "
          "explore_amplitude, n = joints). 0 (default) = the paper's Moore-Penrose J⁺ (Sec. 3.3, "
          "which bypasses singularities with noise). 1 = a joint motion as large as the largest "
          "exploratory micro-action (a per joint, norm a√n) costs as much as missing a full "
          "reaching step v: the damped solve then never moves the joints more than a√n/2 (before "
          "the joint limits' re-solve and the reach noise), the scale of the micro-actions the "
          "local model is fitted from, while where the arm moves its tip "
          "well (singular value ≫ λ) the step is J⁺'s. Needed near a singularity (the unfolded arm; "
          "a rest without net curl, arm.rest_shape zigzag), where J⁺ turns a small radial "
          "displacement into huge joint steps that commit the arm's curl before the goal's side "
          "can choose it (docs/notes/reaching-joint-limits.md). With damping, Inefficient (Sec. 3.6.1) measures ε "
          "against the model's prediction J·Δα of the damped step (learner.step_aim), not against "
          "the shortfall the damping chose.", low=0.0, high=1e6),
    Param("pinv_rcond", "float", 1e-2,
          "Relative cut-off of singular values in J⁺ (Sec. 3.3); paper: noise bypasses singularities.",
          low=0.0, high=1.0),
    Param("eps_c", "float", 0.1,
          "ε_C: a goal closer than this to the start has competence 0 (Sec. 3.5), task units "
          "(rescaled units when competence_rescale).", low=0.0, high=1e9),
    EPS_SIM,
    Param("competence_rescale", "bool", False,
          "Rescale each task dimension to [0, 1] by Y's extent before distances (Sec. 4.3)."),
    Param("actuator_reset_every", "int", 0,
          "max: ACTUATOR-* methods return to rest every max micro-actions (Sec. 3.8). 0 = derived as "
          "in the paper: micro-actions needed at speed v to reach the farthest point of Y from the "
          "rest position.", low=0, high=1_000_000_000),
    Param("riac.g_max", "int", 50, "ACTUATOR-RIAC: points per (α, Δα) region before a split.",
          low=2, high=1_000_000),
    *RIAC_SPLITTING,
    Param("riac.p_random", "float", 0.2,
          "ACTUATOR-RIAC: share of micro-actions drawn uniformly instead of by region interest.",
          low=0.0, high=1.0),
    Param("eval.goals", "int", 100, "Number of test goals (Sec. 3.7).", low=1, high=100_000),
    Param("eval.seed", "int", 0,
          "Seed of the test-goal set; independent of the run seed so every strategy and seed is "
          "scored on the same goals.", low=0),
    Param("eval.timeout_factor", "float", 5.0,
          "Evaluation budget: ceil(factor × D(y_rest, goal) / v) micro-actions per test goal "
          "(paper gives none; our choice: a budget that does not bind a reach still converging, "
          "for every strategy; sagg_low_level/eval_metrics.py, docs/notes/evaluation.md).",
          low=0.0, high=1e6, low_open=True),
    Param("eval.tolerance", "float", 0.01,
          "Evaluation stops early when the effector is this close to the test goal (task units).",
          low=0.0, high=1e9),
)


class MoveCheck(Protocol):
    """What the learner asks of a scene (:class:`sagg_common.scene.SceneChecker`): the refusal of
    the joint-space segment between two postures (an object with ``cause`` and ``detail``), or None."""

    def segment(self, alpha0: np.ndarray, alpha1: np.ndarray):
        """Whether the straight joint-space move may be sent.

        Parameters
        ----------
        alpha0, alpha1 : ndarray, shape (n,)
            The current posture and the one to command.

        Returns
        -------
        Refusal or None
            Why the move is refused (``cause``, ``detail``), or None.
        """


# --------------------------------------------------------------------------- coroutine protocol
@dataclass
class Command:
    """Request one position command. Answer: measured ``(alpha, y)`` once executed.

    ``kind`` is "reach", "explore", "babble" (micro-actions, each stored as one sample) or "reset"
    (return to rest; not a micro-action, nothing is stored)."""

    target: np.ndarray
    kind: str


@dataclass
class Robot:
    """What the learner knows of the robot: joint order, limits and rest posture."""

    joint_names: list[str]
    lower: np.ndarray
    upper: np.ndarray
    rest: np.ndarray

    def __post_init__(self):
        self.lower = np.asarray(self.lower, dtype=float)
        self.upper = np.asarray(self.upper, dtype=float)
        self.rest = np.asarray(self.rest, dtype=float)
        n = len(self.joint_names)
        for name in ("lower", "upper", "rest"):
            arr = getattr(self, name)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ValueError(f"robot {name}: got shape {arr.shape}; allowed: {n} finite values")
        if not np.all(self.upper > self.lower):
            raise ValueError("robot joint limits: every upper limit must exceed its lower limit")
        if np.any(self.rest < self.lower) or np.any(self.rest > self.upper):
            raise ValueError("robot rest posture: must lie within the joint limits")

    @property
    def n(self) -> int:
        return len(self.joint_names)


def subgoal_points(y_start: np.ndarray, goal: np.ndarray, l: int) -> list[np.ndarray]:
    """Subgoals on the straight path (paper Sec. 3.5): ``y_i = y_start + (i/l)(y_g − y_start)``,
    i = 1..l, so ``y_l = y_g``. (The paper omits ``y_start +``, a typo: its y_i must lie between
    y_start and y_g.)

    Parameters
    ----------
    y_start : ndarray, shape (m,)
        The effector's position when the attempt starts; m = task dimensions.
    goal : ndarray, shape (m,)
        The goal y_g.
    l : int
        Number of points, >= 1 (learner parameter ``subgoals``).

    Returns
    -------
    list of ndarray, length l
        The points y_1, ..., y_l, each of shape (m,); the last one is the goal's.
    """
    return [y_start + (i / l) * (goal - y_start) for i in range(1, l + 1)]


def timeout_budget(distance: float, v: float, factor: float) -> int:
    """Distance timeout of paper Sec. 3.6.2: up to ``factor`` (1.5) × the micro-actions needed to
    travel ``distance`` at speed ``v`` (at least one).

    Parameters
    ----------
    distance : float
        Distance to travel, D(y_start, y_g), task units.
    v : float
        Desired speed, task units per micro-action, > 0.
    factor : float
        Allowance factor (``timeout_factor``, or ``eval.timeout_factor`` for the evaluation).

    Returns
    -------
    int
        The most micro-actions allowed, >= 1.
    """
    return max(1, math.ceil(factor * distance / v))


def reach_damping(params: dict, n: int) -> float:
    """λ of the damped least-squares reaching inverse (learner parameter ``reach_damping``, in units
    of v / (a √n), a = explore_amplitude, n = joints): 0 = the paper's J⁺ (Sec. 3.3).

    Parameters
    ----------
    params : dict
        Learner parameters; reads ``reach_damping`` (0 when absent), ``v`` and
        ``explore_amplitude``.
    n : int
        Number of joints.

    Returns
    -------
    float
        λ >= 0, in task units per radian: it weighs ||Δα|| against ||J Δα − Δy|| (0: the paper's
        J⁺).
    """
    return float(params.get("reach_damping", 0.0)) * params["v"] / (params["explore_amplitude"] * math.sqrt(n))


def safe_target(alpha: np.ndarray, target: np.ndarray, max_step: float, robot: Robot) -> np.ndarray:
    """Clip a commanded posture to ``max_step`` per joint from ``alpha`` (the step is scaled down
    as a whole so its direction is kept) and to the robot's joint limits.

    Parameters
    ----------
    alpha : ndarray, shape (n,)
        The current joint posture α; n = joints.
    target : ndarray, shape (n,)
        The requested posture.
    max_step : float
        Largest joint motion per command, rad (e.g. ``max_joint_step``).
    robot : Robot
        Gives the joint limits ``lower`` and ``upper``.

    Returns
    -------
    ndarray, shape (n,)
        The posture to command: at most ``max_step`` from ``alpha`` in every joint, within the
        joint limits.
    """
    step = target - alpha
    big = float(np.abs(step).max()) if step.size else 0.0
    if big > max_step:
        step = step * (max_step / big)
    return np.minimum(np.maximum(alpha + step, robot.lower), robot.upper)


def step_toward(alpha: np.ndarray, target: np.ndarray, max_step: float, robot: Robot) -> np.ndarray:
    """``target`` clipped per joint to at most ``max_step`` from ``alpha`` and to the joint limits:
    the next command of a move done in steps (the return to rest on a real arm: one position
    command across the range is a jump at full speed on a position controller). It
    equals ``target`` once every joint is within a step of it.

    Parameters
    ----------
    alpha : ndarray, shape (n,)
        The current joint posture α; n = joints.
    target : ndarray, shape (n,)
        The requested posture.
    max_step : float
        Largest joint motion per command, rad (e.g. ``max_joint_step``).
    robot : Robot
        Gives the joint limits ``lower`` and ``upper``.

    Returns
    -------
    ndarray, shape (n,)
        The next command of the move.
    """
    return np.minimum(np.maximum(target, np.maximum(robot.lower, alpha - max_step)),
                      np.minimum(robot.upper, alpha + max_step))


def stepped_move_limit(robot: Robot, max_step: float) -> int:
    """The most commands a move in steps (:func:`step_toward`) may take: four times the steps
    across the widest joint range, at least 50; a joint that does not follow ends it there.

    Parameters
    ----------
    robot : Robot
        Gives the joint limits ``lower`` and ``upper``.
    max_step : float
        Largest joint motion per command, rad, > 0.

    Returns
    -------
    int
        The most commands of a move, >= 50.
    """
    span = float((np.asarray(robot.upper) - np.asarray(robot.lower)).max())
    return max(50, 4 * math.ceil(span / max_step))


class EvolvingContextLearner(ReportSource):
    """Low-level goal-directed exploration with evolving context (Alg. 3) + actuator baselines.

    Parameters
    ----------
    params : dict
        The learner's parameters by name (:data:`SCHEMA`), among them ``strategy``,
        ``task_space.lower`` and ``task_space.upper``.
    robot : Robot
        Joint order, limits and rest posture (n joints).
    task_dim : int, optional
        m, the task dimensions the robot reports; must equal the task space's (None: taken
        from it).
    memory : SampleMemory, optional
        The sample memory to use (e.g. a restored one); None: a new, empty one.

    Raises
    ------
    ValueError
        A context other than 'evolving', task-space bounds of unequal length or not increasing,
        or a ``task_dim`` other than the task space's.
    """

    def __init__(self, params: dict, robot: Robot, task_dim: int | None = None,
                 memory: SampleMemory | None = None):
        self.p = params
        self.robot = robot
        if params.get("context", "evolving") != "evolving":
            raise ValueError(f"context: got {params['context']!r}; allowed here: 'evolving' (the fixed "
                             "context is the FixedContextLearner, node fixed_learner)")
        self.strategy = params["strategy"]
        self.task_lower, self.task_upper, self.m = task_space(params, task_dim)
        n = robot.n
        self.memory = memory if memory is not None else SampleMemory(
            n, n, self.m, checks=params["neighbour_checks"])
        self.k = params["neighbours"] or 2 * n
        self.min_samples = params["min_samples"] or n
        self.v = params["v"]
        self.eps_max = params["eps_max_ratio"] * self.v
        self.damping = reach_damping(params, n)
        self.scale = (self.task_upper - self.task_lower) if params["competence_rescale"] else None
        self.rng = stream(params["seed"], "learner")
        self.alpha = robot.rest.copy()
        self.y = np.zeros(self.m)
        self.micro_actions = 0
        self.attempts = 0
        self._init_reports()
        self.goals_done = 0
        self.exploration_phases = 0
        self.on_sample: Callable[[int], None] | None = None
        self.riac_tree: RegionTree | None = None
        self._riac_table: RiacLeaves | None = None
        # the scene (sagg_common.scene): every micro-action's joint-space segment is checked before
        # it is requested; a refused one is not sent (counted per cause: ``refused``)
        self.scene: MoveCheck | None = None
        self.refused: dict[str, int] = {}
        self.on_refusal: Callable[[object], None] | None = None
        # another run's samples beside the robot's own (prior.memory; sagg_low_level.prior)
        self.prior: Prior | None = load_prior(params, n, self.m) if params.get("prior.memory") else None

    # ---------------------------------------------------------------- helpers
    def _report(self, kind, goal_seq, target, start, comp) -> None:
        self._emit_report(kind, goal_seq, target, self.y.copy(), np.array(start, dtype=float), comp,
                          self.micro_actions)

    def safe_target(self, target: np.ndarray) -> np.ndarray:
        """:func:`safe_target` from the current posture α with ``max_joint_step``: the posture
        actually commanded for ``target``.

        Parameters
        ----------
        target : ndarray, shape (n,)
            The requested posture; n = joints.

        Returns
        -------
        ndarray, shape (n,)
            The posture to command.
        """
        return safe_target(self.alpha, target, self.p["max_joint_step"], self.robot)

    def _act(self, target: np.ndarray, kind: str) -> Generator:
        """Execute one micro-action and store the sample (α, Δα, Δy). Returns Δy, or None when
        the scene refuses the move (:meth:`refuses`): nothing is sent, nothing stored, and the
        caller counts it as a failed move and picks another."""
        alpha0, y0 = self.alpha, self.y
        command = self.safe_target(target)
        if self.scene is not None and self.refuses(alpha0, command):
            return None
        alpha1, y1 = yield Command(command, kind)
        alpha1 = np.asarray(alpha1, dtype=float)
        y1 = np.asarray(y1, dtype=float)
        dy = y1 - y0
        idx = self.store(alpha0, alpha1 - alpha0, dy)
        self.alpha, self.y = alpha1, y1
        self.micro_actions += 1
        if self.on_sample is not None:
            self.on_sample(idx)
        return dy

    def store(self, alpha: np.ndarray, delta_alpha: np.ndarray, delta_y: np.ndarray) -> int:
        """Store one robot sample in the memory; with a prior, the prior samples it supersedes
        (:meth:`sagg_low_level.prior.Prior.cover`) are no longer used. Every path that adds the
        robot's samples to a learner (learning, a rebuilt memory) goes through here.

        Parameters
        ----------
        alpha, delta_alpha : ndarray, shape (n,)
        delta_y : ndarray, shape (m,)

        Returns
        -------
        int
            The sample's index in the memory.
        """
        idx = self.memory.add(alpha, delta_alpha, delta_y)
        if self.prior is not None:
            self.prior.cover(self.memory.alpha[idx])
        return idx

    def refuses(self, alpha0: np.ndarray, alpha1: np.ndarray) -> bool:
        """Whether the scene refuses the joint-space segment ``alpha0`` -> ``alpha1`` (a
        collision with itself, the floor or a box on the way or at the end): counted per cause in
        :attr:`refused`, handed to ``on_refusal``.

        Parameters
        ----------
        alpha0, alpha1 : ndarray, shape (n,)
            The current posture and the one to command.

        Returns
        -------
        bool
            True: the move must not be sent.
        """
        refusal = self.scene.segment(alpha0, alpha1)
        if refusal is None:
            return False
        self.count_refusal(refusal)
        return True

    def count_refusal(self, refusal) -> None:
        """Count one move the scene refused in :attr:`refused` and hand it to ``on_refusal``: the
        learner's own moves (:meth:`refuses`) and the ones its node checks for it.

        Parameters
        ----------
        refusal : Refusal
            Why the move was refused (``cause``, ``detail``: :class:`sagg_common.scene.Refusal`).
        """
        self.refused[refusal.cause] = self.refused.get(refusal.cause, 0) + 1
        if self.on_refusal is not None:
            self.on_refusal(refusal)

    def _reset(self) -> Generator:
        alpha, y = yield Command(self.robot.rest.copy(), "reset")
        self.alpha = np.asarray(alpha, dtype=float)
        self.y = np.asarray(y, dtype=float)

    def jacobian_at(self, alpha: np.ndarray) -> np.ndarray | None:
        """Local Jacobian J(α) from the k nearest samples in α (None while memory is too small):
        :func:`~sagg_low_level.local_model.local_jacobian` (Sec. 3.3), computed by the compiled
        :func:`~sagg_low_level.compiled.jacobian`.

        Parameters
        ----------
        alpha : ndarray, shape (n,)
            The posture α whose neighbours are used; n = joints.

        Returns
        -------
        ndarray, shape (m, n), or None
            J(α) (m = task dimensions); None with fewer than ``min_samples`` samples.
        """
        if self.model_samples() < self.min_samples:
            return None
        if self.prior is not None:
            da, dy, _ = neighbour_rows(self.memory, self.prior, alpha, self.k)
            return jacobian(da, dy, None, self.p["jacobian_rcond"])
        idx = self.memory.neighbours(alpha, self.k)
        return jacobian(self.memory.delta_alpha, self.memory.delta_y, idx, self.p["jacobian_rcond"])

    def model_samples(self) -> int:
        """The samples the local models are fitted from: the robot's, and the prior's still in use.

        Returns
        -------
        int
            ``len(memory)`` plus the prior samples not superseded (0 without a prior).
        """
        return len(self.memory) + (self.prior.live_count if self.prior is not None else 0)

    def inverse(self, alpha: np.ndarray, dy_next: np.ndarray) -> np.ndarray | None:
        """Δα = J⁺(α)·Δy_next from the local model (None while memory is too small):
        :func:`~sagg_low_level.local_model.pseudo_inverse_step`, compiled.

        Parameters
        ----------
        alpha : ndarray, shape (n,)
            The posture α; n = joints.
        dy_next : ndarray, shape (m,)
            Desired effector displacement Δy_next; m = task dimensions.

        Returns
        -------
        ndarray, shape (n,), or None
            Δα, without joint limits (the damped step when ``reach_damping`` > 0); None with fewer
            than ``min_samples`` samples.
        """
        jac = self.jacobian_at(alpha)
        return None if jac is None else reach_step(jac, dy_next, alpha, self.robot.lower, self.robot.upper,
                                                   self.p["pinv_rcond"], self.damping, False)

    def reach_step(self, alpha: np.ndarray, dy_next: np.ndarray) -> np.ndarray | None:
        """The reaching micro-action Δα for a desired effector displacement (Sec. 3.6.1), within
        the joint limits as ``reach_limits`` says; used by learning and by the evaluation's
        reaching from rest alike. None while the memory is too small.

        Parameters
        ----------
        alpha : ndarray, shape (n,)
            The posture α; n = joints.
        dy_next : ndarray, shape (m,)
            Desired effector displacement Δy_next; m = task dimensions.

        Returns
        -------
        ndarray, shape (n,), or None
            The micro-action Δα (before the reach noise); None with fewer than ``min_samples``
            samples.
        """
        return self.reach_plan(alpha, dy_next)[1]

    def reach_plan(self, alpha: np.ndarray, dy_next: np.ndarray) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(J(α), Δα) of :meth:`reach_step`: the local Jacobian the step was computed from, and
        the step; (None, None) while the memory is too small. The step is
        :func:`~sagg_low_level.local_model.clamped_step` ('clamp') or
        :func:`~sagg_low_level.local_model.pseudo_inverse_step` ('clip'), compiled
        (:func:`~sagg_low_level.compiled.reach_step`).

        Parameters
        ----------
        alpha : ndarray, shape (n,)
            The posture α; n = joints.
        dy_next : ndarray, shape (m,)
            Desired effector displacement Δy_next; m = task dimensions.

        Returns
        -------
        jac : ndarray, shape (m, n), or None
            The local Jacobian J(α).
        dalpha : ndarray, shape (n,), or None
            The micro-action Δα of :meth:`reach_step`.
        """
        jac = self.jacobian_at(alpha)
        if jac is None:
            return None, None
        return jac, reach_step(jac, dy_next, alpha, self.robot.lower, self.robot.upper, self.p["pinv_rcond"],
                               self.damping, self.p["reach_limits"] == "clamp")

    def step_aim(self, jac: np.ndarray, dalpha: np.ndarray, dy_next: np.ndarray) -> np.ndarray:
        """The effector displacement a reaching micro-action was computed to produce, against
        which Inefficient measures ε = ||Δỹ − aim|| (Sec. 3.6.1, Alg. 3). With the paper's J⁺
        (``reach_damping`` 0) it is Δy_next itself, the paper's formula. The damped inverse aims
        by design at less than Δy_next in the directions the arm barely moves its tip (its
        compromise with the joint motion): its aim is the model's own prediction J·Δα of the
        commanded step, so ε measures how wrong the model was, which is what the test is for
        ("judge if the current model has been efficient enough", Sec. 2, Alg. 2), not the
        shortfall the damping chose.

        Parameters
        ----------
        jac : ndarray, shape (m, n)
            The local Jacobian the step was computed from; m = task dimensions, n = joints.
        dalpha : ndarray, shape (n,)
            The step computed (before the reach noise).
        dy_next : ndarray, shape (m,)
            The desired effector displacement Δy_next.

        Returns
        -------
        ndarray, shape (m,)
            The aim: ``dy_next`` itself (J⁺), or ``jac @ dalpha`` (damped inverse).
        """
        return dy_next if self.damping == 0.0 else jac @ dalpha

    def predict(self, alpha: np.ndarray, dalpha: np.ndarray) -> np.ndarray:
        """Forward prediction Δy ≈ J(α)·Δα from the local model (zeros while memory is too small).

        Parameters
        ----------
        alpha : ndarray, shape (n,)
            The posture α; n = joints.
        dalpha : ndarray, shape (n,)
            The joint displacement Δα.

        Returns
        -------
        ndarray, shape (m,)
            The predicted effector displacement Δy; m = task dimensions.
        """
        jac = self.jacobian_at(alpha)
        return np.zeros(self.m) if jac is None else jac @ dalpha

    def _random_step(self) -> np.ndarray:
        a = self.p["explore_amplitude"]
        return self.rng.uniform(-a, a, self.robot.n)

    def competence_toward(self, target, start) -> Callable[[np.ndarray], float]:
        """``reached -> competence(target, reached, start)`` (Sec. 3.5, with this learner's eps_c and
        rescaling), the target's part computed once: for the micro-actions of one (sub)goal.

        Parameters
        ----------
        target : array_like, shape (m,)
            The (sub)goal; m = task dimensions.
        start : array_like, shape (m,)
            The effector's position when the (sub)goal started.

        Returns
        -------
        callable
            ``of(reached) -> float``: the competence C in [-1, 0] of an effector position of shape
            (m,).
        """
        return competence_toward(target, start, self.p["eps_c"], self.scale)

    # ------------------------------------------------------------- main loop
    def run(self) -> Generator:
        """The learner's whole life: yields requests, receives answers, never returns.

        Yields
        ------
        Observe, Command or GoalRequest
            The next request.

        Receives
        --------
        tuple
            The answer to the request just yielded: ``(alpha, y)``, the posture (n,) and the
            effector's position (m,), for :class:`Observe` and :class:`Command`; ``(goal_seq,
            goal)``, an int and a goal of shape (m,), for :class:`GoalRequest`.
        """
        alpha, y = yield Observe()
        self.alpha = np.asarray(alpha, dtype=float)
        self.y = np.asarray(y, dtype=float)
        if self.strategy in GOAL_STRATEGIES:
            if self.micro_actions and self.attempts % self.p["reset_every"]:
                # a resumed learner: its first motion is the return to rest from the posture measured
                # now (its first attempt would not start with one)
                yield from self._reset()
            while True:
                yield from self._sagg_attempt()
        else:
            yield from self._actuator_babbling(riac=self.strategy == "actuator-riac")

    def _explore(self, goal_seq: int, budget_left: int | None) -> Generator:
        """Exploration phase (Alg. 3, Sec. 3.6.2): q random Δα around the current α, each stored and
        reported; the context evolves with each. At most ``budget_left`` micro-actions when given
        (the distance timeout's counter, Sec. 3.6.2). Returns the number of micro-actions done."""
        self.exploration_phases += 1
        n = self.p["q"] if budget_left is None else max(0, min(self.p["q"], budget_left))
        for _ in range(n):  # (a move the scene refuses counts as one of the q: the next one is another)
            if (yield from self._act(self.alpha + self._random_step(), "explore")) is not None:
                self._report(KIND_EXPLORATION, goal_seq, self.y, self.y, 0.0)
        return n

    def _sagg_attempt(self) -> Generator:
        """One reaching attempt toward a self-generated goal (Alg. 1 inner loop, Alg. 3)."""
        if self.attempts % self.p["reset_every"] == 0:
            yield from self._reset()
        self.attempts += 1
        goal_seq, goal = yield GoalRequest(self.reports_sent)
        goal = np.asarray(goal, dtype=float)
        points = subgoal_points(self.y.copy(), goal, self.p["subgoals"])
        per_goal = self.p["timeout_scope"] == "goal"
        if per_goal:  # one counter for the whole attempt (see Param timeout_scope)
            budget = timeout_budget(norm(goal - self.y), self.v, self.p["timeout_factor"])
            used = 0
        blocked = False  # blocking_scope 'goal': the attempt was declared unreached (Sec. 3.7.6)
        for j, target in enumerate(points):
            kind = KIND_GOAL if j == len(points) - 1 else KIND_SUBGOAL
            start = self.y.copy()
            if not per_goal:
                budget = timeout_budget(norm(target - start), self.v, self.p["timeout_factor"])
                used = 0
            consecutive = 0
            competence_at = self.competence_toward(target, start)
            while True:
                c = competence_at(self.y)
                if blocked or is_reached(c, self.p["eps_sim"]) or used >= budget:
                    break
                if self.p["blocking_w"] and consecutive >= self.p["blocking_w"]:
                    blocked = self.p["blocking_scope"] == "goal"
                    break
                dy_next = desired_displacement(self.y, target, self.v)
                jac, dalpha = self.reach_plan(self.alpha, dy_next)
                need_explore = dalpha is None
                if dalpha is not None:
                    aim = self.step_aim(jac, dalpha, dy_next)
                    if self.p["reach_noise"] > 0:
                        a = self.p["reach_noise"]
                        dalpha = dalpha + self.rng.uniform(-a, a, self.robot.n)
                    dy = yield from self._act(self.alpha + dalpha, "reach")
                    used += 1  # (refused by the scene: a failed move, exploration picks others)
                    if dy is not None:
                        self._report(KIND_REACHED, goal_seq, self.y, self.y, 0.0)
                    need_explore = dy is None or norm(dy - aim) > self.eps_max
                if need_explore:
                    # the timeout counter runs through both phases (Sec. 3.6.2); with
                    # exploration_respects_timeout it may cut the phase short, and a phase that
                    # would get no micro-action is not started (the timeout ends the goal next)
                    left = budget - used if self.p["exploration_respects_timeout"] else None
                    if left is None or left > 0:
                        used += yield from self._explore(goal_seq, left)
                        consecutive += 1
                else:
                    consecutive = 0
            self._report(kind, goal_seq, target, start, gamma(competence_at(self.y), self.p["eps_sim"]))
        self.goals_done += 1

    def actuator_reset_period(self) -> int:
        """``max`` of Sec. 3.8: micro-actions to reach the farthest point of Y from the rest tip
        position at speed v (our reading of "the more distant reachable position"), unless set.

        Returns
        -------
        int
            Micro-actions between two returns to rest, >= 1: ``actuator_reset_every`` when it is
            not 0, else the one derived from Y's corners and the rest tip position (known once the
            babbling has started).
        """
        if self.p["actuator_reset_every"]:
            return self.p["actuator_reset_every"]
        corners = np.array(np.meshgrid(*zip(self.task_lower, self.task_upper))).reshape(self.m, -1).T
        far = float(np.max(np.linalg.norm(corners - self.rest_y, axis=1)))
        return max(1, math.ceil(far / self.v))

    def _actuator_babbling(self, riac: bool) -> Generator:
        """ACTUATOR-RANDOM (random Δα) and ACTUATOR-RIAC (Δα chosen by RIAC over (α, Δα)),
        both returning to rest every ``max`` micro-actions (Sec. 3.8). Apart from the fixed
        context's (Sec. 4.5) because the experiment differs: a micro-action from the current
        posture predicted as Δy, returns to rest, regions over (α, Δα) chosen by the current α."""
        yield from self._reset()
        self.rest_y = self.y.copy()
        period = self.actuator_reset_period()
        if riac and self.riac_tree is None:  # (a resumed learner has its checkpoint's tree)
            self.riac_tree = self.make_riac_tree()
        since_reset = 0
        while True:
            if since_reset >= period:
                yield from self._reset()
                since_reset = 0
            alpha0 = self.alpha
            dalpha = self._riac_choice() if riac else self._random_step()
            if riac:
                predicted = self.predict(alpha0, dalpha)
            dy = yield from self._act(alpha0 + dalpha, "babble")
            since_reset += 1
            if dy is None:
                continue  # (refused by the scene: another Δα next)
            if riac:
                # RIAC's value: minus the prediction error of Δy; interest = its progress
                actual_dalpha = self.memory.delta_alpha[len(self.memory) - 1]
                err = norm(dy - predicted)
                self._riac_leaves().add(np.concatenate([alpha0, np.clip(actual_dalpha, -self.p["explore_amplitude"],
                                                                        self.p["explore_amplitude"])]), -err)
                self.last_competence = -err
            self._report(KIND_EXPLORATION, 0, self.y, self.y, 0.0)

    def make_riac_tree(self) -> RegionTree:
        """ACTUATOR-RIAC's empty region tree over (α, Δα) (Sec. 3.8), with its own split stream.

        Returns
        -------
        RegionTree
            A tree over the 2n-dimensional box of (α, Δα): the joint limits × [−a, a]^n,
            a = ``explore_amplitude``; ``riac.g_max``, ``riac.zeta``, ``riac.split_candidates``.
        """
        a = self.p["explore_amplitude"]
        n = self.robot.n
        return riac_tree(self.p, np.concatenate([self.robot.lower, np.full(n, -a)]),
                         np.concatenate([self.robot.upper, np.full(n, a)]))

    def _riac_leaves(self) -> RiacLeaves:
        """The leaf table of the current RIAC tree (rebuilt when the tree was replaced, e.g. by a
        checkpoint restore); every point goes to the tree through it."""
        if self._riac_table is None or self._riac_table.tree is not self.riac_tree:
            self._riac_table = RiacLeaves(self.riac_tree, self.robot.n)
        return self._riac_table

    def _riac_choice(self) -> np.ndarray:
        """ACTUATOR-RIAC action choice: among leaves whose α-part contains the current α, pick one
        with probability ∝ interest − min (as SAGG-RIAC mode 1) and draw Δα uniformly in its Δα-part;
        with probability ``riac.p_random`` draw Δα uniformly. (The context α is not ours to choose,
        so the choice is restricted to compatible regions: our reading of RIAC for evolving context.)
        The compatible leaves come from the leaf table (:mod:`.riac_leaves`: arrays, the same leaves
        and order as a walk down the tree)."""
        region = riac_region(self.rng, self.p["riac.p_random"], self.riac_tree.leaves(),
                             lambda: self._riac_leaves().compatible(
                                 np.clip(self.alpha, self.robot.lower, self.robot.upper)))
        if region is None:
            return self._random_step()
        n = self.robot.n
        return uniform_in(self.rng, region.lower[n:], region.upper[n:])
