"""``sagg reproduce CLAIM|all``: settle the paper's claims, each at its own set-up and scale.

The claims and the experiments they are decided on are data (``claims.yaml`` next to this module).
Every experiment runs through ``sagg bench compare`` (:func:`sagg_bringup.experiments.sweep.run_compare`): the
same runs, the same resumable layout and the same statistics (:mod:`sagg_bringup.experiments.compare`). This
module only picks the experiments, reads their ``summary.json`` and writes the verdicts.

Layout of ``--out DIR``::

    DIR/experiments/<experiment>/...   one `sagg bench compare` directory each (resumable)
    DIR/claims.json                    a list: one entry per claim (fields: CLAIM_FIELDS)
    DIR/report.md, DIR/figures/*.png   verdict table, curves with seed spread, goal histograms

Verdict rules (written in claims.yaml too): per pair [A, B] of a claim ("A is better than B"),
*reproduced* when A is better in the mean over seeds and the claim's two-sided p < alpha, *not
reproduced* when B is better and p < alpha, else *inconclusive*; a claim is reproduced when all its
pairs are, not reproduced when any pair is, inconclusive otherwise. Its ``p_value`` is the largest p
of its pairs (the weakest link) unless it is not reproduced, then the smallest p of its pairs that
went the other way significantly.
"""
from __future__ import annotations

import math
import os
import shutil
import sys
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from sagg_common.journal import write_json_atomic
from sagg_common.params import STRATEGIES, ConfigError

from .archive import archive_experiment, archive_run, histogram_counts, histogram_of, restore_experiment
from .mechanisms import mechanism_table, strategy_mechanisms
from ..inprocess.results import code_commit, run_commits

REGISTRY = Path(__file__).with_name("claims.yaml")
CLAIM_FIELDS = ("id", "section", "claim", "setup", "strategies", "seeds", "micro_actions", "paper",
                "ours", "p_value", "verdict")
VERDICTS = ("reproduced", "not reproduced", "inconclusive")
METRICS = {"final_mean_error": "lower", "goal_share_reachable_second_half": "higher"}
STATISTICS = ("mannwhitney_p", "welch_p")


def load_registry(path: str | Path = REGISTRY) -> dict:
    """The claim registry, checked: every claim names a known experiment, known strategies of that
    experiment, a known metric and statistic; every experiment has a paper scale and a config.
    (Its ``sensitivity`` section is checked by :func:`sagg_bringup.experiments.sensitivity.load_sensitivity`.)"""
    reg = yaml.safe_load(Path(path).read_text())
    if not isinstance(reg, dict) or reg.get("format") != "sagg.claims/1":
        raise ConfigError(f"{path}: not a sagg.claims/1 registry")
    exps, claims = reg.get("experiments") or {}, reg.get("claims") or []
    for name, e in exps.items():
        for key in ("section", "config", "strategies", "paper"):
            if key not in e:
                raise ConfigError(f"{path}: experiment {name!r} has no {key!r}")
        bad = [s for s in e["strategies"] if s not in STRATEGIES]
        if bad:
            raise ConfigError(f"{path}: experiment {name!r}: unknown strategies {bad}")
        e.setdefault("set", {})
        e.setdefault("kind", "arm")
        if e["kind"] not in reg["scales"]["smoke"]:
            raise ConfigError(f"{path}: experiment {name!r}: kind {e['kind']!r} has no smoke scale")
    seen = set()
    for c in claims:
        if c.get("id") in seen:
            raise ConfigError(f"{path}: claim id {c.get('id')!r} twice")
        seen.add(c["id"])
        if c.get("experiment") not in exps:
            raise ConfigError(f"{path}: claim {c['id']!r}: unknown experiment {c.get('experiment')!r}")
        c.setdefault("metric", "final_mean_error")
        c.setdefault("statistic", reg.get("statistic", "mannwhitney_p"))
        if c["metric"] not in METRICS:
            raise ConfigError(f"{path}: claim {c['id']!r}: metric {c['metric']!r}; allowed: {list(METRICS)}")
        if c["statistic"] not in STATISTICS:
            raise ConfigError(f"{path}: claim {c['id']!r}: statistic {c['statistic']!r}; allowed: {STATISTICS}")
        strategies = exps[c["experiment"]]["strategies"]
        for pair in c.get("expect") or []:
            if len(pair) != 2 or any(s not in strategies for s in pair):
                raise ConfigError(f"{path}: claim {c['id']!r}: pair {pair} not two of {strategies}")
        if not c.get("expect"):
            raise ConfigError(f"{path}: claim {c['id']!r} expects nothing")
    return reg


def scale_of(reg: dict, experiment: dict, scale: str) -> dict:
    """seeds, micro_actions, eval_every and extra parameter overrides of one experiment at ``scale``."""
    if scale == "paper":
        s = dict(experiment["paper"])
        s.setdefault("set", {})
        return s
    if scale == "smoke":
        return dict(reg["scales"]["smoke"][experiment["kind"]])
    raise ConfigError(f"--scale: got {scale!r}; allowed: paper, smoke")


def resolve_config(config: str) -> Path:
    """A registry config path (``config/<name>.yaml``): relative to the current directory, else the
    repository this package sits in, else the installed share directory."""
    here = Path(__file__).resolve()
    # setup.py installs config/*.yaml to <prefix>/share/sagg_bringup/config
    candidates = [Path(config), here.parents[4] / config, Path(sys.prefix) / "share" / "sagg_bringup" / config]
    for c in candidates:
        if c.is_file():
            return c
    raise ConfigError(f"config {config!r} not found (looked in: {', '.join(map(str, candidates))})")


def select(reg: dict, which: list[str]) -> list[dict]:
    """The claims named (ids, ``all``, or an experiment name: its claims), in registry order."""
    claims = reg["claims"]
    if "all" in which:
        return list(claims)
    ids = {c["id"] for c in claims}
    bad = [w for w in which if w not in ids and w not in reg["experiments"]]
    if bad:
        raise ConfigError(f"CLAIM: unknown {bad}; allowed: all, or any of {', '.join(sorted(ids))}")
    return [c for c in claims if c["id"] in which or c["experiment"] in which]


def significance_floor(n_a: int, n_b: int) -> float:
    """The smallest two-sided Mann-Whitney p possible with n_a against n_b values (exact test, no
    ties): 2 / C(n_a + n_b, n_a). Below alpha only with enough seeds."""
    if n_a < 1 or n_b < 1:
        return float("nan")
    return min(1.0, 2.0 / math.comb(n_a + n_b, n_a))


def pair_verdict(mean_a: float, mean_b: float, p: float, higher_is_better: bool, alpha: float) -> str:
    """One pair [A, B] ("A better than B"), by the rule in the module docstring."""
    if not (np.isfinite(mean_a) and np.isfinite(mean_b) and np.isfinite(p)) or mean_a == mean_b:
        return "inconclusive"
    a_better = mean_a > mean_b if higher_is_better else mean_a < mean_b
    if p < alpha:
        return "reproduced" if a_better else "not reproduced"
    return "inconclusive"


def claim_verdict(pairs: list[dict]) -> tuple[str, float]:
    """A claim's verdict and p-value from its pairs (module docstring)."""
    ps = [pr["p"] for pr in pairs]
    against = [pr["p"] for pr in pairs if pr["verdict"] == "not reproduced"]
    if against:
        return "not reproduced", float(min(against))
    p = float(max(ps)) if ps and all(np.isfinite(ps)) else float("nan")
    if all(pr["verdict"] == "reproduced" for pr in pairs):
        return "reproduced", p
    return "inconclusive", p


def decide(claim: dict, summary: dict, alpha: float) -> dict:
    """The ``ours``, ``p_value``, ``verdict`` and per-pair details of one claim from its experiment's
    ``summary.json`` (final values per seed; the tests of :func:`compare.pairwise_tests`)."""
    # lazy (heavy): scipy
    from .compare import pairwise_tests
    strat = summary["strategies"]
    metric, stat = claim["metric"], claim["statistic"]
    higher = METRICS[metric] == "higher"
    key = "final_mean_error" if metric == "final_mean_error" else metric
    values = {s: [float(v) for v in strat[s][key]] for s in strat}
    ours = {s: {"mean": float(np.nanmean(v)) if len(v) else float("nan"),
                "std": float(np.nanstd(v, ddof=1)) if len(v) > 1 else 0.0,
                "median": float(np.nanmedian(v)) if len(v) else float("nan"),
                "n": len(v), "per_seed": v} for s, v in values.items()}
    pairs = []
    for a, b in claim["expect"]:
        if a not in values or b not in values:
            pairs.append({"a": a, "b": b, "p": float("nan"), "verdict": "inconclusive",
                          "why": "runs missing (failed or not run)"})
            continue
        t = pairwise_tests(values[a], values[b])
        p = t[stat]
        pairs.append({"a": a, "b": b, "mean_a": ours[a]["mean"], "mean_b": ours[b]["mean"], "p": p,
                      "p_floor": significance_floor(len(values[a]), len(values[b])),
                      "verdict": pair_verdict(ours[a]["mean"], ours[b]["mean"], p, higher, alpha)})
    verdict, p = claim_verdict(pairs)
    return {"ours": {"metric": metric, "better": METRICS[metric], "strategies": ours},
            "p_value": p, "statistic": stat, "pairs": pairs, "verdict": verdict}


def run_reproduce(which: list[str], scale: str = "smoke", out: str | Path | None = None,
                  workers: int | None = None, ray_address: str | None = None,
                  registry: str | Path = REGISTRY, out_fn: Callable[[str], None] = print,
                  archive: str | Path | None = None, run: bool = True) -> list[dict]:
    """Run (or resume) every experiment the selected claims need, then write claims.json and
    report.md with figures. Returns the claims.json list. ``archive``: a directory of archived runs
    (:mod:`sagg_bringup.experiments.archive`) restored before and updated after every run. ``run=False``: run
    nothing and decide on the runs finished so far (an interim verdict while paper-scale runs go
    on): each row's ``seeds`` are then the seeds every strategy of the experiment has finished,
    ``seeds_planned`` the scale's, ``complete`` whether they are all there, and ``ours`` gives each
    strategy's own ``n``."""

    reg = load_registry(registry)
    claims = select(reg, which)
    out = Path(out or f"runs/reproduce-{scale}")
    commit = code_commit()
    needed = list(dict.fromkeys(c["experiment"] for c in claims))
    summaries, settings = {}, {}
    workers = workers or os.cpu_count() or 1
    pool = None  # one pool for every experiment, made when the first run is due (warm workers)
    try:
        for i, name in enumerate(needed, 1):
            pool = run_claim_experiment(reg, name, i, len(needed), scale, out, workers, ray_address,
                                        pool, summaries, settings, out_fn, archive, run)
    finally:
        if pool is not None:
            pool.close()

    alpha = float(reg.get("alpha", 0.05))
    results = {name: summarised_results(out / "experiments" / name, summaries[name]) for name in needed}
    mechanisms = {name: experiment_mechanisms(results[name]) for name in needed}
    rows = []
    for c in claims:
        e, st = reg["experiments"][c["experiment"]], settings[c["experiment"]]
        d = decide(c, summaries[c["experiment"]], alpha)
        done = finished_seeds(summaries[c["experiment"]], e["strategies"])
        rows.append({"id": c["id"], "section": e["section"], "claim": c["claim"],
                     "setup": {"experiment": c["experiment"], "config": st["config"],
                               "overrides": st["overrides"], "eval_every": st["eval_every"]},
                     "strategies": list(e["strategies"]),
                     "seeds": done, "seeds_planned": st["seeds"], "complete": len(done) == st["seeds"],
                     "micro_actions": st["micro_actions"], "paper": c["paper"], "ours": d["ours"],
                     "p_value": d["p_value"],
                     "verdict": d["verdict"], "statistic": d["statistic"], "pairs": d["pairs"],
                     "mechanisms": mechanisms[c["experiment"]],
                     "alpha": alpha, "scale": scale,
                     **run_commits(out / "experiments" / c["experiment"], commit)})
    write_json_atomic(out / "claims.json", rows)
    write_report(out, rows, reg, scale, commit, results)
    counts = {v: sum(r["verdict"] == v for r in rows) for v in VERDICTS}
    out_fn(f"wrote {out / 'claims.json'}, {out / 'report.md'}: "
           + ", ".join(f"{n} {v}" for v, n in counts.items()))
    return rows


def finished_seeds(summary: dict, strategies: list[str]) -> list[int]:
    """The seeds an experiment's summary holds a finished, valid run of for every strategy."""
    have = [set(summary["strategies"].get(st, {}).get("seeds", [])) for st in strategies]
    return sorted(set.intersection(*have)) if have else []


def run_claim_experiment(reg, name, i, n, scale, out, workers, ray_address, pool, summaries, settings,
                         out_fn, archive=None, run=True):
    """One experiment through run_compare (on ``pool``, made here if None and runs are due);
    fills ``summaries`` / ``settings``; returns the pool. With ``archive``, the experiment's
    archived runs (``archive/<scale>/<experiment>``) are restored first and every run finished
    here is archived as soon as it is written."""
    # lazy (heavy): mujoco
    from .sweep import make_pool, run_compare
    e = reg["experiments"][name]
    sc = scale_of(reg, e, scale)
    overrides = {**e["set"], **sc.get("set", {})}
    out_fn(f"== experiment {i}/{n}: {name} (Sec. {e['section']}, {e['config']}, "
           f"{scale} scale: {sc['seeds']} seeds x {sc['micro_actions']})")
    exp_dir = out / "experiments" / name
    kept = Path(archive) / scale / name if archive else None
    on_result = None
    if kept is not None:
        restored = restore_experiment(kept, exp_dir)
        if restored:
            out_fn(f"restored {restored} archived run(s) from {kept}")
        on_result = lambda f: archive_run(f, exp_dir, kept)  # noqa: E731
    if pool is None and run:
        pool = make_pool(workers, ray_address)
    summaries[name] = run_compare(resolve_config(e["config"]), e["strategies"], sc["seeds"],
                                  sc["micro_actions"], sc["eval_every"], exp_dir,
                                  workers=workers, ray_address=ray_address, overrides=overrides,
                                  base_seed=0, out_fn=out_fn, pool=pool, on_result=on_result, run=run)
    if kept is not None and run:
        archive_experiment(exp_dir, kept)  # runs kept from before the archive existed, too
    settings[name] = {"config": e["config"], "overrides": overrides,
                      **{k: sc[k] for k in ("seeds", "micro_actions", "eval_every")}}
    return pool


def summarised_results(directory: Path, summary: dict) -> list[dict]:
    """The result.json of every run the experiment's summary is made of (finished and matching the
    settings: a run left out by ``--no-run`` as not matching is left out here too)."""
    # lazy (heavy): scipy
    from .compare import load_results
    out = []
    for strategy, v in summary["strategies"].items():
        out += load_results([directory / "runs" / strategy / f"seed-{s}" / "result.json" for s in v["seeds"]])
    return out


def experiment_mechanisms(results: list[dict]) -> dict:
    """:func:`mechanisms.strategy_mechanisms` of one experiment's finished runs."""
    # lazy (heavy): scipy
    from .compare import by_strategy
    return strategy_mechanisms(by_strategy(results)) if results else {}


# --------------------------------------------------------------------------------------- report
def fmt_number(x, spec=".3g") -> str:
    return "—" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def write_report(out: Path, rows: list[dict], reg: dict, scale: str, commit: str,
                 results: dict[str, list[dict]]) -> Path:
    """report.md: the verdict table, then per experiment its curves (mean ± std over seeds, like the
    paper's Figs. 10-13, 17, 21) and a histogram of the self-generated goals of each goal-choosing
    strategy (pooled over seeds; like Figs. 8, 15). ``results``: per experiment, the runs decided on."""
    figs = out / "figures"
    figs.mkdir(parents=True, exist_ok=True)
    md = [f"# Reproduction of the paper's claims ({scale} scale)", "",
          f"Written at commit `{commit}`; each experiment below names the commit its runs computed at. "
          f"Every number below comes from `DIR/experiments/<experiment>` "
          f"(one `sagg bench compare` each; seeds 0..n-1). Verdict rules: see "
          f"`sagg_bringup/experiments/reproduce.py` (alpha = {rows[0]['alpha'] if rows else '—'}).", ""]
    partial = [r["id"] for r in rows if not r.get("complete", True)]
    if partial:
        md += [f"**Interim (`--no-run`)**: {len(partial)} of {len(rows)} claims are decided on fewer seeds "
               "than planned (runs still going on); their rows say how many.", ""]
    if scale == "smoke":
        md += ["**Smoke scale: a wiring check, not a result.** With 2 seeds no two-sided "
               "Mann-Whitney p can fall below 0.33, so every verdict is inconclusive by design.", ""]
    md += ["| claim | Sec. | paper | ours (mean over seeds) | p | verdict |", "|---|---|---|---|---|---|"]
    for r in rows:
        s = r["ours"]["strategies"]
        named = {n for pr in r["pairs"] for n in (pr["a"], pr["b"])}  # the claim's strategies only
        ours = "; ".join(f"{n} {fmt_number(v['mean'])}" for n, v in s.items() if n in named)
        if r["ours"]["metric"] != "final_mean_error":
            ours += f" ({r['ours']['metric']})"
        seeds = "" if r.get("complete", True) else f" ({len(r['seeds'])} of {r['seeds_planned']} seeds)"
        md.append(f"| {r['id']}{seeds} | {r['section']} | {r['paper']} | {ours} | {fmt_number(r['p_value'])} | "
                  f"**{r['verdict']}** |")
    md.append("")
    for exp in dict.fromkeys(r["setup"]["experiment"] for r in rows):
        d = out / "experiments" / exp
        runs = results.get(exp, [])
        first = next(r for r in rows if r["setup"]["experiment"] == exp)
        md += [f"## {exp} (Sec. {first['section']})", "",
               f"`{first['setup']['config']}`, overrides {first['setup']['overrides'] or 'none'}; "
               f"{len(first['seeds'])} seeds × {first['micro_actions']:,} micro-actions"
               + ("; " if first.get("complete", True) else
                  f" (**interim**: {first['seeds_planned']} planned; per strategy n = "
                  + ", ".join(f"{k} {v['n']}" for k, v in first["ours"]["strategies"].items()) + "); ")
               + f"runs computed at commit `{first['commit']}`; "
               f"details: `experiments/{exp}/summary.md`.", ""]
        for r in rows:
            if r["setup"]["experiment"] != exp:
                continue
            md += [f"- **{r['id']}**: {r['claim']} — **{r['verdict']}** ({r['statistic']} "
                   f"{fmt_number(r['p_value'])}, on {r['ours']['metric']})"]
            for pr in r["pairs"]:
                md.append(f"  - {pr['a']} better than {pr['b']}: {fmt_number(pr.get('mean_a'))} vs "
                          f"{fmt_number(pr.get('mean_b'))}, p = {fmt_number(pr['p'])} (smallest possible "
                          f"{fmt_number(pr.get('p_floor'))}): {pr['verdict']}")
        md.append("")
        if first.get("mechanisms"):
            md += ["Where the micro-actions went (the evidence behind the verdicts; "
                   "sagg_bringup/experiments/mechanisms.py):", "", mechanism_table(first["mechanisms"]), ""]
        if runs:
            # the comparison's own figure (mean ± std over seeds, drawn by write_summary)
            shutil.copyfile(d / "curves.png", figs / f"{exp}_curves.png")
            md += [f"![{exp} curves](figures/{exp}_curves.png)", ""]
            if plot_goal_histograms(runs, figs / f"{exp}_goals.png", exp):
                md += [f"![{exp} goals](figures/{exp}_goals.png)", ""]
    path = out / "report.md"
    path.write_text("\n".join(md) + "\n")
    return path


def plot_goal_histograms(results: list[dict], path: Path, title: str) -> bool:
    """2-D histograms of the self-generated goals (first two task dimensions, all seeds pooled), one
    panel per strategy that chooses goals, with the test goals on top; from each run's goal
    histogram (:func:`sagg_bringup.experiments.archive.histogram_of`: archived runs have no goal list). False
    when no strategy has goals (nothing drawn)."""
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib, scipy
    import matplotlib.pyplot as plt

    from .compare import by_strategy
    groups = {}
    for name, rs in by_strategy(results).items():
        hists = [h for h in map(histogram_of, rs) if h is not None]
        if hists:
            groups[name] = (rs, sum(histogram_counts(h) for h in hists), hists[0])
    if not groups:
        return False
    lp = results[0]["config"]["sagg_learner"]
    lo = lp["task_space.lower"]
    fig, axes = plt.subplots(1, len(groups), figsize=(4.2 * len(groups), 3.8), squeeze=False)
    for ax, (name, (rs, counts, h)) in zip(axes[0], groups.items()):
        (x0, y0), (x1, y1) = h["lower"], h["upper"]
        # counts[i, j]: i along y1, j along y2 (as histogram2d, which hist2d drew before)
        ax.pcolormesh(np.linspace(x0, x1, h["bins"] + 1), np.linspace(y0, y1, h["bins"] + 1), counts.T,
                      cmap="Blues")
        tg = np.array(rs[0].get("test_goals") or []).reshape(-1, len(lo))
        if len(tg):
            ax.scatter(tg[:, 0], tg[:, 1], s=4, c="red", label="test goals")
            ax.legend(fontsize=7, loc="upper right")
        ax.set_title(f"{name}: {int(counts.sum())} goals, {len(rs)} seeds", fontsize=9)
        ax.set_xlabel("y1")
        ax.set_ylabel("y2")
    fig.suptitle(f"{title}: self-generated goals (all seeds)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return True


# ------------------------------------------------------------------------------------- estimate
def estimate(which: list[str], out: str | Path, probe_micro_actions: dict | None = None,
             workers: int | None = None, registry: str | Path = REGISTRY,
             out_fn: Callable[[str], None] = print) -> list[dict]:
    """Measure each needed experiment's speed per strategy with one short probe run (seed 0, through
    ``run_compare``, resumable in ``out``) and extrapolate the paper-scale cost: learning time =
    micro-actions / measured rate; evaluation time = evaluations × the probe's time per
    evaluation of a trained model. Returns one row per experiment (core-hours per strategy and
    total). Rates fall as the memory grows (the neighbour search), so this is a lower bound."""
    # lazy (heavy): mujoco
    from .sweep import run_compare
    reg = load_registry(registry)
    claims = select(reg, which)
    probe = {"arm": 2000, "synergy": 100, **(probe_micro_actions or {})}
    rows = []
    for name in dict.fromkeys(c["experiment"] for c in claims):
        e = reg["experiments"][name]
        pa = scale_of(reg, e, "paper")
        n = probe[e["kind"]]
        summ = run_compare(resolve_config(e["config"]), e["strategies"], 1, n, n,
                           Path(out) / name, workers=workers, overrides=dict(e["set"]), base_seed=0,
                           out_fn=out_fn)
        # lazy (heavy): scipy
        from .compare import load_results
        res = {r["strategy"]: r for r in load_results([Path(out) / name / "runs"])}
        evals = len(range(0, pa["micro_actions"], pa["eval_every"])) + 1
        per = {}
        for s in e["strategies"]:
            if s not in res:
                continue
            r = res[s]
            learn_h = pa["micro_actions"] / max(r["micro_actions_per_second"], 1e-9) / 3600
            eval_h = evals * r["eval_seconds"] / 3600  # two evaluations in the probe; the one at 0 is ~free
            per[s] = {"rate": r["micro_actions_per_second"], "eval_seconds": r["eval_seconds"],
                      "core_hours_per_run": learn_h + eval_h}
        total = sum(v["core_hours_per_run"] for v in per.values()) * pa["seeds"]
        rows.append({"experiment": name, "section": e["section"], "seeds": pa["seeds"],
                     "micro_actions": pa["micro_actions"], "evaluations": evals, "probe": n,
                     "strategies": per, "core_hours": total, "failed": summ["failed_runs"]})
    write_json_atomic(Path(out) / "estimate.json", rows)
    out_fn(estimate_table(rows))
    return rows


def estimate_table(rows: list[dict]) -> str:
    """Markdown: per experiment, the measured rate per strategy and the extrapolated core-hours."""
    lines = ["| experiment | Sec. | seeds × micro-actions | micro-actions/s per strategy (probe) | "
             "core-hours per run | core-hours |", "|---|---|---|---|---|---|"]
    for r in rows:
        rates = ", ".join(f"{s} {v['rate']:,.0f}" for s, v in r["strategies"].items())
        per = ", ".join(f"{s} {v['core_hours_per_run']:.2f}" for s, v in r["strategies"].items())
        lines.append(f"| {r['experiment']} | {r['section']} | {r['seeds']} × {r['micro_actions']:,} | "
                     f"{rates} | {per} | {r['core_hours']:.1f} |")
    lines.append(f"| **total** | | | | | **{sum(r['core_hours'] for r in rows):.1f}** |")
    return "\n".join(lines)
