"""What every run shares, arm or synergy, in-process or graph: the run options
(:func:`run_overrides`), the learning curve of an in-process run (:func:`learning_curve`) and the
``result.json`` keys (:func:`result_dict`, :func:`goal_share_stats`, :func:`write_result`)."""
from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError
from sagg_common.progress import Progress
from sagg_goal_generator.core import MODE_NAMES
from sagg_low_level.eval_metrics import error_metrics, metric_frame

from .phases import phase_breakdown


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


def code_commit() -> str:
    """The commit of the code that ran (with ``-dirty`` when the work tree has changes), or
    ``unknown`` outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        rev = subprocess.run(["git", "-C", str(here), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(here), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10, check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return rev + ("-dirty" if dirty else "")


def run_commits(directory: str | Path, fallback: str) -> dict:
    """``commit``: the commit every ``result.json`` under ``directory`` was computed at (``mixed:
    a, b`` when a resumed experiment spans several; ``fallback`` when none says), and
    ``run_commits``: how many runs came from each."""
    counts: dict[str, int] = {}
    for f in sorted(Path(directory).rglob("result.json")):
        c = json.loads(f.read_text()).get("commit", "unrecorded")
        counts[c] = counts.get(c, 0) + 1
    if not counts:
        return {"commit": fallback, "run_commits": {}}
    commit = next(iter(counts)) if len(counts) == 1 else "mixed: " + ", ".join(sorted(counts))
    return {"commit": commit, "run_commits": counts}


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


def result_dict(run, curve: list[dict], area, total: int, eval_seconds: float, done: int,
                memory: dict) -> dict:
    """The ``result.json`` keys every in-process run writes (arm and synergy runs): ``done`` =
    micro-actions (experiments) learned, ``memory`` = the memory's size and digest; ``phases``:
    where they went (``run.phases``, a :class:`~sagg_bringup.inprocess.phases.PhaseCounter`)."""
    gen, learner = run.generator, run.learner
    goals = [{"seq": g.seq, "position": g.position.tolist(), "mode": g.mode,
              "mode_name": MODE_NAMES[g.mode], "competence": g.competence,
              "micro_actions": run.goal_micro_actions.get(g.seq, 0)} for g in gen.goals]
    pos = np.array([g["position"] for g in goals]).reshape(-1, len(gen.lower))
    gma = np.array([g["micro_actions"] for g in goals])
    teacher = gen.teacher.snapshot()  # the strategy's own "where goals went" (None: the tree says it)
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
        "phases": phase_breakdown(run.phases, [g["seq"] for g in goals], pos, area),
        **({} if teacher is None else {"teacher": teacher}),
    }
