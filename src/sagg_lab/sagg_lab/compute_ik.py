"""/sagg/compute_ik's core against the closed-loop test error, on a run's own test goals.

    .venv/bin/python -m sagg_lab.compute_ik --config config/arm7_urdf.yaml [--seeds 0 1 2]
        [--micro-actions 20000] [--out DIR]

Per seed, one in-process run (as ``sagg experiment --config C --seed S --micro-actions N``: the
same learner, simulator and test goals) learns ``--micro-actions``; then, on the frozen model:

* the closed-loop test error: the run's own evaluation (reaches from rest, measured by the
  simulator at every step: ``InProcessRun.evaluate``, the number ``sagg experiment`` reports);
* the open-loop answer of :func:`sagg_low_level.ik.compute_ik` for each test goal, with the rest
  point the learner measures (the simulated arm's tip at rest), under the run's scene, in two ways:
  ``compute_ik`` as served (the reach starts from the stored posture whose rebuilt point is
  nearest the goal: :mod:`sagg_low_level.known_points`, one index kept across the calls, as the
  nodes keep it) and ``from_rest`` (the rest posture given as the start: the reach from rest that
  ``compute_ik`` answered before the known points). Each error is the distance from the forward
  kinematics of the returned joints (the simulator's ``tip_positions``) to the goal.

Also checks the rebuilt points: the largest distance between a known point and the simulator's
forward kinematics of its posture, and how many stored samples have a known point; and what bounds
the answer's error: the distance from each goal to the nearest known point (the open loop's
travel) and the local model's relative error, ||J(α) - J_true(α)|| / ||J_true(α)|| (Frobenius; the
true Jacobian by central differences of the simulator's forward kinematics) at 200 stored
postures drawn with the run's seed.

Prints per seed and in all: mean, median and share within ``eval.tolerance`` of the errors, the
share of answers flagged ``success``, where the answers started, the median distance to the nearest
stored posture, the Spearman rank correlation of that distance with the answer's error, and the
time per call of the core (median and max over the goals, this process, no ROS; the index's
first build apart). ``--out``: the numbers as JSON.
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
from sagg_low_level.known_points import KnownPoints, sample_points
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
    tol = lp["eval.tolerance"]
    points, build = KnownPoints(), time.perf_counter()
    points.update(learner.memory, learner.robot.rest)
    build = time.perf_counter() - build
    served = answer_all(run, goals, tol, lambda g: compute_ik(learner, rest_point, g, points=points))
    rest = answer_all(run, goals, tol, lambda g: compute_ik(learner, rest_point, g, start=learner.robot.rest))
    return {"config": config, "seed": seed, "micro_actions": micro_actions, "tolerance": tol,
            "learn_seconds": learn, "closed_loop": summary(closed, tol), "compute_ik": served,
            "from_rest": rest, "samples": len(learner.memory), "known_points": points.known,
            "known_point_vs_fk_max": point_check(run, rest_point), "index_build_ms": 1000 * build,
            "start_distance_median": float(np.median([np.linalg.norm(points.nearest(g - rest_point, 1)[1][0]
                                                                     + rest_point - g) for g in goals])),
            "jacobian_rel_error_median": float(np.median(jacobian_errors(run, seed))),
            "errors_closed_loop": closed.tolist()}


def jacobian_errors(run, seed: int, count: int = 200, h: float = 1e-6) -> np.ndarray:
    """The local model's relative error at ``count`` stored postures (the module docstring)."""
    mem, learner = run.learner.memory, run.learner
    rows = np.random.default_rng(seed).choice(len(mem), min(count, len(mem)), replace=False)
    out = []
    for a in mem.alpha[rows]:
        steps = h * np.eye(len(a))
        true = (run.sim.tip_positions(a + steps) - run.sim.tip_positions(a - steps)).T / (2 * h)
        out.append(np.linalg.norm(learner.jacobian_at(a) - true) / np.linalg.norm(true))
    return np.array(out)


def answer_all(run, goals: np.ndarray, tol: float, ask) -> dict:
    """``ask(goal)`` (an :class:`~sagg_low_level.ik.IKAnswer`) for every goal: the errors of the
    answers (forward kinematics of the joints to the goal) and what the answers say."""
    answers, seconds = [], []
    for g in goals:
        t = time.perf_counter()
        answers.append(ask(g))
        seconds.append(time.perf_counter() - t)
    joints = np.array([a.joints for a in answers])
    errors = np.linalg.norm(run.sim.tip_positions(joints) - goals, axis=1)
    nearest = np.array([a.nearest_sample for a in answers])
    return {**summary(errors, tol), "success_share": float(np.mean([a.success for a in answers])),
            "outcomes": counts([a.outcome for a in answers]), "starts": counts([a.start for a in answers]),
            "predicted_error_median": float(np.median([a.predicted_error for a in answers])),
            "nearest_sample_median": float(np.median(nearest)),
            "nearest_vs_error_spearman": spearman(nearest, errors),
            "steps_mean": float(np.mean([a.steps for a in answers])),
            "call_ms_median": 1000 * float(np.median(seconds)), "call_ms_max": 1000 * float(np.max(seconds)),
            "errors": errors.tolist()}


def counts(values: list[str]) -> dict:
    return {v: values.count(v) for v in sorted(set(values))}


def point_check(run, rest_point: np.ndarray) -> float:
    """The largest distance from a rebuilt start point (:func:`sample_points`) to the simulator's
    forward kinematics of its posture (NaN: none known)."""
    mem, rest = run.learner.memory, run.learner.robot.rest
    known, start = sample_points(mem.alpha, mem.delta_alpha, mem.delta_y, rest, rest_point)
    if not known.any():
        return float("nan")
    return float(np.linalg.norm(start[known] - run.sim.tip_positions(mem.alpha[known]), axis=1).max())


def summary(errors: np.ndarray, tol: float) -> dict:
    """Mean, median and share within ``tol`` of ``errors``."""
    return {"mean": float(errors.mean()), "median": float(np.median(errors)),
            "within_share": float(np.mean(errors <= tol))}


def line(r: dict) -> str:
    c = r["closed_loop"]
    parts = [f"{Path(r['config']).stem} seed {r['seed']}: {r['known_points']}/{r['samples']} samples with a known "
             f"point (max distance to FK {r['known_point_vs_fk_max']:.2g}; index {r['index_build_ms']:.1f} ms); "
             f"goal to nearest known point median {r['start_distance_median']:.4g}; local model's relative "
             f"error median {r['jacobian_rel_error_median']:.3f}"]
    for name in ("compute_ik", "from_rest"):
        o = r[name]
        parts.append(f"{name} FK error mean {o['mean']:.4g} median {o['median']:.4g} within "
                     f"{o['within_share']:.2f}, success {o['success_share']:.2f} {o['outcomes']} from "
                     f"{o['starts']}, steps {o['steps_mean']:.1f}, "
                     f"nearest sample median {o['nearest_sample_median']:.3g} rad (rank corr. with the error "
                     f"{o['nearest_vs_error_spearman']:.2f}), {o['call_ms_median']:.2f} ms/call (max "
                     f"{o['call_ms_max']:.1f})")
    parts.append(f"closed loop mean {c['mean']:.4g} median {c['median']:.4g} within {c['within_share']:.2f} "
                 f"(tolerance {r['tolerance']:.4g}) | learning {r['learn_seconds']:.0f} s")
    return "\n  ".join(parts)


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
    both = {k: np.concatenate([r[k]["errors"] for r in results]) for k in ("compute_ik", "from_rest")}
    both["closed_loop"] = np.concatenate([r["errors_closed_loop"] for r in results])
    tol = results[0]["tolerance"]
    print(f"all seeds ({len(results)} x {len(both['compute_ik']) // len(results)} goals): "
          + ", ".join(f"{k} {summary(v, tol)}" for k, v in both.items()) + f"; load {os.getloadavg()[0]:.2f}")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
