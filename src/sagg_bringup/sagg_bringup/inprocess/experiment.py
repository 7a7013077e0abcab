"""In-process experiments of the evolving-context arm: the three cores wired together without ROS
(``sagg experiment`` with an arm config; the set-up registry :mod:`.setups` chooses it).

The driver answers the learner coroutine's requests from a simulator and the goal generator, in
exactly the order the ROS graph does in lockstep mode.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.journal import save_npz_atomic
from sagg_common.params import resolve_nodes
from sagg_common.progress import Progress
from sagg_common.region_arrays import tree_arrays
from sagg_common.rng import substream_seed
from sagg_goal_generator.core import SCHEMA as GEN_SCHEMA, GoalGenerator
from sagg_low_level.eval_metrics import frame_summary, metric_frame
from sagg_low_level.learner import (SCHEMA as LEARNER_SCHEMA, Command, EvolvingContextLearner,
                                    GoalRequest, Observe, Robot)
from sagg_sim_bridge.arms import (arm_base_point, arm_reachable_area, arm_scene_checker, arm_spec_from_params,
                                  arm_test_goals,
                                  make_arm_sim)
from sagg_sim_bridge.params import SCHEMA as BRIDGE_SCHEMA

from .arm_config import finish_arm_config
from .arm_eval import evaluate_arm
from .phases import PhaseCounter, coverage
from .results import learning_curve, result_dict, run_overrides, write_result


def load_arm_config(path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
    """Resolve the three nodes' parameters from an arm config file (+ overrides applied to every node)."""
    out = resolve_nodes(path, {"sagg_goal_generator": GEN_SCHEMA, "sagg_learner": LEARNER_SCHEMA,
                               "sagg_sim_bridge": BRIDGE_SCHEMA}, overrides)
    finish_arm_config(out, path, overrides)  # validates the arm, naming the bad parameter
    return out


class InProcessRun:
    """A learning run of one strategy and seed, stepped in-process."""

    def __init__(self, config: dict[str, dict]):
        self.config = config
        gp, lp, bp = config["sagg_goal_generator"], config["sagg_learner"], config["sagg_sim_bridge"]
        self.seed = lp["seed"]
        self.spec = arm_spec_from_params(bp)
        self.sim = make_arm_sim(self.spec, seed=substream_seed(self.seed, "sim"))
        robot = Robot(list(self.sim.joint_names), self.sim.lower, self.sim.upper, self.sim.rest)
        self.generator = GoalGenerator(gp)
        self.learner = EvolvingContextLearner(lp, robot, self.sim.task_dim)
        self.learner.on_report = self._on_report
        # the scene, as the learner node checks it (the config's arm model, its scene.*)
        self.learner.scene = arm_scene_checker(self.spec)
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
                if req.kind == "reset" and learner.scene is not None and learner.refuses(learner.alpha, req.target):
                    answer = sim.observe()  # (refused by the scene, as the learner node does: the arm stays)
                else:
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
        """Test errors of the frozen model, one evaluation arm per goal, all goals reached together
        (:mod:`.arm_eval`; never counted as learning)."""
        return evaluate_arm(self.learner, self.spec, self.seed, goals)


def run_arm_experiment(config_path: str | Path, strategy: str | None, seed: int | None,
                       micro_actions: int, eval_every: int, out_dir: str | Path | None,
                       progress: bool = True, overrides: dict[str, Any] | None = None,
                       save_model: bool = False) -> dict:
    """Run one (strategy, seed) arm experiment in-process and write ``out_dir/result.json``;
    ``save_model``: also the learned model, ``out_dir/memory.npz`` and ``out_dir/regions.npz`` (the
    goal generator's region tree), what another run takes as its prior (``--prior out_dir``)."""
    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    config = load_arm_config(config_path, ov)
    run = InProcessRun(config)
    lp = config["sagg_learner"]
    lower = np.asarray(lp["task_space.lower"])
    upper = np.asarray(lp["task_space.upper"])
    area = cached_reachable_area(run.spec, lower, upper, lp["eval.seed"])
    goals = arm_test_goals(run.spec, lower, upper, n=lp["eval.goals"], seed=lp["eval.seed"], area=area)

    bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']}", enabled=progress)
    frame = metric_frame(goals, arm_base_point(run.spec))  # distance bands from the arm's base
    curve, eval_seconds, errors = learning_curve(run, goals, micro_actions, eval_every, bar, frame)

    result = build_result(run, curve, area, micro_actions, eval_seconds)
    result["eval_metrics"] = frame_summary(frame)
    result["test_goals"] = goals.tolist()
    result["final_errors"] = errors.tolist()
    mem = run.learner.memory
    n = len(mem)
    result["coverage"] = coverage(run.sim.tip_positions(mem.alpha[:n] + mem.delta_alpha[:n]), goals)
    prior = run.learner.prior
    if prior is not None:
        result["prior"] = {"samples": len(prior), "superseded": prior.superseded_count, "radius": prior.radius,
                           "source": prior.source,
                           "regions": bool(config["sagg_goal_generator"]["prior.regions"])}
    if save_model and out_dir is not None:
        save_model_files(run, Path(out_dir))
    write_result(out_dir, result)
    return result


def save_model_files(run: InProcessRun, out: Path) -> None:
    """The run's model as a prior source: ``memory.npz`` (the learner's samples) and ``regions.npz``
    (the goal generator's region tree, :func:`sagg_common.region_arrays.tree_arrays`)."""
    out.mkdir(parents=True, exist_ok=True)
    run.learner.memory.save(out / "memory.npz")
    save_npz_atomic(out / "regions.npz", **tree_arrays(run.generator.tree))


_AREAS: dict[str, Any] = {}


def cached_reachable_area(spec, lower, upper, seed: int):
    """:func:`reachable_area` of (arm, bounds, seed), kept for the next run in this process: the
    runs of a comparison share it, and a worker process runs many of them (seconds each)."""
    key = repr((spec, np.asarray(lower, float).tolist(), np.asarray(upper, float).tolist(), int(seed)))
    if key not in _AREAS:
        if len(_AREAS) >= 4:
            _AREAS.pop(next(iter(_AREAS)))
        _AREAS[key] = arm_reachable_area(spec, lower, upper, seed=seed)
    return _AREAS[key]


def build_result(run: InProcessRun, curve: list[dict], area, total: int, eval_seconds: float) -> dict:
    learner = run.learner
    res = result_dict(run, curve, area, total, eval_seconds, learner.micro_actions,
                      {"samples": len(learner.memory), "digest": learner.memory.digest(),
                       "bytes": int(learner.memory.nbytes)})
    return res
