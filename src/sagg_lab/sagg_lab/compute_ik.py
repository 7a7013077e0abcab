"""/sagg/compute_ik's core against the closed-loop test error, on a run's own test goals.

    .venv/bin/python -m sagg_lab.compute_ik --config config/arm7_urdf.yaml [--seeds 0 1 2]
        [--micro-actions 20000] [--out DIR]

Per seed, one in-process run (as ``sagg experiment --config C --seed S --micro-actions N``: the
same learner, simulator and test goals) learns ``--micro-actions``; then, on the frozen model:

* the closed-loop test error: the run's own evaluation (reaches from rest, measured by the
  simulator at every step: ``InProcessRun.evaluate``, the number ``sagg experiment`` reports);
* the open-loop answer of :func:`sagg_low_level.ik.compute_ik` for each test goal, from rest with the
  rest point the learner measures (the simulated arm's tip at rest), under the run's scene; its
  error is the distance from the forward kinematics of the returned joints (the simulator's
  ``tip_positions``) to the goal.

Prints per seed and in all: mean, median and share within ``eval.tolerance`` of both errors,
the share of answers flagged ``success``, the median distance to the nearest stored posture, the
Spearman rank correlation of that distance with the answer's error, and the time per call of the
core (median over the goals, this process, no ROS). ``--out``: the numbers as JSON.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from sagg_bringup.inprocess.experiment import InProcessRun, cached_reachable_area, load_arm_config
from sagg_low_level.ik import compute_ik
from sagg_sim_bridge.arms import arm_test_goals


def spearman(a, b) -> float:
    """Spearman's rank correlation (no ties expected among floats)."""
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def measure(config: str, seed: int, micro_actions: int) -> dict:
    """One seed's run and both errors on its test goals (the module docstring)."""
    cfg = load_arm_config(config, {"seed": seed})  # (as `sagg experiment --seed S`)
    run = InProcessRun(cfg)
    lp = cfg["sagg_learner"]
    lower, upper = np.asarray(lp["task_space.lower"]), np.asarray(lp["task_space.upper"])
    area = cached_reachable_area(run.spec, lower, upper, lp["eval.seed"])
    goals = arm_test_goals(run.spec, lower, upper, n=lp["eval.goals"], seed=lp["eval.seed"], area=area)
    t0 = time.perf_counter()
    run.step_until(micro_actions)
    learn = time.perf_counter() - t0
    closed = run.evaluate(goals)
    learner = run.learner
    rest_point = run.sim.tip_positions(learner.robot.rest[None])[0]
    answers, seconds = [], []
    for g in goals:
        t = time.perf_counter()
        answers.append(compute_ik(learner, rest_point, g))
        seconds.append(time.perf_counter() - t)
    joints = np.array([a.joints for a in answers])
    opened = np.linalg.norm(run.sim.tip_positions(joints) - goals, axis=1)
    nearest = np.array([a.nearest_sample for a in answers])
    tol = lp["eval.tolerance"]
    return {"config": config, "seed": seed, "micro_actions": micro_actions, "tolerance": tol,
            "learn_seconds": learn, "closed_loop": summary(closed, tol), "compute_ik": summary(opened, tol),
            "success_share": float(np.mean([a.success for a in answers])),
            "outcomes": {o: sum(a.outcome == o for a in answers) for o in sorted({a.outcome for a in answers})},
            "predicted_error_median": float(np.median([a.predicted_error for a in answers])),
            "nearest_sample_median": float(np.median(nearest)),
            "nearest_vs_error_spearman": spearman(nearest, opened),
            "steps_mean": float(np.mean([a.steps for a in answers])),
            "call_ms_median": 1000 * float(np.median(seconds)), "call_ms_max": 1000 * float(np.max(seconds)),
            "errors_compute_ik": opened.tolist(), "errors_closed_loop": closed.tolist()}


def summary(errors: np.ndarray, tol: float) -> dict:
    return {"mean": float(errors.mean()), "median": float(np.median(errors)),
            "within_share": float(np.mean(errors <= tol))}


def line(r: dict) -> str:
    c, o = r["closed_loop"], r["compute_ik"]
    return (f"{Path(r['config']).stem} seed {r['seed']}: compute_ik FK error mean {o['mean']:.4g} median "
            f"{o['median']:.4g} within {o['within_share']:.2f} | closed loop mean {c['mean']:.4g} median "
            f"{c['median']:.4g} within {c['within_share']:.2f} (tolerance {r['tolerance']:.4g}) | success "
            f"{r['success_share']:.2f} {r['outcomes']} | nearest sample median {r['nearest_sample_median']:.3g} rad, "
            f"rank corr. with the error {r['nearest_vs_error_spearman']:.2f} | {r['call_ms_median']:.2f} ms/call "
            f"(max {r['call_ms_max']:.1f}) | learning {r['learn_seconds']:.0f} s")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.compute_ik", description=__doc__.splitlines()[0])
    ap.add_argument("--config", required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--micro-actions", type=int, default=20000)
    ap.add_argument("--out", default=None, help="write the numbers (JSON) here")
    args = ap.parse_args(argv)
    results = []
    for seed in args.seeds:
        results.append(measure(args.config, seed, args.micro_actions))
        print(line(results[-1]), flush=True)
    both = {k: np.concatenate([r[f"errors_{k}"] for r in results]) for k in ("compute_ik", "closed_loop")}
    tol = results[0]["tolerance"]
    print(f"all seeds ({len(results)} x {len(both['compute_ik']) // len(results)} goals): compute_ik "
          f"{summary(both['compute_ik'], tol)}, closed loop {summary(both['closed_loop'], tol)}; load "
          f"{os.getloadavg()[0]:.2f}")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
