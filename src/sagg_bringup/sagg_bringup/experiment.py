"""In-process experiments: the three cores wired together without ROS (``sagg experiment``).

The driver answers the learner coroutine's requests from a simulator and the goal generator, in
exactly the order the ROS graph does in lockstep mode.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError, resolve_nodes
from sagg_common.progress import Progress
from sagg_common.rng import substream_seed
from sagg_goal_generator.core import MODE_NAMES, SCHEMA as GEN_SCHEMA, GoalGenerator
from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame
from sagg_low_level.evaluate import evaluate
from sagg_low_level.learner import (SCHEMA as LEARNER_SCHEMA, Command, EvolvingContextLearner,
                                    GoalRequest, Observe, Robot)
from sagg_sim_bridge.arm import ArmSim, reachable_area, test_goals
from sagg_sim_bridge.params import SCHEMA as BRIDGE_SCHEMA, arm_spec_from_params

from .phases import PhaseCounter, coverage, phase_breakdown


def load_experiment_config(path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
    """Resolve the three nodes' parameters from a config file (+ overrides applied to every node)."""
    from .synergy_experiment import config_setup, load_synergy_config
    if config_setup(path, overrides) is not None:  # quadruped / fishing / context: fixed arm
        return load_synergy_config(path, overrides)
    out = resolve_nodes(path, {"sagg_goal_generator": GEN_SCHEMA, "sagg_learner": LEARNER_SCHEMA,
                               "sagg_sim_bridge": BRIDGE_SCHEMA}, overrides)
    arm_spec_from_params(out["sagg_sim_bridge"])  # validates the arm, naming the bad parameter
    return out


class InProcessRun:
    """A learning run of one strategy and seed, stepped in-process."""

    def __init__(self, config: dict[str, dict]):
        self.config = config
        gp, lp, bp = config["sagg_goal_generator"], config["sagg_learner"], config["sagg_sim_bridge"]
        self.seed = lp["seed"]
        self.spec = arm_spec_from_params(bp)
        self.sim = ArmSim(self.spec, seed=substream_seed(self.seed, "sim"))
        robot = Robot(list(self.sim.joint_names), self.sim.lower, self.sim.upper, self.sim.rest)
        self.generator = GoalGenerator(gp)
        self.learner = EvolvingContextLearner(lp, robot, self.sim.task_dim)
        self.learner.on_report = self._on_report
        self.goal_micro_actions: dict[int, int] = {}
        self.phases = PhaseCounter()
        self.sim.reset()
        self._coro = self.learner.run()
        self._pending = next(self._coro)
        self.learn_seconds = 0.0

    def _on_report(self, r) -> None:
        self.generator.report(r.kind, r.target, r.competence)

    def step_until(self, micro_actions: int) -> None:
        """Advance the learner until it has done ``micro_actions`` micro-actions in total."""
        learner, sim, gen, phases = self.learner, self.sim, self.generator, self.phases
        coro, req = self._coro, self._pending
        t0 = time.perf_counter()
        while learner.micro_actions < micro_actions:
            if isinstance(req, Command):
                answer = sim.command(req.target)
                phases.command(req.kind)
            elif isinstance(req, GoalRequest):
                g = gen.next_goal()
                phases.goal(g.seq)
                self.goal_micro_actions[g.seq] = learner.micro_actions
                answer = (g.seq, g.position)
            elif isinstance(req, Observe):
                answer = sim.observe()
            else:  # pragma: no cover - protocol error
                raise TypeError(f"unknown learner request {req!r}")
            req = coro.send(answer)
        self._pending = req
        self.learn_seconds += time.perf_counter() - t0

    def evaluate(self, goals: np.ndarray) -> np.ndarray:
        """Test errors of the frozen model on a fresh simulator (never counted as learning)."""
        eval_sim = ArmSim(self.spec, seed=substream_seed(self.seed, "eval_sim"))
        return evaluate(self.learner, eval_sim, goals)


def run_experiment(config_path: str | Path, strategy: str | None, seed: int | None,
                   micro_actions: int, eval_every: int, out_dir: str | Path | None,
                   progress: bool = True, overrides: dict[str, Any] | None = None) -> dict:
    """Run one (strategy, seed) experiment in-process and write ``out_dir/result.json``."""
    # synergy setups (config parameter `setup`: quadruped / fishing, paper Sec. 4-5): fixed-context
    # learner and synergy simulators, same result.json keys (micro_actions = experiments)
    # and the arm with the learner parameter context: fixed (the same fixed-context learner)
    from .synergy_experiment import config_setup, run_synergy_experiment
    if config_setup(config_path, overrides) is not None:
        return run_synergy_experiment(config_path, strategy, seed, micro_actions, eval_every, out_dir,
                                      progress=progress, overrides=overrides)
    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    config = load_experiment_config(config_path, ov)
    run = InProcessRun(config)
    lp = config["sagg_learner"]
    lower = np.asarray(lp["task_space.lower"])
    upper = np.asarray(lp["task_space.upper"])
    area = cached_reachable_area(run.spec, lower, upper, lp["eval.seed"])
    goals = test_goals(run.spec, lower, upper, n=lp["eval.goals"], seed=lp["eval.seed"], area=area)

    bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']}", enabled=progress)
    frame = metric_frame(goals, np.zeros(goals.shape[1]))  # the arm's base is the origin
    curve, eval_seconds, errors = learning_curve(run, goals, micro_actions, eval_every, bar, frame)

    result = build_result(run, curve, area, micro_actions, eval_seconds)
    result["eval_metrics"] = frame_summary(frame)
    result["test_goals"] = goals.tolist()
    result["final_errors"] = errors.tolist()
    mem = run.learner.memory
    n = len(mem)
    result["coverage"] = coverage(run.sim.tip_positions(mem.alpha[:n] + mem.delta_alpha[:n]), goals)
    write_result(out_dir, result)
    return result


_AREAS: dict[str, Any] = {}


def cached_reachable_area(spec, lower, upper, seed: int):
    """:func:`reachable_area` of (arm, bounds, seed), kept for the next run in this process: the
    runs of a comparison share it, and a worker process runs many of them (0.5-2.5 s each)."""
    key = repr((spec, np.asarray(lower, float).tolist(), np.asarray(upper, float).tolist(), int(seed)))
    if key not in _AREAS:
        if len(_AREAS) >= 4:
            _AREAS.pop(next(iter(_AREAS)))
        _AREAS[key] = reachable_area(spec, lower, upper, seed=seed)
    return _AREAS[key]


def run_overrides(micro_actions: int, eval_every: int, strategy: str | None, seed: int | None,
                  overrides: dict[str, Any] | None) -> dict[str, Any]:
    """The run-length options checked (ConfigError naming the option), and the parameter overrides
    with ``--strategy`` / ``--seed`` (when given) added: what every run command starts with."""
    if micro_actions < 1:
        raise ConfigError(f"--micro-actions: got {micro_actions}; allowed: an integer >= 1")
    if eval_every < 1:
        raise ConfigError(f"--eval-every: got {eval_every}; allowed: an integer >= 1")
    ov = dict(overrides or {})
    if strategy is not None:
        ov["strategy"] = strategy
    if seed is not None:
        ov["seed"] = seed
    return ov


def learning_curve(run, goals: np.ndarray, micro_actions: int, eval_every: int,
                   bar: Progress, frame: dict | None = None) -> tuple[list[dict], float, np.ndarray]:
    """Step an in-process run (:class:`InProcessRun` or a synergy run) to every multiple of
    ``eval_every`` and to ``micro_actions``, evaluating the frozen model on ``goals`` at each
    (never counted as learning). Each curve point holds the evaluation's metrics
    (:func:`sagg_low_level.eval_metrics.error_metrics` against ``frame``; default: base at the
    origin). Returns the curve, the evaluation seconds and the final errors; ``bar`` is closed."""
    if frame is None:
        frame = metric_frame(goals, np.zeros(np.asarray(goals).shape[1]))
    curve = []
    eval_seconds = 0.0
    for target in list(range(0, micro_actions, eval_every)) + [micro_actions]:
        run.step_until(target)
        t0 = time.perf_counter()
        errors = run.evaluate(goals)
        eval_seconds += time.perf_counter() - t0
        curve.append({"micro_actions": target, **error_metrics(errors, frame)})
        bar.update(target, goals=len(run.generator.goals), regions=len(run.generator.tree.leaves()),
                   competence=run.learner.last_competence, error=float(errors.mean()))
    bar.close()
    return curve, eval_seconds, errors


def write_result(out_dir: str | Path | None, result: dict) -> None:
    """``out_dir/result.json`` (the directory is created; nothing when ``out_dir`` is None)."""
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        write_json_atomic(out / "result.json", result)


def goal_share_stats(goal_positions: np.ndarray, goal_ma: np.ndarray, area, total: int) -> dict:
    """Share of self-generated goals (not subgoals) inside the reachable area, overall and in the
    second half of the run (by micro-actions), next to the reachable area's share of Y."""
    inside = area.contains(goal_positions) if len(goal_positions) else np.zeros(0, bool)
    second = goal_ma >= total / 2
    return {
        "reachable_share_of_Y": float(area.share()),
        "goals": int(len(goal_positions)),
        "goal_share_reachable": float(inside.mean()) if len(inside) else float("nan"),
        "goals_second_half": int(second.sum()),
        "goal_share_reachable_second_half": float(inside[second].mean()) if second.any() else float("nan"),
    }


def build_result(run: InProcessRun, curve: list[dict], area, total: int, eval_seconds: float) -> dict:
    learner = run.learner
    res = result_dict(run, curve, area, total, eval_seconds, learner.micro_actions,
                      {"samples": len(learner.memory), "digest": learner.memory.digest(),
                       "bytes": int(learner.memory.nbytes)})
    gen = run.generator
    res["phases"] = phase_breakdown(run.phases, [g.seq for g in gen.goals],
                                    np.array([g.position for g in gen.goals]).reshape(-1, len(gen.lower)), area)
    return res


def result_dict(run, curve: list[dict], area, total: int, eval_seconds: float, done: int,
                memory: dict) -> dict:
    """The ``result.json`` keys every in-process run writes (arm and synergy runs): ``done`` =
    micro-actions (experiments) learned, ``memory`` = the memory's size and digest."""
    gen, learner = run.generator, run.learner
    goals = [{"seq": g.seq, "position": g.position.tolist(), "mode": g.mode,
              "mode_name": MODE_NAMES[g.mode], "competence": g.competence,
              "micro_actions": run.goal_micro_actions.get(g.seq, 0)} for g in gen.goals]
    pos = np.array([g["position"] for g in goals]).reshape(-1, len(gen.lower))
    gma = np.array([g["micro_actions"] for g in goals])
    return {
        "format": "sagg.result/1",
        "strategy": run.config["sagg_learner"]["strategy"],
        "seed": run.seed,
        "config": run.config,
        "micro_actions": done,
        "micro_actions_per_second": done / max(run.learn_seconds, 1e-9),
        "learn_seconds": run.learn_seconds,
        "eval_seconds": eval_seconds,
        "curve": curve,
        "final_mean_error": curve[-1]["mean_error"],
        "final_median_error": curve[-1]["median_error"],
        "memory": memory,
        "exploration_phases": learner.exploration_phases,
        "reports": learner.reports_sent,
        "goals": goals,
        "goal_stats": goal_share_stats(pos, gma, area, total),
        "regions": gen.region_snapshot(),
        "splits": gen.tree.splits,
    }


