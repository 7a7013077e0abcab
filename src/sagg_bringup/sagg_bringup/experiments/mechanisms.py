"""Where each strategy's micro-actions went, over the seeds of one comparison: the evidence next to
a verdict (where a claim does not reproduce, say so with the evidence: which mechanism, measured).

From every run's ``result.json``: ``goal_stats`` (self-generated goals inside the reachable area,
overall and in the second half), ``phases`` (micro-actions by phase, on goals inside / outside the
reachable area), ``coverage`` (test goal to the nearest point the run reached) and the final test
error's median and share within tolerance. Means over seeds; ROS-free, light.
"""
from __future__ import annotations

import math

import numpy as np

# (key in the output, label, how to read it from one result.json, format)
FIELDS = (
    ("final_mean_error", "final mean error", lambda r: r["final_mean_error"], ".3g"),
    ("final_median_error", "final median error", lambda r: r["curve"][-1].get("median_error"), ".3g"),
    ("within_share", "test goals within tolerance", lambda r: r["curve"][-1].get("within_share"), ".2f"),
    ("goals", "self-generated goals", lambda r: r["goal_stats"]["goals"], ".0f"),
    ("goal_share_reachable", "goals in reachable area",
     lambda r: r["goal_stats"]["goal_share_reachable"], ".2f"),
    ("goal_share_reachable_second_half", "… in the second half",
     lambda r: r["goal_stats"]["goal_share_reachable_second_half"], ".2f"),
    ("explore_share", "exploration share of micro-actions", lambda r: r["phases"]["explore_share"], ".2f"),
    ("on_reachable_goals", "micro-actions on reachable goals",
     lambda r: r["phases"]["reachable_goals"]["share_of_micro_actions"], ".2f"),
    ("per_reachable_goal", "micro-actions per reachable goal",
     lambda r: r["phases"]["reachable_goals"]["micro_actions_per_goal"], ".0f"),
    ("per_unreachable_goal", "micro-actions per unreachable goal",
     lambda r: r["phases"]["unreachable_goals"]["micro_actions_per_goal"], ".0f"),
    ("coverage_median", "coverage: median test goal to nearest reached point",
     lambda r: r["coverage"]["median"], ".3g"),
    ("coverage_max", "coverage: worst test goal to nearest reached point",
     lambda r: r["coverage"]["max"], ".3g"),
)


def _value(read, r) -> float:
    try:
        v = read(r)
    except (KeyError, IndexError, TypeError):
        return math.nan
    return math.nan if v is None else float(v)


def strategy_mechanisms(groups: dict[str, list[dict]]) -> dict[str, dict[str, float]]:
    """Per strategy (``groups``: results by strategy, as compare.by_strategy), the mean over its
    seeds of every field of FIELDS (NaN where no run has it, e.g. goals of ACTUATOR methods)."""
    out = {}
    for name, runs in groups.items():
        vals = {key: np.array([_value(read, r) for r in runs], dtype=float) for key, _, read, _ in FIELDS}
        out[name] = {key: float(np.nanmean(v)) if np.isfinite(v).any() else math.nan
                     for key, v in vals.items()}
        out[name]["seeds"] = len(runs)
    return out


def mechanism_table(mech: dict[str, dict[str, float]]) -> str:
    """Markdown: one row per field, one column per strategy (means over seeds)."""
    names = list(mech)
    lines = ["| mean over seeds | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
    for key, label, _, spec in FIELDS:
        cells = ["—" if not math.isfinite(mech[n].get(key, math.nan)) else format(mech[n][key], spec)
                 for n in names]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
