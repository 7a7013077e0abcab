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


def pairwise_tests(a, b) -> dict:
    """Two-sided Mann-Whitney U (rank) and Welch t-test between two samples of final errors
    (scipy: exact U distribution for small samples without ties), plus the one-sided
    Mann-Whitney p of "a lower than b" (the paper's claims are orderings)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    nan = float("nan")
    if len(a) < 2 or len(b) < 2:
        return {"mannwhitney_u": nan, "mannwhitney_p": nan, "mannwhitney_p_less": nan,
                "welch_t": nan, "welch_p": nan}
    mw = stats.mannwhitneyu(a, b, alternative="two-sided")
    less = stats.mannwhitneyu(a, b, alternative="less")
    w = stats.ttest_ind(a, b, equal_var=False)
    return {"mannwhitney_u": float(mw.statistic), "mannwhitney_p": float(mw.pvalue),
            "mannwhitney_p_less": float(less.pvalue),
            "welch_t": float(w.statistic), "welch_p": float(w.pvalue)}


def curve_stats(results: list[dict], key: str = "mean_error") -> dict:
    """Mean, std (ddof 1; 0 for one seed) and median over seeds of ``key`` at each evaluation
    point of runs that share the same evaluation points."""
    xs = [c["micro_actions"] for c in results[0]["curve"]]
    ys = np.array([[c[key] for c in r["curve"]] for r in results
                   if [c["micro_actions"] for c in r["curve"]] == xs])
    std = ys.std(axis=0, ddof=1) if len(ys) > 1 else np.zeros(len(xs))
    return {"micro_actions": xs, "mean": ys.mean(axis=0).tolist(), "std": std.tolist(),
            "median": np.median(ys, axis=0).tolist(), "n": int(len(ys))}


def final_metrics(results: list[dict]) -> dict:
    """The evaluation's other metrics at the last point (sagg_low_level.eval_metrics), per seed and
    averaged over seeds: the median test error, the share of test goals within tolerance, and the
    mean error per distance-from-base band (with the band edges). Runs written before these
    metrics existed give None."""
    last = [r["curve"][-1] for r in results]
    med = [c.get("median_error") for c in last]
    within = [c.get("within_share") for c in last]
    bands = [c.get("band_mean_errors") for c in last]
    frame = results[0].get("eval_metrics") if results else None
    out = {"final_median_error": med, "final_within_share": within,
           "mean_of_median_errors": float(np.mean(med)) if None not in med else None,
           "mean_within_share": float(np.mean(within)) if None not in within else None,
           "band_edges": frame["band_edges"] if frame else None,
           "within": frame["within"] if frame else None, "band_mean_errors": None}
    if bands and None not in bands:
        cols = list(zip(*bands))
        out["band_mean_errors"] = [None if None in c else float(np.mean(c)) for c in cols]
    return out


def summary_json(results: list[dict], order: list[str] | None = None) -> dict:
    """Per strategy: seeds, final errors, curve statistics; every pair: the tests above."""
    groups = by_strategy(results)
    names = [n for n in (order or list(groups)) if n in groups]
    out = {"strategies": {}, "tests": []}
    for n in names:
        rs = groups[n]
        f = np.array([r["final_mean_error"] for r in rs])
        out["strategies"][n] = {
            "seeds": [r["seed"] for r in rs], "final_mean_error": f.tolist(),
            "final_mean": float(f.mean()), "final_std": float(f.std(ddof=1)) if len(f) > 1 else 0.0,
            "final_median": float(np.median(f)), "curve": curve_stats(rs),
            "goal_share_reachable_second_half": [r["goal_stats"]["goal_share_reachable_second_half"]
                                                 for r in rs],
            **final_metrics(rs)}
    for a, b in itertools.combinations(names, 2):
        t = pairwise_tests(out["strategies"][a]["final_mean_error"],
                           out["strategies"][b]["final_mean_error"])
        out["tests"].append({"a": a, "b": b, **t})
    return out


def curve_table(summary: dict) -> str:
    """Markdown: one row per evaluation point, one column per strategy (mean ± std over seeds)."""
    names = list(summary["strategies"])
    xs = summary["strategies"][names[0]]["curve"]["micro_actions"]
    lines = ["| micro-actions | " + " | ".join(f"{n} (n={summary['strategies'][n]['curve']['n']})"
                                              for n in names) + " |",
             "|---|" + "---|" * len(names)]
    for i, x in enumerate(xs):
        cells = []
        for n in names:
            c = summary["strategies"][n]["curve"]
            cells.append(f"{c['mean'][i]:.3f} ± {c['std'][i]:.3f}" if i < len(c["mean"]) else "—")
        lines.append(f"| {x} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def pairwise_table(summary: dict) -> str:
    """Markdown: Mann-Whitney U and Welch t (statistics and two-sided p) for every pair, and the
    one-sided Mann-Whitney p that A is below B."""
    lines = ["| A | B | mean A | mean B | Mann-Whitney U | p (two-sided) | p (A < B) | Welch t | "
             "p (two-sided) |", "|---|---|---|---|---|---|---|---|---|"]
    for t in summary["tests"]:
        ma = summary["strategies"][t["a"]]["final_mean"]
        mb = summary["strategies"][t["b"]]["final_mean"]
        lines.append(f"| {t['a']} | {t['b']} | {ma:.3f} | {mb:.3f} | {t['mannwhitney_u']:.1f} | "
                     f"{t['mannwhitney_p']:.3g} | {t['mannwhitney_p_less']:.3g} | "
                     f"{t['welch_t']:.3f} | {t['welch_p']:.3g} |")
    return "\n".join(lines)


def _other_metrics(results: list[dict]) -> str:
    """Table cells: mean over seeds of the final median error, of the share within tolerance, and
    of the mean error per distance band (edges in task units); — for runs without these metrics."""
    m = final_metrics(results)
    med = "—" if m["mean_of_median_errors"] is None else f"{m['mean_of_median_errors']:.3f}"
    within = ("—" if m["mean_within_share"] is None
              else f"{m['mean_within_share']:.0%} (≤ {m['within']:.3g})")
    if m["band_mean_errors"] is None:
        bands = "—"
    else:
        e = m["band_edges"]
        bands = ", ".join(f"[{e[i]:.3g}, {e[i + 1]:.3g}]: " + ("—" if v is None else f"{v:.3f}")
                          for i, v in enumerate(m["band_mean_errors"]))
    return f"{med} | {within} | {bands}"


def summary_markdown(results: list[dict], tests: bool = True) -> str:
    """Final test error per strategy (mean ± std over seeds, per seed), goal shares, and
    (``tests``) pairwise tests, as Markdown."""
    groups = by_strategy(results)
    lines = ["| strategy | seeds | final mean error (mean ± std) | median of seeds | per seed | "
             "goals in reachable area, 2nd half | reachable share of Y | median error | "
             "within tolerance | mean error by distance band |",
             "|---|---|---|---|---|---|---|---|---|---|"]
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
            f"{rs[0]['goal_stats']['reachable_share_of_Y']:.1%} | {_other_metrics(rs)} |")
    if not tests:
        return "\n".join(lines)
    lines += ["", "| A | B | Mann-Whitney U p | Welch t p |", "|---|---|---|---|"]
    for a, b in itertools.combinations(groups, 2):
        t = pairwise_tests(finals[a], finals[b])
        lines.append(f"| {a} | {b} | {t['mannwhitney_p']:.3g} | {t['welch_p']:.3g} |")
    return "\n".join(lines)


def plot_curves(results: list[dict], path, title: str = "", key: str = "mean_error") -> None:
    """Test error against micro-actions, one line per strategy: mean over seeds with a shaded
    ±1 std band (ddof 1; like the paper's Figs. 10-12)."""
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for name, rs in by_strategy(results).items():
        c = curve_stats(rs, key)
        xs, m, s = c["micro_actions"], np.array(c["mean"]), np.array(c["std"])
        ax.plot(xs, m, label=f"{name} (n={c['n']})")
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
