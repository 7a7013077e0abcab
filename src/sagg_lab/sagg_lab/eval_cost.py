"""The cost of one evaluation, as a ratio to a 5k learning phase, before and after batching.

    .venv/bin/python -m sagg_lab.eval_cost [--setups arm8 arm15 ...] [--strategy S]
        [--micro-actions 5000] [--seed 0] [--repeat 2] [--base COMMIT]

Per set-up, one process, one seeded run: the learning phase from 0 to ``--micro-actions`` is timed,
then the evaluation of the frozen model on the config's test goals, ``--repeat`` times each way,
alternating (a burst of load on this shared machine hits both alike; the minimum is reported):

* evolving-context arms (arm8, arm15, arm7_ratio15): *before* = goal after goal
  (:func:`sagg_low_level.evaluate.evaluate_per_goal`, the procedure the batch replaced, apart from
  arm8's per-goal noise streams, same cost), *after* = all goals together
  (:func:`~sagg_low_level.evaluate.evaluate_batch`). Both must give the same floats (checked, printed);
* fixed-context set-ups (quadruped, fishing, arm15_fixed = config/arm15.yaml with context fixed): one
  synergy execution per goal; *before* = ``evaluate_fixed`` (goal by goal), *after* =
  :func:`~sagg_low_level.fixed_eval_batch.evaluate_fixed_batch` (the inverse model's searches
  batched; the executions stay one per goal). Same floats (checked, printed).

Prints one table (CPU seconds of this process, and ratios to the learning phase) and the load average.

``--base COMMIT``: the same measurement of that commit's sources (``git archive``) against this tree's,
each set-up in two child processes importing their own sources first, base and new alternating
``--repeat`` times (the minimum of each is reported); the table then compares the two trees' batched
evaluations (learning phase, evaluation, their ratio) and checks they give the same errors.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from sagg_low_level.evaluate import evaluate_batch, evaluate_per_goal
from sagg_low_level.fixed_context import evaluate_fixed
from sagg_low_level.fixed_eval_batch import evaluate_fixed_batch
from sagg_sim_bridge.arm import test_goals

from sagg_bringup.inprocess.arm_eval import eval_arms
from sagg_bringup.inprocess.experiment import InProcessRun, cached_reachable_area
from sagg_bringup.graph.setups import in_process_run
from .base_tree import check_source, exported, pythonpath, repo_root

SETUPS = {"arm8": ("config/arm8.yaml", {}), "arm15": ("config/arm15.yaml", {}),
          "arm7_ratio15": ("config/arm7_ratio15.yaml", {}),
          "quadruped": ("config/quadruped.yaml", {}), "fishing": ("config/fishing.yaml", {}),
          "arm15_fixed": ("config/arm15.yaml", {"context": "fixed"})}


def _timed(f):
    """CPU seconds of this process (``time.process_time``: on a shared machine far less sensitive
    to other processes' load than the wall clock; the work is single-threaded) and the result."""
    t0 = time.process_time()
    out = f()
    return time.process_time() - t0, out


def measure(name: str, strategy: str, micro_actions: int, seed: int, repeat: int) -> dict:
    """Learning-phase and evaluation seconds of one set-up (see the module docstring)."""
    cfg, ov = SETUPS[name]
    run = in_process_run(cfg, dict(ov, strategy=strategy, seed=seed))
    evolving = isinstance(run, InProcessRun)
    if evolving:
        config = run.config
        lp = config["sagg_learner"]
        lower, upper = np.asarray(lp["task_space.lower"]), np.asarray(lp["task_space.upper"])
        area = cached_reachable_area(run.spec, lower, upper, lp["eval.seed"])
        goals = test_goals(run.spec, lower, upper, n=lp["eval.goals"], seed=lp["eval.seed"], area=area)
        eval_arms(run.spec, run.seed, len(goals))  # the arms are built once per process, as in a curve
        before = lambda: evaluate_per_goal(run.learner, eval_arms(run.spec, run.seed, len(goals)), goals)  # noqa: E731
        after = lambda: evaluate_batch(run.learner, eval_arms(run.spec, run.seed, len(goals)), goals)  # noqa: E731
    else:
        goals = run.test_goals()[0]
        before = lambda: evaluate_fixed(run.learner, run.setup.evaluator(), goals)  # noqa: E731
        after = lambda: evaluate_fixed_batch(run.learner, run.setup.evaluator(), goals)  # noqa: E731
    learn, _ = _timed(lambda: run.step_until(micro_actions))
    tb, ta, same = [], [], True
    for _ in range(repeat):
        t, eb = _timed(before)
        tb.append(t)
        t, ea = _timed(after)
        ta.append(t)
        same = same and eb.tobytes() == ea.tobytes()
    return {"setup": name, "learn": learn, "before": min(tb), "after": min(ta), "same": same,
            "mean_error": float(ea.mean()), "goals": len(goals), "batched": evolving}


_CHILD = r"""
import json, sys
import sagg_low_level
from sagg_lab import eval_cost
errors = []
def keep(f):
    def g(*a):
        e = f(*a)
        errors.append(e.tolist())
        return e
    return g
eval_cost.evaluate_batch = keep(eval_cost.evaluate_batch)  # the batched evaluation's errors, exactly
eval_cost.evaluate_fixed_batch = keep(eval_cost.evaluate_fixed_batch)
r = eval_cost.measure(sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), 1)
r["source"], r["errors"] = sagg_low_level.__file__, errors[-1]
print(json.dumps(r))
"""


def _child(src, name: str, strategy: str, micro_actions: int, seed: int) -> dict:
    env = dict(os.environ, PYTHONPATH=pythonpath(src))
    out = subprocess.run([sys.executable, "-c", _CHILD, name, strategy, str(micro_actions), str(seed)],
                         env=env, capture_output=True, text=True, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    check_source(r["source"], src)
    return r


def compare_base(base: str, setups, strategy: str, micro_actions: int, seed: int, repeat: int) -> list[dict]:
    """The batched evaluation's cost of ``base``'s sources against this tree's (module docstring)."""
    repo = repo_root()
    rows = []
    print(f"strategy {strategy}, seed {seed}, learning phase 0-{micro_actions}, base {base} vs this tree "
          f"({repo}), min of {repeat} alternating runs, CPU seconds")
    print("| set-up | learning base | learning new | eval base | eval new | eval speed-up | "
          "eval / learning base | eval / learning new | same errors |")
    print("|---|---|---|---|---|---|---|---|---|")
    with exported(base, repo) as base_src:
        for name in setups:
            runs = {"base": [], "new": []}
            for _ in range(repeat):
                for label, src in (("base", base_src), ("new", repo / "src")):
                    runs[label].append(_child(src, name, strategy, micro_actions, seed))
            b = {k: min(r[k] for r in runs["base"]) for k in ("learn", "after")}
            n = {k: min(r[k] for r in runs["new"]) for k in ("learn", "after")}
            errs = {json.dumps(r["errors"]) for r in runs["base"] + runs["new"]}
            row = {"setup": name, "base": b, "new": n, "same": len(errs) == 1}
            rows.append(row)
            print(f"| {name} | {b['learn']:.2f} | {n['learn']:.2f} | {b['after']:.2f} | {n['after']:.2f} | "
                  f"{b['after'] / n['after']:.2f} | {b['after'] / b['learn']:.2f} | {n['after'] / n['learn']:.2f} | "
                  f"{row['same']} |", flush=True)
    print("load average (1, 5, 15 min): " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))
    return rows


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.eval_cost", description=__doc__.split("\n")[0])
    ap.add_argument("--setups", nargs="+", default=["arm8", "arm15", "arm7_ratio15", "quadruped", "fishing"],
                    choices=sorted(SETUPS))
    ap.add_argument("--strategy", default="sagg-riac")
    ap.add_argument("--micro-actions", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--base", help="compare the batched evaluation with this commit's (see the module docstring)")
    args = ap.parse_args(argv)
    if args.base:
        return compare_base(args.base, args.setups, args.strategy, args.micro_actions, args.seed, args.repeat)
    rows = []
    print(f"strategy {args.strategy}, seed {args.seed}, learning phase 0-{args.micro_actions}, "
          f"evaluation on the config's test goals, min of {args.repeat} alternating repeats")
    print("| set-up | learning CPU s | eval before CPU s | eval after CPU s | before / learning | after / learning | "
          "speed-up | same floats | mean error |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.setups:
        r = measure(name, args.strategy, args.micro_actions, args.seed, args.repeat)
        rows.append(r)
        note = "" if r["batched"] else " (fixed context)"
        print(f"| {name}{note} | {r['learn']:.2f} | {r['before']:.2f} | {r['after']:.2f} | "
              f"{r['before'] / r['learn']:.2f} | {r['after'] / r['learn']:.2f} | "
              f"{r['before'] / r['after']:.2f} | {r['same']} | {r['mean_error']:.4g} |", flush=True)
    print("load average (1, 5, 15 min): " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))
    return rows


if __name__ == "__main__":
    main()
