"""Where the fixed-context arm's queries go and what limits its test error:
``python -m sagg_lab.fixed_diagnosis --strategies sagg-riac sagg-random --seeds 5
--points 5000 20000 [--set NAME=VALUE ...]``.

For each (strategy, seed, point) on the config's test goals:
  * ``inverse``: mean test error of the learner's inverse (Sec. 4.4.1 local linear model, one
    experiment from rest per goal: the evaluation of ``sagg experiment``);
  * ``nn``: mean test error of the nearest-neighbour inverse (θ of the stored outcome closest to the
    goal, replayed: the peer's evaluation); noise-free, so it equals ``coverage``;
  * ``coverage`` / ``coverage_max``: distance from each test goal to the nearest stored outcome;
  * ``explore``: share of the experiments that were exploration (Alg. 4) rather than reaching;
  * ``goals``, ``goals_inside``: goals chosen, and the share of them inside the reachable-area
    estimate of the evaluation (``sagg_sim_bridge.arm.reachable_area``);
  * ``interest_in`` / ``interest_out``: mean interest of the goal generator's leaves whose centre is
    inside / outside that area, and ``mass_in``: the share of mode 1's selection probability
    (Sec. 2.4.4) on the inside leaves.
Means over seeds are printed as a markdown table.
"""
from __future__ import annotations

import argparse
import collections

import numpy as np

from sagg_common.params import parse_set
from sagg_common.regions import interest_probabilities

from sagg_bringup.graph.setups import in_process_run


def diagnose(config: str, strategy: str, seed: int, points: list[int], overrides: dict) -> list[dict]:
    run = in_process_run(config, dict(overrides, context="fixed", strategy=strategy, seed=seed))
    goals, area, _ = run.test_goals()
    kinds: collections.Counter = collections.Counter()
    execute = run.driver.execute

    def counted(theta, kind):
        kinds[kind] += 1
        return execute(theta, kind)

    run.driver.execute = counted
    rows = []
    for n in points:
        run.step_until(n)
        learner = run.learner
        replay = run.setup.evaluator()
        nearest = [learner.closest(g) for g in goals]
        cov = np.array([np.linalg.norm(g - learner.outcomes[k]) for g, k in zip(goals, nearest)])
        nn = np.array([np.linalg.norm(g - replay(learner.thetas[k])) for g, k in zip(goals, nearest)])
        chosen = np.array([r.position for r in run.generator.goals])
        leaves = run.generator.tree.leaves()
        interests = np.array([r.interest for r in leaves])
        inside = area.contains(np.array([(r.lower + r.upper) / 2 for r in leaves]))
        inner = interests[inside] if inside.any() else np.zeros(1)
        outer = interests[~inside] if (~inside).any() else np.zeros(1)
        rows.append({"queries": n, "inverse": float(run.evaluate(goals).mean()), "nn": float(nn.mean()),
                     "coverage": float(cov.mean()), "coverage_max": float(cov.max()),
                     "explore": kinds["explore"] / max(1, sum(kinds.values())),
                     "goals": len(chosen), "goals_inside": float(area.contains(chosen).mean()),
                     "interest_in": float(inner.mean()), "interest_out": float(outer.mean()),
                     "mass_in": float(interest_probabilities(interests)[inside].sum())})
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="config/arm7_ratio15.yaml")
    ap.add_argument("--strategies", nargs="+", default=["sagg-riac", "sagg-random"])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--points", nargs="+", type=int, default=[5000, 20000])
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args(argv)
    overrides = parse_set(a.set)
    keys = ("inverse", "nn", "coverage", "coverage_max", "explore", "goals", "goals_inside",
            "interest_in", "interest_out", "mass_in")
    print(f"{a.config}, fixed context, overrides {overrides}, seeds 0-{a.seeds - 1} (mean over seeds)")
    print("| strategy | queries | " + " | ".join(keys) + " |")
    print("|---" * (len(keys) + 2) + "|")
    for strategy in a.strategies:
        per = [diagnose(a.config, strategy, seed, a.points, overrides) for seed in range(a.seeds)]
        for j, n in enumerate(a.points):
            vals = [np.mean([p[j][k] for p in per]) for k in keys]
            print(f"| {strategy} | {n} | " + " | ".join(f"{v:.4g}" for v in vals) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
