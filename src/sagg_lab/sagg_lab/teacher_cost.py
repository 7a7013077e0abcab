"""What each goal strategy's teacher costs per goal, against the micro-actions a goal takes (a
teacher must not slow a micro-action noticeably)::

    python -m sagg_lab.teacher_cost --config config/arm8.yaml --micro-actions 10000 --seed 0 \\
        [--strategies sagg-riac sagg-random alp-gmm discretized-progress] [--set NAME=VALUE ...]

One in-process run per strategy (the code path of ``sagg experiment``, no evaluation). The
teacher's ``choose`` and ``report`` (the strategy's own work; the region tree, which every strategy
feeds, is timed apart as ``tree``) are wrapped with ``time.perf_counter``; they run in the same
process and the same run as the learning they are compared with, so the shares below hold on a
loaded machine too (the absolute times do not). Per strategy: goals, micro-actions per goal, the
learning loop's seconds, the teacher's seconds (choices + reports), per goal (µs), per micro-action
(µs), its share of the loop, and the tree's share.
"""
from __future__ import annotations

import argparse
import time

from sagg_common.params import GOAL_STRATEGIES, parse_set

from sagg_bringup.graph.setups import in_process_run


def teacher_cost(config: str, strategy: str, seed: int, micro_actions: int, overrides: dict) -> dict:
    run = in_process_run(config, dict(overrides, strategy=strategy, seed=seed))
    gen = run.generator
    spent = {"choose": 0.0, "report": 0.0, "tree": 0.0}

    def timed(key, method):
        def wrapper(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return method(*args, **kwargs)
            finally:
                spent[key] += time.perf_counter() - t0
        return wrapper

    gen.teacher.choose = timed("choose", gen.teacher.choose)
    gen.teacher.report = timed("report", gen.teacher.report)
    gen.tree.add = timed("tree", gen.tree.add)
    t0 = time.perf_counter()
    run.step_until(micro_actions)
    loop = time.perf_counter() - t0
    goals = max(1, len(gen.goals))
    teacher = spent["choose"] + spent["report"]
    return {"strategy": strategy, "goals": len(gen.goals), "micro_actions_per_goal": micro_actions / goals,
            "loop_seconds": loop, "choose_seconds": spent["choose"], "report_seconds": spent["report"],
            "per_goal_us": 1e6 * teacher / goals, "per_micro_action_us": 1e6 * teacher / micro_actions,
            "loop_per_micro_action_us": 1e6 * loop / micro_actions, "share": teacher / loop,
            "tree_share": spent["tree"] / loop}


def table(rows: list[dict]) -> str:
    lines = ["| strategy | goals | micro-actions / goal | loop s | teacher s (choose + report) | "
             "teacher µs / goal | teacher µs / micro-action | loop µs / micro-action | teacher's share of loop "
             "| tree's share |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['strategy']} | {r['goals']} | {r['micro_actions_per_goal']:.1f} | {r['loop_seconds']:.2f} "
                     f"| {r['choose_seconds'] + r['report_seconds']:.3f} ({r['choose_seconds']:.3f} + "
                     f"{r['report_seconds']:.3f}) | {r['per_goal_us']:.0f} | {r['per_micro_action_us']:.1f} "
                     f"| {r['loop_per_micro_action_us']:.0f} | {100 * r['share']:.1f} % "
                     f"| {100 * r['tree_share']:.1f} % |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.teacher_cost", description=__doc__.split("::")[0])
    ap.add_argument("--config", default="config/arm8.yaml")
    ap.add_argument("--strategies", nargs="+", default=list(GOAL_STRATEGIES), choices=GOAL_STRATEGIES)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--micro-actions", type=int, default=10_000)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args(argv)
    overrides = parse_set(a.set)
    rows = []
    for s in a.strategies:
        rows.append(teacher_cost(a.config, s, a.seed, a.micro_actions, overrides))
        print(f"{s}: {rows[-1]['per_goal_us']:.0f} µs per goal", flush=True)
    print(table(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
