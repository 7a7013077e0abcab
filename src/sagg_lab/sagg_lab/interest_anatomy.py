"""Why SAGG-RIAC's goals gather near the rest tip on arm8: the region tree's
interest taken apart at every goal choice::

    python -m sagg_lab.interest_anatomy --config config/arm8.yaml --seeds 10 --micro-actions 10000 \\
        --variants sagg-riac sagg-random sagg-riac:count_reached=false --out DIR

A variant is a strategy, optionally followed by ``:NAME=VALUE,...`` overrides. Every run is an
in-process run of the config (the same code path as ``sagg experiment``); the goal generator's
``report`` and ``next_goal`` are wrapped to log what the tree receives and what it chooses, which
changes no draw. Near = a leaf whose centre, or a goal, lies within ``--radius`` task units of the
rest tip (the outcome of the rest posture). At every ``--every``-th goal choice, over the leaves:

- ``mass_near``: mode 1's selection probability (Sec. 2.4.4, ``interest_probabilities``) on near
  leaves, against ``area_near``, their share of Y's area, and ``leaves_near``, their share of leaves;
- ``zeros_near`` / ``zeros_far``: share of the windows' values (the last ζ of each leaf) that come
  from reached points and exploration samples (competence 0, ``count_reached``, Sec. 2.5);
- ``interest_near`` / ``interest_far``: mean interest (Sec. 2.4.3, ``regions.interest``) of the near
  and far leaves, and ``shuffled_near`` / ``shuffled_far``: the same with each window's values in a
  random order (mean of ``--shuffles`` permutations), i.e. what the interest is worth when the
  values carry no trend at all. Interest well above its shuffled value is progress; equal to it is
  the window's spread of values (its mixture of 0s and goal competences), not progress;
- ``mass_near_goals_only``: ``mass_near`` if each leaf's interest were taken over its goal and
  subgoal competences only (the last ζ of them), leaving the reached points out;
- ``mass_near_by_area``: ``mass_near`` if each leaf's probability were also weighted by its area
  (not the paper: a counterfactual that removes the effect of the number of leaves).

Prints per variant, means ± std over seeds, and writes ``anatomy.json`` and ``anatomy.png`` in
``--out``.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from sagg_common.params import parse_set
from sagg_common.regions import interest, interest_probabilities
from sagg_common.report_kinds import KIND_GOAL, KIND_SUBGOAL

from sagg_bringup.graph.setups import in_process_run

FIELDS = ("mass_near", "area_near", "leaves_near", "zeros_near", "zeros_far", "interest_near",
          "interest_far", "shuffled_near", "shuffled_far", "mass_near_goals_only", "mass_near_by_area")


def parse_variant(text: str) -> tuple[str, dict]:
    """``strategy[:NAME=VALUE,...]`` -> (strategy, overrides)."""
    strategy, _, rest = text.partition(":")
    return strategy, parse_set([item for item in rest.split(",") if item])


def shuffled_interest(values: np.ndarray, zeta: int, shuffles: int, rng: np.random.Generator) -> float:
    """Mean of :func:`interest` over ``shuffles`` random orders of the last ζ values: the interest a
    window of these values has when their order carries no trend."""
    window = values[len(values) - min(zeta, len(values)):]
    if len(window) < 2:
        return 0.0
    orders = rng.permuted(np.tile(window, (shuffles, 1)), axis=1)
    return float(np.mean([interest(o, zeta) for o in orders]))


class Log:
    """What the goal generator's tree received (kind of report, point, value) and what it chose, for one run."""

    def __init__(self, generator, center: np.ndarray, radius: float, every: int, shuffles: int, seed: int):
        self.gen, self.center, self.radius, self.every, self.shuffles = generator, center, radius, every, shuffles
        self.kinds: list[int] = []
        self.points: list[np.ndarray] = []
        self.values: list[float] = []
        self.goals: list[dict] = []
        self.rows: list[dict] = []
        self.rng = np.random.default_rng(seed)
        report, next_goal, add = generator.report, generator.next_goal, generator.tree.add
        kind_now = [None]

        def logged_report(kind, target, competence):
            kind_now[0] = int(kind)
            report(kind, target, competence)

        def logged_add(y, value, stamp=None):  # what the tree takes (count_reached decides for reached points)
            self.kinds.append(kind_now[0])
            self.points.append(np.asarray(y, dtype=float))
            self.values.append(float(value))
            return add(y, value, stamp=stamp)

        def logged_next_goal():
            leaves = generator.tree.leaves()
            if len(leaves) >= 2 and len(self.goals) % every == 0:
                self.rows.append(self.look(leaves))
            rec = next_goal()
            self.goals.append({"seq": rec.seq, "mode": rec.mode, "position": rec.position.tolist(),
                               "reports": len(self.values),
                               "distance": float(np.linalg.norm(rec.position - center))})
            return rec

        generator.report, generator.next_goal, generator.tree.add = logged_report, logged_next_goal, logged_add

    def look(self, leaves) -> dict:
        """The fields of the module docstring for the tree as it is now."""
        zeta = self.gen.tree.zeta
        lower, upper = self.gen.lower, self.gen.upper
        centers = np.array([(r.lower + r.upper) / 2 for r in leaves])
        areas = np.array([np.prod(r.upper - r.lower) for r in leaves]) / np.prod(upper - lower)
        near = np.linalg.norm(centers - self.center, axis=1) <= self.radius
        probs = interest_probabilities(np.array([r.interest for r in leaves]))
        pts, kinds, vals = np.array(self.points), np.array(self.kinds), np.array(self.values)
        goal_kind = (kinds == KIND_GOAL) | (kinds == KIND_SUBGOAL)
        inside_y = np.all((pts >= lower) & (pts <= upper), axis=1)
        goals_only, zero_share, observed, shuffled = [], [], [], []
        for r in leaves:
            inside = inside_y & np.all((pts >= r.lower) & (pts <= r.upper), axis=1)
            win = np.flatnonzero(inside)[-zeta:]
            zero_share.append(float(np.mean(~goal_kind[win])) if len(win) else np.nan)
            gv = vals[inside & goal_kind]
            goals_only.append(interest(gv, zeta))
            observed.append(r.interest)
            shuffled.append(shuffled_interest(r.filled_values, zeta, self.shuffles, self.rng))
        goals_only, zero_share = np.array(goals_only), np.array(zero_share)
        observed, shuffled = np.array(observed), np.array(shuffled)

        def mean(a, m):
            return float(np.nanmean(a[m])) if m.any() and np.isfinite(a[m]).any() else np.nan

        return {"goals": len(self.goals), "leaves": len(leaves),
                "mass_near": float(probs[near].sum()), "area_near": float(areas[near].sum()),
                "leaves_near": float(near.mean()),
                "zeros_near": mean(zero_share, near), "zeros_far": mean(zero_share, ~near),
                "interest_near": mean(observed, near), "interest_far": mean(observed, ~near),
                "shuffled_near": mean(shuffled, near), "shuffled_far": mean(shuffled, ~near),
                "mass_near_goals_only": float(interest_probabilities(goals_only)[near].sum()),
                "mass_near_by_area": float((probs * areas)[near].sum() / max((probs * areas).sum(), 1e-300))}


def anatomy(config: str, strategy: str, overrides: dict, seed: int, micro_actions: int, radius: float,
            every: int, shuffles: int) -> dict:
    run = in_process_run(config, dict(overrides, strategy=strategy, seed=seed))
    center = np.asarray(run.sim.observe()[1], dtype=float)  # the rest tip (the arm starts at rest)
    log = Log(run.generator, center, radius, every, shuffles, seed)
    run.step_until(micro_actions)
    d = np.array([g["distance"] for g in log.goals])
    quarters = [float(np.mean(q <= radius)) for q in np.array_split(d, 4)]
    summary = {f: float(np.nanmean([r[f] for r in log.rows])) if log.rows else np.nan for f in FIELDS}
    return {"seed": seed, "rest_tip": center.tolist(), "goals": len(log.goals),
            "goals_near_by_quarter": quarters, "goals_near": float(np.mean(d <= radius)),
            "final_leaves": len(run.generator.tree.leaves()), "summary": summary, "rows": log.rows,
            "goal_log": log.goals}


def _ms(values) -> str:
    v = np.asarray(values, dtype=float)
    return f"{np.nanmean(v):.3f} ± {np.nanstd(v):.3f}"


def table(results: dict[str, list[dict]]) -> str:
    heads = ["goals near, all", "1st quarter", "4th quarter"] + list(FIELDS)
    lines = ["| variant | " + " | ".join(heads) + " |", "|---|" + "---|" * len(heads)]
    for name, runs in results.items():
        cells = [_ms([r["goals_near"] for r in runs]), _ms([r["goals_near_by_quarter"][0] for r in runs]),
                 _ms([r["goals_near_by_quarter"][3] for r in runs])]
        cells += [_ms([r["summary"][f] for r in runs]) for f in FIELDS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(results: dict[str, list[dict]], radius: float, path: Path) -> None:
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for name, runs in results.items():
        # share of goals within the radius, over the goals' order (10 bins), mean over seeds
        bins = np.array([[np.mean(b <= radius) for b in np.array_split([g["distance"] for g in r["goal_log"]], 10)]
                         for r in runs])
        axes[0].plot(np.arange(1, 11) / 10, bins.mean(axis=0), marker="o", label=name)
        rows = [r["rows"] for r in runs if r["rows"]]
        if rows:
            n = min(len(x) for x in rows)
            mass = np.array([[x[i]["mass_near"] for i in range(n)] for x in rows]).mean(axis=0)
            area = np.array([[x[i]["area_near"] for i in range(n)] for x in rows]).mean(axis=0)
            t = np.linspace(0, 1, n)
            line, = axes[1].plot(t, mass, label=f"{name}: mode-1 mass near")
            axes[1].plot(t, area, color=line.get_color(), linestyle=":", label=f"{name}: area near")
            obs = np.array([[x[i]["interest_near"] for i in range(n)] for x in rows])
            shf = np.array([[x[i]["shuffled_near"] for i in range(n)] for x in rows])
            axes[2].plot(t, np.nanmean(obs, axis=0), color=line.get_color(), label=f"{name}: near, observed")
            axes[2].plot(t, np.nanmean(shf, axis=0), color=line.get_color(), linestyle="--",
                         label=f"{name}: near, shuffled")
    axes[0].set(xlabel="share of the run's goals", ylabel=f"goals within {radius:g} of the rest tip",
                title="where the goals went")
    axes[1].set(xlabel="share of the run", ylabel="share", title="near leaves: selection mass vs area")
    axes[2].set(xlabel="share of the run", ylabel="mean interest", title="interest: observed vs values shuffled")
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.interest_anatomy", description=__doc__.split("::")[0])
    ap.add_argument("--config", default="config/arm8.yaml")
    ap.add_argument("--variants", nargs="+", default=["sagg-riac", "sagg-random"],
                    help="strategy[:NAME=VALUE,...] each")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--micro-actions", type=int, default=10_000)
    ap.add_argument("--radius", type=float, default=10.0, help="near: within this distance of the rest tip")
    ap.add_argument("--every", type=int, default=5, help="look at the tree every this many goals")
    ap.add_argument("--shuffles", type=int, default=50)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, list[dict]] = {}
    for v in a.variants:
        strategy, overrides = parse_variant(v)
        results[v] = []
        for seed in range(a.seeds):
            results[v].append(anatomy(a.config, strategy, overrides, seed, a.micro_actions, a.radius, a.every,
                                      a.shuffles))
            print(f"{v} seed {seed}: goals near {results[v][-1]['goals_near']:.2f}", flush=True)
    (out / "anatomy.json").write_text(json.dumps({"args": vars(a), "results": results}))
    figure(results, a.radius, out / "anatomy.png")
    print(table(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
