"""In-process synergy experiments (quadruped Sec. 4, fishing rod Sec. 5): the goal generator, the
fixed-context learner and a synergy simulator wired together without ROS (``sagg experiment`` with a
config whose ``setup`` is ``quadruped`` or ``fishing``). Writes the same ``result.json`` keys as the
arm's :func:`~sagg_bringup.experiment.run_experiment` (``micro_actions`` counts experiments, i.e.
synergy executions with an outcome) plus a ``synergy`` section (trials, discarded trials, outcomes).
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.params import ConfigError, read_config, resolve_nodes
from sagg_common.progress import Progress
from sagg_common.rng import stream
from sagg_common.synergy import transported_outcome
from sagg_goal_generator.core import SCHEMA as GEN_SCHEMA, GoalGenerator
from sagg_low_level.eval_metrics import frame_summary, metric_frame
from sagg_low_level.outcome_set import reachable_outcomes
from sagg_low_level.fixed_context import (SCHEMA as FC_SCHEMA, SYNERGY_NODE_SCHEMA, SYNERGY_SCHEMA, Driver, FixedContextLearner,
                                          ThetaSpace, evaluate_fixed, spread_goals, synergy_from_params)
from sagg_sim_bridge.synergy_params import NODE_SCHEMA as BRIDGE_NODE_SCHEMA, SCHEMA as SIM_SCHEMA, SETUPS, make_sim

# the nodes' full schemas (what the synergy learner and bridge nodes declare)
LEARNER_SCHEMA = FC_SCHEMA + SYNERGY_SCHEMA + SYNERGY_NODE_SCHEMA
SYN_BRIDGE_SCHEMA = SIM_SCHEMA + BRIDGE_NODE_SCHEMA


def config_setup(path: str | Path) -> str | None:
    """The config's ``setup`` ('quadruped' / 'fishing', under '/**' or 'sagg_sim_bridge'), or None
    (an arm config, which has no such parameter)."""
    sections = read_config(path)
    setup = sections.get("/**", {}).get("setup", sections.get("sagg_sim_bridge", {}).get("setup"))
    if setup is not None and setup not in SETUPS:
        raise ConfigError(f"parameter 'setup': got {setup!r}; allowed: one of {', '.join(map(repr, SETUPS))}")
    return setup


def load_synergy_config(path: str | Path, overrides: dict[str, Any] | None = None,
                        learner_schema=LEARNER_SCHEMA, bridge_schema=SYN_BRIDGE_SCHEMA) -> dict[str, dict]:
    """Resolve the three nodes' parameters of a synergy config (+ overrides applied to every node)."""
    out = resolve_nodes(path, {"sagg_goal_generator": GEN_SCHEMA, "sagg_learner": learner_schema,
                               "sagg_sim_bridge": bridge_schema}, overrides)
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


class SynergyRun:
    """A synergy learning run of one strategy and seed, stepped in-process."""

    def __init__(self, config: dict[str, dict]):
        self.config = config
        gp, lp, bp = config["sagg_goal_generator"], config["sagg_learner"], config["sagg_sim_bridge"]
        self.seed = lp["seed"]
        self.sim = make_sim(bp)
        self.eval_sim = make_sim(bp)
        self.synergy = synergy_from_params(lp)
        if sorted(self.synergy.joint_names) != sorted(self.sim.joint_names):
            raise ConfigError(f"parameter 'joints': got {self.synergy.joint_names}; allowed: the "
                              f"{bp['setup']}'s joints {list(self.sim.joint_names)}")
        if len(lp["task_space.lower"]) != self.sim.task_dim:
            raise ConfigError(f"parameter 'task_space.lower': {len(lp['task_space.lower'])} dimensions; "
                              f"allowed: {self.sim.task_dim} for the {bp['setup']}")
        core = {p.name: lp[p.name] for p in FC_SCHEMA}
        self.generator = GoalGenerator(gp)
        self.learner = FixedContextLearner(core, ThetaSpace(self.synergy.lower, self.synergy.upper),
                                           self.sim.task_dim)
        self.learner.on_report = self._on_report
        self.goal_micro_actions: dict[int, int] = {}
        self.driver = Driver(self.learner, self._execute, self._next_goal, self.sim.rest_outcome)
        self.learn_seconds = 0.0

    def _on_report(self, r) -> None:
        self.generator.report(r.kind, r.target, r.competence)

    def _execute(self, theta, kind):
        # exactly what the learner node receives from the bridge (φ through the PoseStamped quaternion)
        return transported_outcome(self.sim.execute(self.synergy.trajectory(theta)))

    def _next_goal(self):
        g = self.generator.next_goal()
        self.goal_micro_actions[g.seq] = self.learner.experiments
        return g.seq, g.position

    def step_until(self, experiments: int) -> None:
        t0 = time.perf_counter()
        self.driver.step_until(experiments)
        self.learn_seconds += time.perf_counter() - t0

    def run_eval(self, theta):
        return transported_outcome(self.eval_sim.execute(self.synergy.trajectory(theta)))

    def evaluate(self, goals: np.ndarray) -> np.ndarray:
        """Test errors of the frozen model on the evaluation simulator (never counted as learning)."""
        return evaluate_fixed(self.learner, self.run_eval, goals)

    def test_pool(self) -> np.ndarray:
        """``eval.pool`` synergy executions spread over the reachable outcome set by
        :func:`sagg_low_level.outcome_set.reachable_outcomes` (``eval.pool_rounds`` rounds; 0 = plain
        uniformly random synergies), seeded by eval.seed, no-contact trials dropped: the estimate of
        the reachable outcome set the test goals are picked from (and the goal-share box)."""
        lp = self.config["sagg_learner"]
        # the same for every strategy and seed of a set-up: kept for the next run in this process
        key = json.dumps([self.config["sagg_sim_bridge"], {k: v for k, v in lp.items()
                                                           if k not in ("seed", "strategy")}],
                         sort_keys=True, default=str)
        if key in _POOLS:
            return _POOLS[key].copy()
        rng = stream(lp["eval.seed"], "synergy_test_pool")
        out = reachable_outcomes(self.run_eval, self.synergy.lower, self.synergy.upper,
                                 lp["eval.pool"], lp["eval.pool_rounds"], rng)
        if not len(out):
            raise ConfigError("eval.pool: no synergy of the test pool produced an outcome")
        if len(_POOLS) >= 4:
            _POOLS.pop(next(iter(_POOLS)))
        _POOLS[key] = out.copy()
        return out

    def test_goals(self, pool: np.ndarray) -> np.ndarray:
        lp = self.config["sagg_learner"]
        return spread_goals(pool, lp["eval.goals"], stream(lp["eval.seed"], "synergy_test_goals"),
                            lp["task_space.lower"], lp["task_space.upper"])


def outcome_extents(outcomes: np.ndarray) -> dict:
    """Explored extents per task dimension: min, max, 1st and 99th percentile (Sec. 4.5 compares the
    explored (u, v) intervals)."""
    if not len(outcomes):
        return {}
    return {"min": outcomes.min(axis=0).tolist(), "max": outcomes.max(axis=0).tolist(),
            "p1": np.percentile(outcomes, 1, axis=0).tolist(),
            "p99": np.percentile(outcomes, 99, axis=0).tolist()}


def run_synergy_experiment(config_path: str | Path, strategy: str | None, seed: int | None,
                           micro_actions: int, eval_every: int, out_dir: str | Path | None,
                           progress: bool = True, overrides: dict[str, Any] | None = None) -> dict:
    """Run one (strategy, seed) synergy experiment in-process and write ``out_dir/result.json``.
    ``micro_actions`` is the number of experiments (synergy executions with an outcome)."""
    from .experiment import learning_curve, result_dict, run_overrides, write_result

    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    config = load_synergy_config(config_path, ov)
    run = SynergyRun(config)
    lp = config["sagg_learner"]
    t0 = time.perf_counter()
    pool = run.test_pool()
    goals = run.test_goals(pool)
    pool_seconds = time.perf_counter() - t0
    area = BoxArea(pool, lp["task_space.lower"], lp["task_space.upper"])

    bar = Progress(micro_actions, f"{bp_setup(config)} {lp['strategy']} seed {lp['seed']}", enabled=progress)
    frame = metric_frame(goals, run.sim.rest_outcome)  # distance bands from the rest outcome
    curve, eval_seconds, errors = learning_curve(run, goals, micro_actions, eval_every, bar, frame)

    learner = run.learner
    outcomes = learner.outcomes.copy()
    result = result_dict(run, curve, area, micro_actions, eval_seconds, learner.experiments,
                         {"samples": len(learner), "digest": learner.by_theta.digest(),
                          "bytes": int(learner.by_theta.nbytes + learner.by_y.nbytes)})
    result.update({
        "eval_metrics": frame_summary(frame),
        "test_goals": goals.tolist(),
        "final_errors": errors.tolist(),
        "synergy": {
            "setup": config["sagg_sim_bridge"]["setup"],
            "experiments": learner.experiments,
            "trials": learner.trials,
            "discarded": learner.discarded,
            "goals_done": learner.goals_done,
            "pool_seconds": pool_seconds,
            "pool_outcomes": len(pool),
            "pool_extents": outcome_extents(pool),
            "outcome_extents": outcome_extents(outcomes),
            "outcomes": outcomes.tolist(),
        },
    })
    write_result(out_dir, result)
    return result


def bp_setup(config: dict) -> str:
    return config["sagg_sim_bridge"]["setup"]
