"""In-process fixed-context experiments (quadruped Sec. 4, fishing rod Sec. 5, and the arm in the
fixed context): the goal generator, the fixed-context learner (Alg. 4) and a simulator wired together
without ROS (``sagg experiment`` with a config whose ``setup`` is ``quadruped`` or ``fishing``, or an
arm config with the learner parameter ``context: fixed``). Writes the same ``result.json`` keys as
the arm's :func:`~sagg_bringup.inprocess.experiment.run_experiment` (``micro_actions`` counts experiments, i.e.
executions with an outcome) plus a ``synergy`` section (trials, discarded trials, outcomes).

What differs between the set-ups is one small adapter (:class:`SynergySetup`, :class:`ArmPostureSetup`):
how θ is executed on the simulator and the outcome read, the test goals, and the reachable area.
"""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.params import ConfigError, is_given, read_config, resolve_nodes
from sagg_common.progress import Progress
from sagg_common.rng import stream, substream_seed
from sagg_common.synergy import transported_outcome
from sagg_goal_generator.core import SCHEMA as GEN_SCHEMA, GoalGenerator
from sagg_low_level.eval_metrics import frame_summary, metric_frame
from sagg_low_level.fixed_context import (SCHEMA as FC_SCHEMA, Driver, FixedContextLearner, ThetaSpace,
                                          spread_goals, synergy_from_params)
from sagg_low_level.fixed_eval_batch import evaluate_fixed_batch
from sagg_low_level.learner import SCHEMA as EVOLVING_SCHEMA
from sagg_low_level.outcome_set import reachable_outcomes
from sagg_low_level.schema import FIXED_LEARNER_SCHEMA as LEARNER_SCHEMA
from sagg_sim_bridge.arms import (arm_base_point, arm_reach, arm_reachable_area, arm_spec_from_params,
                                  arm_test_goals, make_arm_sim)
from sagg_sim_bridge.params import SCHEMA as ARM_SCHEMA
from sagg_sim_bridge.schema import SYNERGY_BRIDGE_SCHEMA as SYN_BRIDGE_SCHEMA
from sagg_sim_bridge.synergy_params import make_sim

from .phases import PhaseCounter, coverage
from .arm_config import absolute_model_paths
from .results import learning_curve, result_dict, run_overrides, write_result

ARM_FIXED = "arm-fixed"  # the set-up name of the arm in the fixed context (context: fixed)


def fixed_arm_learner_schema(node_schema=LEARNER_SCHEMA):
    """The learner schema of the arm in the fixed context: the fixed-context learner node's, with the
    arm's hardware-contract defaults (controller ``forward_position_controller``, task topic
    ``/tip_position``, synergy.kind 'posture') and its metric task space (competence_rescale false;
    :meth:`ArmPostureSetup.resolve` sets explore_length to the arm's length)."""
    arm = {"controller": "forward_position_controller", "task_topic": "/tip_position",
           "synergy.kind": "posture", "context": "fixed",
           # the arm's Y is metric in both dimensions: its competence is on plain distances (Sec. 3.5;
           # Sec. 4.3 rescales because u, v and φ have different units) and the arm configs give
           # ε_C in task units
           "competence_rescale": False}
    return tuple(dataclasses.replace(p, default=arm[p.name]) if p.name in arm else p for p in node_schema)


def load_fixed_config(path: str | Path, overrides: dict[str, Any] | None, adapter,
                        learner_schema=LEARNER_SCHEMA, bridge_schema=None) -> dict[str, dict]:
    """Resolve the three nodes' parameters of a fixed-context config (+ overrides applied to every
    node) for the set-up adapter ``adapter`` (:class:`SynergySetup` or :class:`ArmPostureSetup`,
    named by the set-up registry); ``bridge_schema`` None = the simulator's core schema."""
    out = adapter.resolve(path, overrides, learner_schema, bridge_schema)
    synergy_from_params(out["sagg_learner"])  # validates the synergy, naming the bad parameter
    return out


class BoxArea:
    """The bounding box of the test pool's outcomes: our estimate of the reachable part of Y (the
    paper's red outlines, Sec. 4.5), for the goal-share statistics."""

    def __init__(self, outcomes: np.ndarray, lower, upper):
        self.lower_y, self.upper_y = np.asarray(lower, float), np.asarray(upper, float)
        self.lo, self.hi = outcomes.min(axis=0), outcomes.max(axis=0)

    def contains(self, points: np.ndarray) -> np.ndarray:
        p = np.asarray(points, dtype=float)
        return np.all((p >= self.lo) & (p <= self.hi), axis=1)

    def share(self) -> float:
        return float(np.prod((self.hi - self.lo) / (self.upper_y - self.lower_y)))


_POOLS: dict[str, np.ndarray] = {}


class SynergySetup:
    """Quadruped / fishing rod: θ → a joint trajectory run by the synergy simulator from its rest state
    (the synergy bridge's ``on_trajectory``); test goals spread over an estimate of the reachable
    outcome set (:mod:`sagg_low_level.outcome_set`)."""

    @staticmethod
    def resolve(path, overrides, learner_schema, bridge_schema) -> dict[str, dict]:
        """The config's parameters (the synergy bridge's core schema unless ``bridge_schema``)."""
        return resolve_nodes(path, {"sagg_goal_generator": GEN_SCHEMA, "sagg_learner": learner_schema,
                                    "sagg_sim_bridge": bridge_schema or SYN_BRIDGE_SCHEMA}, overrides)

    def __init__(self, config: dict[str, dict]):
        lp, bp = config["sagg_learner"], config["sagg_sim_bridge"]
        self.config = config
        self.name = bp["setup"]
        self.sim = make_sim(bp)
        self.eval_sim = make_sim(bp)
        self.synergy = synergy_from_params(lp)
        if sorted(self.synergy.joint_names) != sorted(self.sim.joint_names):
            raise ConfigError(f"parameter 'joints': got {self.synergy.joint_names}; allowed: the "
                              f"{bp['setup']}'s joints {list(self.sim.joint_names)}")
        self.task_dim = self.sim.task_dim
        self.rest_outcome = self.sim.rest_outcome
        self.metric_base = self.rest_outcome  # distance bands of the evaluation (eval_metrics)

    def execute(self, theta):
        # exactly what the learner node receives from the bridge (φ through the PoseStamped quaternion)
        return transported_outcome(self.sim.execute(self.synergy.trajectory(theta)))

    def evaluator(self):
        """θ → outcome on the evaluation simulator (deterministic: one for the whole run)."""
        return lambda theta: transported_outcome(self.eval_sim.execute(self.synergy.trajectory(theta)))

    def test_pool(self) -> np.ndarray:
        """``eval.pool`` synergy executions spread over the reachable outcome set by
        :func:`sagg_low_level.outcome_set.reachable_outcomes` (``eval.pool_rounds`` rounds; 0 = plain
        uniformly random synergies), seeded by eval.seed, no-contact trials dropped: the estimate of
        the reachable outcome set the test goals are picked from (and the goal-share box). The same
        for every strategy and seed of a set-up: kept for the next run in this process."""
        lp = self.config["sagg_learner"]
        key = json.dumps([self.config["sagg_sim_bridge"], {k: v for k, v in lp.items()
                                                           if k not in ("seed", "strategy")}],
                         sort_keys=True, default=str)
        if key in _POOLS:
            return _POOLS[key].copy()
        rng = stream(lp["eval.seed"], "synergy_test_pool")
        pool = reachable_outcomes(self.evaluator(), self.synergy.lower, self.synergy.upper,
                                  lp["eval.pool"], lp["eval.pool_rounds"], rng)
        if not len(pool):
            raise ConfigError("eval.pool: no synergy of the test pool produced an outcome")
        if len(_POOLS) >= 4:
            _POOLS.pop(next(iter(_POOLS)))
        _POOLS[key] = pool.copy()
        return pool

    def test_goals(self):
        """(test goals, reachable-area estimate, extra result keys): goals spread cell by cell over
        :meth:`test_pool`."""
        lp = self.config["sagg_learner"]
        pool = self.test_pool()
        goals = spread_goals(pool, lp["eval.goals"], stream(lp["eval.seed"], "synergy_test_goals"),
                             lp["task_space.lower"], lp["task_space.upper"])
        area = BoxArea(pool, lp["task_space.lower"], lp["task_space.upper"])
        return goals, area, {"pool_outcomes": len(pool), "pool_extents": outcome_extents(pool)}


def posture_outcome(sim, rest: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """One experiment of the arm in the fixed context, as the MuJoCo bridge runs it from the synergy
    learner's two position commands: back to the rest posture, then θ; the settled tip."""
    sim.command(rest)
    return sim.command(theta)[1]


class ArmPostureSetup:
    """The arm in the fixed context (``context: fixed``): θ = absolute joint targets within the joint
    limits, one position command from the rest posture (:func:`posture_outcome`) on the same
    ``ArmSim(spec, substream_seed(seed, "sim"))`` as the evolving arm and the MuJoCo bridge; test
    goals and reachable area = the evolving arm's of the same config (``test_goals`` over
    ``reachable_area``), each reached by ONE experiment θ_g of the frozen inverse model from rest
    (:func:`~sagg_low_level.fixed_context.evaluate_fixed`; the evaluation of Sec. 4.6, one
    experiment per goal, on a fresh evaluation arm as the evolving arm's evaluation)."""

    name = ARM_FIXED

    @staticmethod
    def resolve(path, overrides, learner_schema, bridge_schema) -> dict[str, dict]:
        """The arm bridge's parameters and the learner's with :func:`fixed_arm_learner_schema`; the
        evolving learner's own parameters (v, subgoals, ...) are accepted there and dropped (unused
        in the fixed context); ``joints``, ``joint_limits.*`` and ``rest_posture`` come from the
        simulated arm."""
        fixed = fixed_arm_learner_schema(learner_schema)
        names = {p.name for p in fixed}
        tolerated = tuple(p for p in EVOLVING_SCHEMA if p.name not in names)
        out = resolve_nodes(path, {"sagg_goal_generator": GEN_SCHEMA, "sagg_learner": fixed + tolerated,
                                   "sagg_sim_bridge": bridge_schema or ARM_SCHEMA}, overrides)
        lp = out["sagg_learner"] = {k: v for k, v in out["sagg_learner"].items() if k in names}
        absolute_model_paths(out["sagg_sim_bridge"], Path(path).resolve().parent)
        spec = arm_spec_from_params(out["sagg_sim_bridge"])
        lower, upper = spec.limits()
        lp.update({"joints": spec.joint_names(), "joint_limits.lower": lower.tolist(),
                   "joint_limits.upper": upper.tolist(), "rest_posture": spec.rest_posture().tolist(),
                   "synergy.kind": "posture"})
        # the exploration noise per arm length (Param explore_length), unless the config or an
        # override gives explore_length (0 included: the competence's units)
        if not is_given(read_config(path), "sagg_learner", "explore_length", overrides):
            lp["explore_length"] = arm_reach(spec)
        return out

    def __init__(self, config: dict[str, dict]):
        lp, bp = config["sagg_learner"], config["sagg_sim_bridge"]
        self.config = config
        self.spec = arm_spec_from_params(bp)
        self.seed = lp["seed"]
        self.sim = make_arm_sim(self.spec, seed=substream_seed(self.seed, "sim"))
        self.synergy = synergy_from_params(lp)
        if self.synergy.joint_names != list(self.sim.joint_names):
            raise ConfigError(f"parameter 'joints': got {self.synergy.joint_names}; allowed: the arm's "
                              f"joints {list(self.sim.joint_names)}")
        self.rest = self.sim.rest.copy()
        self.task_dim = self.sim.task_dim
        self.rest_outcome = self.sim.command(self.rest)[1]  # the node's Observe: a rest command
        self.metric_base = arm_base_point(self.spec)  # the arm's base, as the evolving arm's evaluation

    def execute(self, theta):
        return posture_outcome(self.sim, self.rest, self.synergy.command(theta))

    def evaluator(self):
        sim = make_arm_sim(self.spec, seed=substream_seed(self.seed, "eval_sim"))
        return lambda theta: posture_outcome(sim, self.rest, self.synergy.command(theta))

    def test_goals(self):
        lp = self.config["sagg_learner"]
        lower, upper = np.asarray(lp["task_space.lower"]), np.asarray(lp["task_space.upper"])
        area = arm_reachable_area(self.spec, lower, upper, seed=lp["eval.seed"])
        goals = arm_test_goals(self.spec, lower, upper, n=lp["eval.goals"], seed=lp["eval.seed"], area=area)
        return goals, area, {}


class FixedRun:
    """A fixed-context learning run of one strategy and seed (synergy set-up or the arm in the fixed
    context), stepped in-process; ``adapter``: the set-up's class (:class:`SynergySetup`,
    :class:`ArmPostureSetup`), named by the set-up registry."""

    def __init__(self, config: dict[str, dict], adapter):
        self.config = config
        gp, lp = config["sagg_goal_generator"], config["sagg_learner"]
        self.seed = lp["seed"]
        self.setup = adapter(config)
        self.synergy = self.setup.synergy
        if len(lp["task_space.lower"]) != self.setup.task_dim:
            raise ConfigError(f"parameter 'task_space.lower': {len(lp['task_space.lower'])} dimensions; "
                              f"allowed: {self.setup.task_dim} for the {self.setup.name}")
        core = {p.name: lp[p.name] for p in FC_SCHEMA}
        self.generator = GoalGenerator(gp)
        self.learner = FixedContextLearner(core, ThetaSpace(self.synergy.lower, self.synergy.upper),
                                           self.setup.task_dim)
        self.learner.on_report = self._on_report
        self.goal_micro_actions: dict[int, int] = {}
        self.phases = PhaseCounter()  # experiments by kind (reach / explore / babble), per goal
        self.driver = Driver(self.learner, self._execute, self._next_goal, self.setup.rest_outcome)
        self.learn_seconds = 0.0

    def _on_report(self, r) -> None:
        self.generator.report(r.kind, r.target, r.competence)

    def _execute(self, theta, kind):
        self.phases.command(kind)
        return self.setup.execute(theta)

    def _next_goal(self):
        g = self.generator.next_goal()
        self.goal_micro_actions[g.seq] = self.learner.experiments
        self.phases.goal(g.seq)
        return g.seq, g.position

    def step_until(self, experiments: int) -> None:
        t0 = time.perf_counter()
        self.driver.step_until(experiments)
        self.learn_seconds += time.perf_counter() - t0

    def evaluate(self, goals: np.ndarray) -> np.ndarray:
        """Test errors of the frozen model on the evaluation simulator (never counted as learning;
        ``evaluate_fixed`` with the inverse model's searches batched across goals: the same floats)."""
        return evaluate_fixed_batch(self.learner, self.setup.evaluator(), goals)

    def test_goals(self):
        """(test goals, reachable-area estimate, extra ``synergy`` result keys) of the set-up."""
        return self.setup.test_goals()


def outcome_extents(outcomes: np.ndarray) -> dict:
    """Explored extents per task dimension: min, max, 1st and 99th percentile (Sec. 4.5 compares the
    explored (u, v) intervals)."""
    if not len(outcomes):
        return {}
    return {"min": outcomes.min(axis=0).tolist(), "max": outcomes.max(axis=0).tolist(),
            "p1": np.percentile(outcomes, 1, axis=0).tolist(),
            "p99": np.percentile(outcomes, 99, axis=0).tolist()}


def run_fixed_experiment(adapter, config_path: str | Path, strategy: str | None, seed: int | None,
                           micro_actions: int, eval_every: int, out_dir: str | Path | None,
                           progress: bool = True, overrides: dict[str, Any] | None = None) -> dict:
    """Run one (strategy, seed) fixed-context experiment of the set-up ``adapter`` in-process and
    write ``out_dir/result.json``. ``micro_actions`` is the number of experiments (synergy
    executions with an outcome)."""
    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    config = load_fixed_config(config_path, ov, adapter)
    run = FixedRun(config, adapter)
    lp = config["sagg_learner"]
    t0 = time.perf_counter()
    goals, area, goal_info = run.test_goals()
    pool_seconds = time.perf_counter() - t0

    bar = Progress(micro_actions, f"{run.setup.name} {lp['strategy']} seed {lp['seed']}", enabled=progress)
    frame = metric_frame(goals, run.setup.metric_base)  # distance bands (eval_metrics)
    curve, eval_seconds, errors = learning_curve(run, goals, micro_actions, eval_every, bar, frame)

    learner = run.learner
    outcomes = learner.outcomes.copy()
    result = result_dict(run, curve, area, micro_actions, eval_seconds, learner.experiments,
                         {"samples": len(learner), "digest": learner.by_theta.digest(),
                          "bytes": learner.memory_bytes})
    result.update({
        "eval_metrics": frame_summary(frame),
        "test_goals": goals.tolist(),
        "final_errors": errors.tolist(),
        "coverage": coverage(outcomes, goals),  # test goal to the nearest outcome ever reached
        "synergy": {
            "setup": run.setup.name,
            "experiments": learner.experiments,
            "trials": learner.trials,
            "discarded": learner.discarded,
            "goals_done": learner.goals_done,
            "goals_reached": learner.goals_reached,  # attempts whose best outcome reached the goal
            "goals_blocked": learner.goals_blocked,  # not reached, stopped by blocking_w (Sec. 3.7.6)
            "pool_seconds": pool_seconds,
            **goal_info,
            "outcome_extents": outcome_extents(outcomes),
            "outcomes": outcomes.tolist(),
        },
    })
    write_result(out_dir, result)
    return result

