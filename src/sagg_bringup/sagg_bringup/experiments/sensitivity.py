"""``sagg reproduce sensitivity``: which of the paper's conclusions depend on our open choices.

The registry's ``sensitivity`` section (``claims.yaml``) names one claim (the Sec. 3.9 15-DOF
comparison), a scale (8 seeds x 50k at paper scale) and the open choices: rest posture, ε_sim,
ε_max, the exploration amplitude, the evaluation budget, the blocking timeout's scope, reached points
on/off. Each value is the claim's experiment with that one choice changed (``set``); "default" is the
experiment itself at the same scale. Every variant is one ``sagg bench compare`` directory (the
same resumable runs as ``sagg reproduce``), decided with the same rules (:func:`reproduce.decide`).

A choice may name the ``strategies`` that read its parameters (e.g. ε_sim, ε_max, the blocking
timeout and reached points are read by the goal-directed learner and the goal generator only, never
by ACTUATOR-RANDOM or ACTUATOR-RIAC). Its variants then run only those; every other strategy's runs
would be the default's bit for bit, so the default's runs stand for them (the row says so in
``reused``). ``test_reproduce`` checks each such declaration: the strategies left out, run with the
variant's change, give the default's memory and curve.

A conclusion *flips* when a pair [A, B] of the claim ("A better than B") has another verdict under
the variant than under the default (e.g. reproduced → inconclusive), or the claim's verdict changes.

Layout of ``--out DIR``::

    DIR/experiments/sens-<choice>-<value>/   one `sagg bench compare` directory per variant
    DIR/sensitivity.json                      one row per variant (SENSITIVITY_FIELDS)
    DIR/sensitivity.md                        the table: per variant the strategies' final errors,
                                              the claim's verdict and p, and what flipped
    DIR/sensitivity.png                       the same as a picture: each variant's final errors
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Callable

import numpy as np

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError

from .reproduce import REGISTRY, decide, finished_seeds, fmt_number, load_registry, run_claim_experiment
from ..inprocess.results import code_commit, run_commits

SENSITIVITY_FIELDS = ("choice", "value", "overrides", "experiment", "claim", "strategies", "reused", "verdict",
                      "p_value", "pairs", "flips", "seeds", "seeds_planned", "complete", "micro_actions",
                      "scale", "commit")
DEFAULT = "default"


def load_sensitivity(reg: dict) -> dict:
    """The registry's ``sensitivity`` section, checked: a known claim on its named experiment, a
    paper scale, and per choice a unique name and values with a label and a non-empty ``set``."""
    sens = reg.get("sensitivity")
    if not isinstance(sens, dict):
        raise ConfigError("claims registry: no 'sensitivity' section")
    exp = sens.get("experiment")
    if exp not in reg["experiments"]:
        raise ConfigError(f"sensitivity: unknown experiment {exp!r}")
    claims = [c for c in reg["claims"] if c["id"] == sens.get("claim")]
    if not claims or claims[0]["experiment"] != exp:
        raise ConfigError(f"sensitivity: claim {sens.get('claim')!r} is not a claim on experiment {exp!r}")
    for key in ("seeds", "micro_actions", "eval_every"):
        if key not in (sens.get("paper") or {}):
            raise ConfigError(f"sensitivity: paper scale has no {key!r}")
    names = [c.get("name") for c in sens.get("choices") or []]
    if not names or len(set(names)) != len(names) or DEFAULT in names:
        raise ConfigError(f"sensitivity: choice names {names} must be unique, non-empty, not {DEFAULT!r}")
    every = reg["experiments"][exp]["strategies"]
    for c in sens["choices"]:
        reads = c.get("strategies", every)
        if not reads or any(s not in every for s in reads):
            raise ConfigError(f"sensitivity: choice {c['name']!r}: strategies {reads} must be a non-empty "
                              f"subset of {every}")
        for v in c.get("values") or [None]:
            if not isinstance(v, dict) or not v.get("label") or not isinstance(v.get("set"), dict) \
                    or not v["set"]:
                raise ConfigError(f"sensitivity: choice {c['name']!r}: every value needs a label and a "
                                  f"non-empty 'set', got {v!r}")
    return sens


def slug(text: str) -> str:
    """A directory-safe name: lower case, runs of other characters as one '-'."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def variants(reg: dict, choices: list[str] | None = None) -> list[dict]:
    """The default, then every value of the selected choices (all when None), each as an
    experiment entry ready for :func:`reproduce.run_claim_experiment`."""
    sens = load_sensitivity(reg)
    known = [c["name"] for c in sens["choices"]]
    bad = [c for c in choices or [] if c not in known]
    if bad:
        raise ConfigError(f"--choice: unknown {bad}; allowed: {', '.join(known)}")
    base = reg["experiments"][sens["experiment"]]
    out = [{"choice": DEFAULT, "value": DEFAULT, "name": "sens-default", "set": {}}]
    for c in sens["choices"]:
        if choices and c["name"] not in choices:
            continue
        reads = [s for s in base["strategies"] if s in c.get("strategies", base["strategies"])]
        out += [{"choice": c["name"], "value": v["label"], "set": dict(v["set"]), "strategies": reads,
                 "name": f"sens-{slug(c['name'])}-{i}"} for i, v in enumerate(c["values"], 1)]
    for v in out:
        v.setdefault("strategies", list(base["strategies"]))
        v["reused"] = [s for s in base["strategies"] if s not in v["strategies"]]
        v["experiment"] = {**base, "set": {**base["set"], **v["set"]}, "strategies": v["strategies"],
                           "paper": dict(sens["paper"])}
    return out


def with_reused(summary: dict, default: dict, reused: list[str]) -> dict:
    """A variant's summary with the default's results for the strategies it did not run (they do
    not read the variant's parameters)."""
    strategies = {**summary["strategies"], **{s: default["strategies"][s] for s in reused
                                               if s in default["strategies"]}}
    return {**summary, "strategies": strategies}


def flips(default: dict, variant: dict) -> list[str]:
    """What changed against the default: per pair "A>B: old → new", and the claim's verdict."""
    old = {(p["a"], p["b"]): p["verdict"] for p in default["pairs"]}
    out = [f"{a}>{b}: {old[(a, b)]} → {p['verdict']}" for p in variant["pairs"]
           for a, b in [(p["a"], p["b"])] if old.get((a, b)) not in (None, p["verdict"])]
    if default["verdict"] != variant["verdict"]:
        out.append(f"claim: {default['verdict']} → {variant['verdict']}")
    return out


def run_sensitivity(scale: str = "smoke", out: str | Path | None = None, workers: int | None = None,
                    ray_address: str | None = None, choices: list[str] | None = None,
                    registry: str | Path = REGISTRY,
                    out_fn: Callable[[str], None] = print,
                    archive: str | Path | None = None, run: bool = True) -> list[dict]:
    """Run (or resume) the default and every variant, decide the claim on each, write
    sensitivity.json and sensitivity.md. Returns the rows. ``archive`` and ``run=False`` (decide
    on the runs finished so far, run nothing): as :func:`~sagg_bringup.experiments.reproduce.run_reproduce`;
    each row's ``seeds`` are then the seeds every strategy of the variant (its own runs and the
    default's it reuses) has finished, ``complete`` whether all the scale's are there."""
    reg = load_registry(registry)
    sens = load_sensitivity(reg)
    claim = next(c for c in reg["claims"] if c["id"] == sens["claim"])
    vs = variants(reg, choices)
    out = Path(out or f"runs/sensitivity-{scale}")
    commit = code_commit()
    alpha = float(reg.get("alpha", 0.05))
    reg = {**reg, "experiments": {**reg["experiments"], **{v["name"]: v["experiment"] for v in vs}}}
    summaries, settings, pool = {}, {}, None
    workers = workers or os.cpu_count() or 1
    try:
        for i, v in enumerate(vs, 1):
            out_fn(f"-- sensitivity {i}/{len(vs)}: {v['choice']} = {v['value']}")
            pool = run_claim_experiment(reg, v["name"], i, len(vs), scale, out, workers, ray_address,
                                        pool, summaries, settings, out_fn, archive, run)
    finally:
        if pool is not None:
            pool.close()
    rows = []
    for v in vs:
        summary = with_reused(summaries[v["name"]], summaries[vs[0]["name"]], v["reused"])
        d = decide(claim, summary, alpha)
        st = settings[v["name"]]
        done = finished_seeds(summary, list(v["experiment"]["strategies"]) + v["reused"])
        rows.append({"choice": v["choice"], "value": v["value"], "overrides": v["set"],
                     "experiment": v["name"], "claim": claim["id"], "reused": v["reused"],
                     "strategies": d["ours"]["strategies"], "verdict": d["verdict"],
                     "p_value": d["p_value"], "pairs": d["pairs"], "seeds": done,
                     "seeds_planned": st["seeds"], "complete": len(done) == st["seeds"],
                     "micro_actions": st["micro_actions"], "scale": scale,
                     **run_commits(out / "experiments" / v["name"], commit)})
    for r in rows:  # a variant with no finished run (--no-run) has nothing to flip
        r["flips"] = flips(rows[0], r) if r["seeds"] and rows[0]["seeds"] else []
    write_json_atomic(out / "sensitivity.json", rows)
    text = sensitivity_table(rows, sens, reg)
    if plot_sensitivity(rows, out / "sensitivity.png", f"claim {sens['claim']}"):
        text += "\n\n![final mean test error per variant](sensitivity.png)"
    (out / "sensitivity.md").write_text(text + "\n")
    flipped = sum(bool(r["flips"]) for r in rows)
    out_fn(f"wrote {out / 'sensitivity.json'}, {out / 'sensitivity.md'}: {len(rows)} variants, "
           f"{flipped} with a flipped conclusion")
    return rows


def sensitivity_table(rows: list[dict], sens: dict, reg: dict) -> str:
    """Markdown: one line per variant (final mean error ± std per strategy, verdict, p, flips)."""
    strategies = list(rows[0]["strategies"]) if rows else []
    base = reg["experiments"][sens["experiment"]]
    r0 = rows[0] if rows else {"seeds": [], "micro_actions": 0, "commit": "?", "scale": "?"}
    head = [f"# Sensitivity of claim `{sens['claim']}` to the open choices ({r0['scale']} scale)", "",
            f"Experiment `{sens['experiment']}` (Sec. {base['section']}, `{base['config']}`, "
            f"overrides {base['set']}), {r0.get('seeds_planned', len(r0['seeds']))} seeds × {r0['micro_actions']:,} "
            f"micro-actions per variant, code commit `{r0['commit']}`. One choice changed at a time; "
            "final mean test error, mean ± std over seeds; verdict and p as `sagg reproduce` "
            "(sagg_bringup/experiments/reproduce.py); *flips*: pairs whose verdict differs from the default's; "
            "*default's runs*: a strategy that does not read the choice's parameters (the default's "
            "runs are its runs under the variant, bit for bit).", "",
            "| choice | value | " + " | ".join(strategies) + " | verdict | p | flips vs default |",
            "|---|---|" + "---|" * len(strategies) + "---|---|---|"]
    defaults = {c["name"]: c["default"] for c in sens["choices"]}
    lines = []
    for r in rows:
        value = r["value"] if r["choice"] != DEFAULT else "paper / registry defaults"
        if not r["seeds"]:
            lines.append(f"| {r['choice']} | {value} | " + " | ".join("—" for _ in strategies)
                         + " | not run yet | — | — |")
            continue
        cells = [f"{fmt_number(r['strategies'][s]['mean'])} ± {fmt_number(r['strategies'][s]['std'], '.2g')}"
                 + (" (default's runs)" if s in r.get("reused", ()) else "")
                 if s in r["strategies"] else "—" for s in strategies]
        interim = "" if r.get("complete", True) else f" (interim: {len(r['seeds'])} of {r['seeds_planned']} seeds)"
        lines.append(f"| {r['choice']} | {value} | " + " | ".join(cells) + f" | {r['verdict']}{interim} | "
                     f"{fmt_number(r['p_value'])} | {'; '.join(r['flips']) or '—'} |")
    notes = ["", "Defaults of each choice: " + "; ".join(f"{k}: {v}" for k, v in defaults.items()) + "."]
    return "\n".join(head + lines + notes)


def plot_sensitivity(rows: list[dict], path: Path, title: str) -> bool:
    """One row per variant, the strategies' final mean test errors (mean ± std over seeds) side by
    side, the default's as vertical lines, a variant that flips a conclusion in red. False when no
    variant has runs (nothing drawn)."""
    done = [r for r in rows if r["seeds"]]
    if not done:
        return False
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt

    strategies = list(done[0]["strategies"])
    fig, ax = plt.subplots(figsize=(8.5, 0.42 * len(done) + 1.6))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, s in enumerate(strategies):
        c = colours[k % len(colours)]
        ys = [i + (k - (len(strategies) - 1) / 2) * 0.15 for i in range(len(done))]
        mean = [r["strategies"][s]["mean"] if s in r["strategies"] else np.nan for r in done]
        std = [r["strategies"][s]["std"] if s in r["strategies"] else np.nan for r in done]
        ax.errorbar(mean, ys, xerr=std, fmt="o", ms=4, capsize=2, color=c, label=s)
        if DEFAULT == done[0]["choice"] and s in done[0]["strategies"]:
            ax.axvline(done[0]["strategies"][s]["mean"], color=c, lw=0.6, ls=":")
    labels = [("default" if r["choice"] == DEFAULT else f"{r['choice']}: {r['value']}")
              + ("" if r.get("complete", True) else f" ({len(r['seeds'])} seeds)") for r in done]
    ax.set_yticks(range(len(done)), labels, fontsize=7)
    for t, r in zip(ax.get_yticklabels(), done):
        if r.get("flips"):
            t.set_color("red")
    ax.invert_yaxis()
    ax.set_xlabel("final mean test error (mean ± std over seeds)")
    ax.set_title(f"{title}: one open choice changed at a time\n(red: a conclusion flips)", fontsize=9)
    ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return True
