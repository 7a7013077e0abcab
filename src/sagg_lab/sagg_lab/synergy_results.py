"""Tables and figures of the synergy experiments for docs/notes/early-results.md:
``python -m sagg_lab.synergy_results RUNS_DIR FIG_DIR`` reads every ``result.json`` under
RUNS_DIR (``sagg experiment`` runs of config/quadruped.yaml and config/fishing.yaml) and prints
Markdown: explored extents per strategy (Sec. 4.5), test-error curves (Sec. 4.6, 5.3) with Mann-Whitney
tests over seeds; it draws the explored (u, v) positions, the float-position histograms (Sec. 5.2)
and the error curves into FIG_DIR.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sagg_bringup.experiments.compare import by_strategy, curve_stats, load_results, pairwise_tests

ORDER = ("sagg-riac", "sagg-random", "actuator-random", "actuator-riac")


def _fmt(lo, hi) -> str:
    return f"[{lo:.1f}, {hi:.1f}]"


def extents_table(groups: dict[str, list[dict]], dims: tuple[str, ...]) -> str:
    rows = ["| strategy | seeds | experiments | trials (discarded) | "
            + " | ".join(f"{d}: 1st-99th pct (min-max)" for d in dims) + " | final mean error |",
            "|---" * (5 + len(dims)) + "|"]
    for s in ORDER:
        if s not in groups:
            continue
        rs = groups[s]
        ys = np.concatenate([np.array(r["synergy"]["outcomes"]) for r in rs])
        cells = []
        for j in range(len(dims)):
            p1, p99 = np.percentile(ys[:, j], [1, 99])
            cells.append(f"{_fmt(p1, p99)} ({_fmt(ys[:, j].min(), ys[:, j].max())})")
        trials = sum(r["synergy"]["trials"] for r in rs)
        disc = sum(r["synergy"]["discarded"] for r in rs)
        fin = np.array([r["final_mean_error"] for r in rs])
        err = f"{fin.mean():.3f}" + (f" ± {fin.std(ddof=1):.3f}" if len(fin) > 1 else "")
        rows.append(f"| {s} | {len(rs)} | {rs[0]['micro_actions']} | {trials} ({disc}) | "
                    + " | ".join(cells) + f" | {err} |")
    return "\n".join(rows)


def spread_ratio(groups, dim: int) -> dict[str, float]:
    """Width of the 1st-99th percentile interval of dimension ``dim`` per strategy."""
    out = {}
    for s, rs in groups.items():
        ys = np.concatenate([np.array(r["synergy"]["outcomes"]) for r in rs])
        p1, p99 = np.percentile(ys[:, dim], [1, 99])
        out[s] = float(p99 - p1)
    return out


def curves_table(groups) -> str:
    stats = {s: curve_stats(groups[s]) for s in ORDER if s in groups}
    xs = next(iter(stats.values()))["micro_actions"]
    rows = ["| experiments | " + " | ".join(stats) + " |", "|---" * (1 + len(stats)) + "|"]
    for i, x in enumerate(xs):
        cells = []
        for s, st in stats.items():
            if i < len(st["mean"]):
                cells.append(f"{st['mean'][i]:.3f}" + (f" ± {st['std'][i]:.3f}" if st["n"] > 1 else ""))
            else:
                cells.append("")
        rows.append(f"| {x} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def tests_table(groups, at_indices=None) -> str:
    strategies = [s for s in ORDER if s in groups]
    if len(strategies) < 2 or min(len(groups[s]) for s in strategies) < 2:
        return ""
    a, b = strategies[0], strategies[1]
    xs = [c["micro_actions"] for c in groups[a][0]["curve"]]
    rows = [f"| experiments | {a} mean | {b} mean | Mann-Whitney p ({a} < {b}) | two-sided p | Welch p |",
            "|---|---|---|---|---|---|"]
    for i, x in enumerate(xs):
        if at_indices is not None and i not in at_indices:
            continue
        ea = [r["curve"][i]["mean_error"] for r in groups[a]]
        eb = [r["curve"][i]["mean_error"] for r in groups[b]]
        t = pairwise_tests(ea, eb)
        rows.append(f"| {x} | {np.mean(ea):.3f} | {np.mean(eb):.3f} | {t['mannwhitney_p_less']:.3g} | "
                    f"{t['mannwhitney_p']:.3g} | {t['welch_p']:.3g} |")
    return "\n".join(rows)


def plot_quadruped(groups, path: Path) -> None:
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt
    strategies = [s for s in ORDER if s in groups]
    fig, axes = plt.subplots(1, len(strategies) + 1, figsize=(4 * (len(strategies) + 1), 4))
    for ax, s in zip(axes, strategies):
        ys = np.array(groups[s][0]["synergy"]["outcomes"])
        ax.scatter(ys[:, 0], ys[:, 1], s=1, alpha=0.3)
        ax.set_xlim(-15, 15)
        ax.set_ylim(-15, 15)
        ax.set_aspect("equal")
        ax.set_title(f"{s} ({len(ys)} exp.)")
        ax.set_xlabel("u")
        ax.set_ylabel("v")
    ax = axes[-1]
    for s in strategies:
        st = curve_stats(groups[s])
        ax.plot(st["micro_actions"], st["mean"], label=s)
    ax.set_xlabel("experiments")
    ax.set_ylabel("mean test error (100 goals)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_fishing(groups, path: Path) -> None:
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt
    strategies = [s for s in ORDER if s in groups]
    fig, axes = plt.subplots(1, len(strategies) + 1, figsize=(4.2 * (len(strategies) + 1), 4))
    for ax, s in zip(axes, strategies):
        ys = np.concatenate([np.array(r["synergy"]["outcomes"]) for r in groups[s]])
        h = ax.hist2d(ys[:, 0], ys[:, 1], bins=40, range=[[-1.2, 1.2], [-1.2, 1.2]], cmap="viridis")
        fig.colorbar(h[3], ax=ax)
        ax.plot([0], [0], "r+")
        ax.set_aspect("equal")
        ax.set_title(f"{s}: {len(ys)} contacts, {len(groups[s])} seeds")
        ax.set_xlabel("x")
        ax.set_ylabel("y")
    ax = axes[-1]
    for s in strategies:
        st = curve_stats(groups[s])
        m, sd = np.array(st["mean"]), np.array(st["std"])
        ax.plot(st["micro_actions"], m, label=f"{s} (n={st['n']})")
        ax.fill_between(st["micro_actions"], m - sd, m + sd, alpha=0.2)
    ax.set_xlabel("contacts (experiments)")
    ax.set_ylabel("mean test error (100 goals)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    runs, figs = Path(argv[0]), Path(argv[1])
    figs.mkdir(parents=True, exist_ok=True)
    results = [r for r in load_results([runs]) if "synergy" in r]
    for setup, dims in (("quadruped", ("u", "v", "φ")), ("fishing", ("x", "y"))):
        rs = [r for r in results if r["synergy"]["setup"] == setup]
        if not rs:
            continue
        groups = by_strategy(rs)
        print(f"## {setup}\n")
        print(extents_table(groups, dims) + "\n")
        if setup == "quadruped":
            for j, d in enumerate(dims[:2]):
                w = spread_ratio(groups, j)
                base = max(w.get("actuator-random", np.nan), w.get("actuator-riac", np.nan))
                print(f"{d}: 1st-99th percentile widths " + ", ".join(f"{s} {v:.1f}" for s, v in w.items())
                      + (f"; sagg-riac / max(actuator-*) = {w['sagg-riac'] / base:.2f}" if "sagg-riac" in w
                         and np.isfinite(base) else "") + "\n")
            plot_quadruped(groups, figs / "results_quadruped.png")
        else:
            plot_fishing(groups, figs / "results_fishing.png")
        print(curves_table(groups) + "\n")
        t = tests_table(groups)
        if t:
            print(t + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
