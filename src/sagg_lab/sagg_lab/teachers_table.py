"""The side-by-side of the goal strategies over several set-ups, from the output directories of
``sagg bench compare``::

    python -m sagg_lab.teachers_table --out DIR arm8=/tmp/cmp/arm8 quadruped=/tmp/cmp/q1,/tmp/cmp/q2 ...

(a set-up's runs may come from several directories, comma-separated: e.g. the teachers' runs
beside an archive's runs of the paper's strategies on the same seeds, budget and test goals).

Per set-up: each strategy's final mean test error (mean ± std over seeds), and each strategy
against ``--baseline`` (default sagg-random): two-sided Mann-Whitney p and Welch p on the final
errors (``experiments.compare.pairwise_tests``), marked where p < 0.05 (better or worse); then
where the goals went (``experiments.mechanisms``: goals in the reachable area in the second
half, coverage of the test goals, test goals within tolerance), and where each teacher's own
interest lay (:func:`interest_on_reachable`: the share of its choice weight on the reachable area,
and for the grid the mean competence inside and outside it). Writes ``teachers.md`` and
``teachers_curves.png`` (one panel per set-up, mean ± std over seeds) in ``--out``.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from sagg_common.params import GOAL_STRATEGIES, STRATEGIES

from sagg_bringup.experiments.compare import by_strategy, curve_stats, load_results, pairwise_tests
from sagg_bringup.experiments.mechanisms import strategy_mechanisms
from sagg_bringup.report.report import reachable_mask

ALPHA = 0.05
MECHANISMS = (("goal_share_reachable_second_half", "reachable goals, 2nd half", "{:.0%}"),
              ("coverage_median", "coverage (median)", "{:.3g}"), ("within_share", "within tolerance", "{:.0%}"))


def interest_on_reachable(result: dict) -> dict | None:
    """Where a teacher's choice weight lay, from its snapshot in ``result`` (None for the paper's
    strategies or a run without a reachable area): ``discretized-progress``: the share of the
    final |progress| on cells centred in the reachable area, and the mean normalised competence
    of the windows of the cells inside and outside it; ``alp-gmm``: the share of the choice weight
    (∝ mean ALP) on components centred in the reachable area, averaged over the second half of its
    fits (the bootstrap chose uniformly)."""
    t = result.get("teacher")
    area = reachable_mask(result) if t else None
    if area is None:
        return None
    if t["teacher"] == "discretized-progress":
        shape = np.array(t["shape"])
        lower, upper = np.array(t["lower"]), np.array(t["upper"])
        idx = np.array(np.unravel_index(np.arange(int(shape.prod())), tuple(shape))).T
        inside = area.contains(lower + (idx + 0.5) * (upper - lower) / shape)
        progress, comp = np.abs(np.array(t["progress"])), np.array(t["competence"])
        return {"share": float(progress[inside].sum() / progress.sum()) if progress.sum() > 0 else math.nan,
                "competence_inside": float(comp[inside].mean()), "competence_outside": float(comp[~inside].mean())}
    fits = t["fits"][len(t["fits"]) // 2:]
    if not fits:
        return {"share": math.nan}
    shares = []
    for f in fits:
        means = np.array(f["means"])
        alp = np.clip(means[:, -1], 0.0, None)
        w = alp / alp.sum() if alp.sum() > 0 else np.full(len(alp), 1.0 / len(alp))
        shares.append(float(w[area.contains(means[:, :-1])].sum()))
    return {"share": float(np.mean(shares)), "fits": len(t["fits"])}


def setup_rows(name: str, directories: str, baseline: str) -> dict:
    groups = by_strategy(load_results(directories.split(",")))
    if baseline not in groups:
        raise SystemExit(f"{name}: no {baseline} runs under {directories}")
    base = [r["final_mean_error"] for r in groups[baseline]]
    rows = {}
    for strategy, runs in groups.items():
        final = [r["final_mean_error"] for r in runs]
        rows[strategy] = {"seeds": len(runs), "mean": float(np.mean(final)), "std": float(np.std(final, ddof=1)),
                          "budget": runs[0]["curve"][-1]["micro_actions"],
                          **({} if strategy == baseline else pairwise_tests(final, base))}
    interest = {}
    for strategy, runs in groups.items():
        found = [x for x in map(interest_on_reachable, runs) if x is not None]
        if found:
            interest[strategy] = {k: float(np.nanmean([x.get(k, math.nan) for x in found])) for k in found[0]}
    return {"name": name, "rows": rows, "mechanisms": strategy_mechanisms(groups), "groups": groups,
            "interest": interest}


def _rank(strategy: str) -> int:
    """A strategy's column and colour: the goal strategies first, then the paper's others."""
    order = list(GOAL_STRATEGIES) + [s for s in STRATEGIES if s not in GOAL_STRATEGIES]
    return order.index(strategy) if strategy in order else len(order)


def _verdict(row: dict, base_mean: float) -> str:
    p = row.get("mannwhitney_p", math.nan)
    if not p < ALPHA:
        return ""
    return " **better**" if row["mean"] < base_mean else " **worse**"


def markdown(setups: list[dict], baseline: str) -> str:
    strategies = sorted({s for st in setups for s in st["rows"]}, key=_rank)
    head = ["set-up", "seeds × budget"] + strategies
    lines = [f"Final mean test error (mean ± std over seeds); for each strategy against {baseline}: two-sided "
             f"Mann-Whitney p / Welch p, **better** or **worse** where the Mann-Whitney p < {ALPHA}.", "",
             "| " + " | ".join(head) + " |", "|---|---|" + "---|" * len(strategies)]
    for st in setups:
        rows, base = st["rows"], st["rows"][baseline]
        any_row = next(iter(rows.values()))
        cells = [st["name"], f"{any_row['seeds']} × {any_row['budget']:,}"]
        for s in strategies:
            r = rows.get(s)
            if r is None:
                cells.append("–")
            elif s == baseline:
                cells.append(f"{r['mean']:.4g} ± {r['std']:.2g}")
            else:
                cells.append(f"{r['mean']:.4g} ± {r['std']:.2g} (p {r['mannwhitney_p']:.2g} / "
                             f"{r['welch_p']:.2g}){_verdict(r, base['mean'])}")
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Where the goals went (means over seeds): " + "; ".join(label for _, label, _ in MECHANISMS) + ".",
              "", "| set-up | " + " | ".join(strategies) + " |", "|---|" + "---|" * len(strategies)]
    for st in setups:
        cells = []
        for s in strategies:
            m = st["mechanisms"].get(s)
            cells.append("–" if m is None else " / ".join(
                "–" if not np.isfinite(m[k]) else fmt.format(m[k]) for k, _, fmt in MECHANISMS))
        lines.append(f"| {st['name']} | " + " | ".join(cells) + " |")
    lines += ["", "Where each teacher's interest lay: share of its choice weight on the reachable area "
              "(discretized-progress: final |progress| of the cells, with the windows' mean normalised "
              "competence inside / outside; alp-gmm: components by mean ALP, second half of its fits).", "",
              "| set-up | discretized-progress | alp-gmm |", "|---|---|---|"]
    for st in setups:
        dp, alp = st["interest"].get("discretized-progress"), st["interest"].get("alp-gmm")
        cells = ["–" if dp is None else f"{dp['share']:.0%} (competence {dp['competence_inside']:.2f} / "
                 f"{dp['competence_outside']:.2f})",
                 "–" if alp is None or not np.isfinite(alp["share"]) else
                 f"{alp['share']:.0%} ({alp['fits']:.0f} fits)"]
        lines.append(f"| {st['name']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def figure(setups: list[dict], path: Path) -> None:
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt
    cols = min(4, len(setups))
    rows = math.ceil(len(setups) / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax, st in zip(axes.flat, setups):
        for strategy in sorted(st["groups"], key=_rank):
            c = curve_stats(st["groups"][strategy])
            x, m, s = np.array(c["micro_actions"]), np.array(c["mean"]), np.array(c["std"])
            color = plt.cm.tab10(_rank(strategy) % 10)
            ax.plot(x, m, marker="o", ms=3, label=strategy, color=color)
            ax.fill_between(x, np.maximum(m - s, m / 10), m + s, color=color, alpha=0.12)  # (log axis: floored)
        ax.set(title=st["name"], xlabel="micro-actions", ylabel="mean test error", yscale="log")
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(setups):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.teachers_table", description=__doc__.split("::")[0])
    ap.add_argument("setups", nargs="+", metavar="NAME=DIR[,DIR...]")
    ap.add_argument("--baseline", default="sagg-random")
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    setups = []
    for item in a.setups:
        name, sep, directory = item.partition("=")
        if not sep:
            ap.error(f"{item!r}: expected NAME=DIR[,DIR...]")
        setups.append(setup_rows(name, directory, a.baseline))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    text = markdown(setups, a.baseline)
    (out / "teachers.md").write_text(text)
    figure(setups, out / "teachers_curves.png")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
