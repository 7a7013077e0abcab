"""Compare strategies across seeds from result.json files: tables and statistical tests."""
from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
from scipy import stats


def load_results(paths) -> list[dict]:
    """Every result.json under the given directories (or the files themselves)."""
    out = []
    for p in map(Path, paths):
        files = [p] if p.is_file() else sorted(p.rglob("result.json"))
        for f in files:
            out.append(json.loads(f.read_text()))
    return out


def by_strategy(results: list[dict]) -> dict[str, list[dict]]:
    groups: dict[str, list[dict]] = {}
    for r in results:
        groups.setdefault(r["strategy"], []).append(r)
    for g in groups.values():
        g.sort(key=lambda r: r["seed"])
    return groups


def pairwise_tests(a: np.ndarray, b: np.ndarray) -> dict:
    """Two-sided Mann-Whitney U (rank) and Welch t-test between two samples of final errors."""
    if len(a) < 2 or len(b) < 2:
        return {"mannwhitney_p": float("nan"), "welch_p": float("nan")}
    return {"mannwhitney_p": float(stats.mannwhitneyu(a, b, alternative="two-sided").pvalue),
            "welch_p": float(stats.ttest_ind(a, b, equal_var=False).pvalue)}


def summary_markdown(results: list[dict]) -> str:
    """Final test error per strategy (mean ± std over seeds, per seed), goal shares, and
    pairwise tests, as Markdown."""
    groups = by_strategy(results)
    lines = ["| strategy | seeds | final mean error (mean ± std) | median of seeds | per seed | "
             "goals in reachable area, 2nd half | reachable share of Y |",
             "|---|---|---|---|---|---|---|"]
    finals = {}
    for name, rs in groups.items():
        f = np.array([r["final_mean_error"] for r in rs])
        finals[name] = f
        share = [r["goal_stats"]["goal_share_reachable_second_half"] for r in rs]
        share_txt = ("—" if all(np.isnan(s) for s in share)
                     else f"{np.nanmean(share):.1%} ({', '.join(f'{s:.0%}' for s in share)})")
        lines.append(
            f"| {name} | {len(rs)} | {f.mean():.3f} ± {f.std(ddof=1) if len(f) > 1 else 0:.3f} | "
            f"{np.median(f):.3f} | {', '.join(f'{x:.2f}' for x in f)} | {share_txt} | "
            f"{rs[0]['goal_stats']['reachable_share_of_Y']:.1%} |")
    lines += ["", "| A | B | Mann-Whitney U p | Welch t p |", "|---|---|---|---|"]
    for a, b in itertools.combinations(groups, 2):
        t = pairwise_tests(finals[a], finals[b])
        lines.append(f"| {a} | {b} | {t['mannwhitney_p']:.3g} | {t['welch_p']:.3g} |")
    return "\n".join(lines)


def plot_curves(results: list[dict], path, title: str = "", key: str = "mean_error") -> None:
    """Test error against micro-actions, one line per strategy: mean over seeds with a shaded
    ±1 std band (like the paper's Figs. 10-12)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for name, rs in by_strategy(results).items():
        xs = [c["micro_actions"] for c in rs[0]["curve"]]
        ys = np.array([[c[key] for c in r["curve"]] for r in rs if len(r["curve"]) == len(xs)])
        m, s = ys.mean(axis=0), ys.std(axis=0)
        ax.plot(xs, m, label=f"{name} (n={len(ys)})")
        ax.fill_between(xs, np.maximum(m - s, 1e-3), m + s, alpha=0.2)
    ax.set_yscale("log")
    ax.set_xlabel("micro-actions")
    ax.set_ylabel(f"test error ({key.replace('_', ' ')}, task units)")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
