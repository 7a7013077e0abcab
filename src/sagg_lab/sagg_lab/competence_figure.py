"""Paper Fig. 6 for one run: the competence of every self-generated goal in windows of micro-actions
(a figure script: nothing in the product calls it).

    .venv/bin/python -m sagg_lab.competence_figure RUN/result.json out.png [--windows 6]
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def plot_competence_over_time(result: dict, path, windows: int = 6) -> None:
    """Competence of every self-generated goal, in ``windows`` equal windows of micro-actions
    (paper Fig. 6: competence values over time), coloured by Γ (0 = reached, −1 = moved away).
    The circle is the arm's length around its base (the reachable area's outer contour)."""
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt

    goals = [g for g in result["goals"] if g.get("competence") is not None]
    if not goals:
        raise ValueError("result has no goals with a competence to plot")
    pos = np.array([g["position"] for g in goals])
    comp = np.array([g["competence"] for g in goals], float)
    ma = np.array([g["micro_actions"] for g in goals])
    lp = result["config"]["sagg_learner"]
    lo, hi = lp["task_space.lower"], lp["task_space.upper"]
    radius = result["config"]["sagg_sim_bridge"]["arm.total_length"]
    edges = np.linspace(0, result["micro_actions"], windows + 1)
    cols = min(windows, 3)
    rows = -(-windows // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 3.6 * rows), squeeze=False)
    t = np.linspace(-np.pi / 2, np.pi / 2, 100)
    sc = None
    for i, ax in enumerate(axes.flat):
        if i >= windows:
            ax.axis("off")
            continue
        m = (ma >= edges[i]) & ((ma < edges[i + 1]) | (i == windows - 1))
        sc = ax.scatter(pos[m, 0], pos[m, 1], c=comp[m], cmap="RdYlGn", vmin=-1, vmax=0, s=9)
        ax.plot(radius * np.cos(t), radius * np.sin(t), "k-", lw=0.8)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_title(f"micro-actions {edges[i]:,.0f}-{edges[i + 1]:,.0f}\n{int(m.sum())} goals",
                     fontsize=8)
        ax.tick_params(labelsize=7)
    fig.colorbar(sc, ax=axes, shrink=0.6, label="competence Γ of the goal (0 = reached)")
    fig.suptitle(f"{result['strategy']} seed {result['seed']}: competence of self-generated goals "
                 "over time", fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("result", help="a result.json of sagg experiment / sagg run")
    ap.add_argument("png")
    ap.add_argument("--windows", type=int, default=6)
    a = ap.parse_args(argv)
    with open(a.result) as f:
        plot_competence_over_time(json.load(f), a.png, windows=a.windows)
    print(a.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
