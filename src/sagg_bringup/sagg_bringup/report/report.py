"""Run reports: ``report.md`` + PNG figures in the spirit of the paper's (ROS-free).

:func:`write_report` takes a result-like dict, either an in-process ``result.json``
(:func:`sagg_bringup.inprocess.experiment.build_result`) or a graph run's ``summary.json`` (same keys, plus the
recording), and writes into ``out_dir``:

- ``learning_curve.png``: mean / median test error vs micro-actions (paper Fig. 9-12 style);
- ``goals_over_time.png``: 2-D histograms of the self-generated goals (not subgoals) in 6 time
  windows, reachable-area contour drawn (paper Fig. 7);
- ``regions_over_time.png``: the region tree's leaves at several times, rebuilt from the split
  history (paper Fig. 8); the last panel is the final tree coloured by interest;
- ``competence_map.png``: goals coloured by the competence of their attempt (paper Fig. 5/6);
- ``report.md`` referencing them, with the run's numbers.

Figures need a task space of 2 or 3 dimensions: a 2-D Y is drawn as it is, a 3-D one in its three
orthogonal projections (planes y1-y2, y1-y3, y2-y3: one row or panel each), the reachable set
projected onto each.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

# Choices for the figures (not from the paper): number of goal windows (the paper's Fig. 7 has 6),
# histogram resolution along the longer side of Y, and the number of region-tree snapshots.
GOAL_WINDOWS = 6
HIST_BINS = 20
REGION_PANELS = 6


# ----------------------------------------------------------------------------------- helpers
def _task_box(result: dict) -> tuple[np.ndarray, np.ndarray]:
    lp = result["config"]["sagg_learner"]
    return np.asarray(lp["task_space.lower"], float), np.asarray(lp["task_space.upper"], float)


def reachable_mask(result: dict):
    """The reachable set of the run's arm inside Y (a ReachableArea: a 2-D or 3-D grid), or None
    when the config has no simulated arm (e.g. a real-arm run)."""
    try:
        # lazy (heavy): mujoco
        from sagg_sim_bridge.arms import arm_reachable_area, arm_spec_from_params
        lower, upper = _task_box(result)
        spec = arm_spec_from_params(result["config"]["sagg_sim_bridge"])
        seed = int(result["config"]["sagg_learner"].get("eval.seed", 0))
        return arm_reachable_area(spec, lower, upper, seed=seed)
    except Exception:  # noqa: BLE001 - a figure overlay, never worth failing the report for
        return None


def planes(dims: int) -> list[tuple[int, int]]:
    """The planes a figure draws: Y itself when 2-D; the three orthogonal projections when 3-D."""
    return [(0, 1)] if dims < 3 else [(0, 1), (0, 2), (1, 2)]


AXIS_NAMES = ("y1", "y2", "y3")


def _draw_area(ax, area, fill: bool = False, plane: tuple[int, int] = (0, 1)) -> None:
    """The reachable set's outline (and fill) in ``plane``: a 3-D set is projected onto it."""
    if area is None:
        return
    i, j = plane
    mask = area.mask if area.mask.ndim == 2 else area.mask.any(axis=3 - i - j)
    m = mask.astype(float).T  # mask[a, b]: a along plane axis i, b along j -> image rows = j
    lo, hi = np.asarray(area.lower)[[i, j]], np.asarray(area.upper)[[i, j]]
    extent = (lo[0], hi[0], lo[1], hi[1])
    if fill:
        ax.imshow(np.where(m > 0, 1.0, np.nan), origin="lower", extent=extent, cmap="Greys",
                  vmin=0, vmax=8, interpolation="nearest", aspect="auto", zorder=0)
    nx, ny = mask.shape
    xs = lo[0] + (np.arange(nx) + 0.5) * (hi[0] - lo[0]) / nx
    ys = lo[1] + (np.arange(ny) + 0.5) * (hi[1] - lo[1]) / ny
    ax.contour(xs, ys, m, levels=[0.5], colors="tab:red", linewidths=1.0, zorder=3)


def _setup_axes(ax, lower, upper, title: str, plane: tuple[int, int] = (0, 1), dims: int = 2) -> None:
    i, j = plane
    ax.set_xlim(lower[i], upper[i])
    ax.set_ylim(lower[j], upper[j])
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    if dims > 2:
        ax.set_xlabel(AXIS_NAMES[i], fontsize=8)
        ax.set_ylabel(AXIS_NAMES[j], fontsize=8)


def _panel_size(lower, upper, plane: tuple[int, int], width: float) -> float:
    """The height of a panel ``width`` wide showing ``plane`` of Y at equal aspect."""
    i, j = plane
    return width * (upper[j] - lower[j]) / (upper[i] - lower[i])


def _goal_arrays(result: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    goals = result.get("goals") or []
    lower, _ = _task_box(result)
    pos = np.array([g["position"] for g in goals], float).reshape(-1, len(lower))
    ma = np.array([g.get("micro_actions", 0) for g in goals], float)
    comp = np.array([np.nan if g.get("competence") is None else g["competence"] for g in goals], float)
    return pos, ma, comp


def leaves_after(splits: list[dict], lower, upper, stamp: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Leaf boxes of the region tree once every split with ``stamp <= stamp`` is applied (splits in
    the order they happened; format of ``RegionTree.splits``: region, dim, value, left, right)."""
    boxes = {0: (np.asarray(lower, float), np.asarray(upper, float))}
    leaves = [0]  # the root region has id 0 (RegionTree numbers regions from 0)
    for s in splits:
        if s.get("stamp") is not None and s["stamp"] > stamp:
            break
        if s["region"] not in boxes:
            continue
        lo, hi = boxes[s["region"]]
        lu = hi.copy()
        lu[s["dim"]] = s["value"]
        rl = lo.copy()
        rl[s["dim"]] = s["value"]
        boxes[s["left"]] = (lo.copy(), lu)
        boxes[s["right"]] = (rl, hi.copy())
        i = leaves.index(s["region"])
        leaves[i:i + 1] = [s["left"], s["right"]]
    return [boxes[i] for i in leaves]


# ----------------------------------------------------------------------------------- figures
def _plt():
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt
    return plt


def fig_learning_curve(result: dict, path: Path) -> Path | None:
    curve = result.get("curve") or []
    if not curve:
        return None
    plt = _plt()
    x = [c["micro_actions"] for c in curve]
    fig, ax = plt.subplots(figsize=(6, 3.6), dpi=110)
    ax.plot(x, [c["mean_error"] for c in curve], "o-", ms=3, label="mean")
    ax.plot(x, [c["median_error"] for c in curve], "s--", ms=3, label="median")
    ax.set_xlabel("micro-actions")
    ax.set_ylabel("test error (task units)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend()
    ax.set_title(f"{result['strategy']} seed {result['seed']}: reaching error on "
                 f"{result['config']['sagg_learner'].get('eval.goals', '?')} test goals", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def fig_goals_over_time(result: dict, path: Path, area) -> Path | None:
    """Histograms of the goals in GOAL_WINDOWS time windows (paper Fig. 7): a 3 x 2 grid for a 2-D
    Y; for a 3-D Y one row per orthogonal projection, a column per window."""
    lower, upper = _task_box(result)
    pos, ma, _ = _goal_arrays(result)
    if len(lower) < 2 or len(pos) == 0:
        return None
    plt = _plt()
    total = max(float(result.get("micro_actions", 0)), float(ma.max(initial=0)), 1.0)
    edges = np.linspace(0.0, total, GOAL_WINDOWS + 1)
    sels, labels = [], []
    for w in range(GOAL_WINDOWS):
        last = w == GOAL_WINDOWS - 1
        sel = (ma >= edges[w]) & ((ma <= edges[w + 1]) if last else (ma < edges[w + 1]))
        sels.append(sel)
        labels.append(f"micro-actions {edges[w]:,.0f}-{edges[w + 1]:,.0f}\n{int(sel.sum())} goals")
    dims = len(lower)
    panels = [(w, pl) for pl in planes(dims) for w in range(GOAL_WINDOWS)]
    hists = []
    for w, (i, j) in panels:
        ext = upper[[i, j]] - lower[[i, j]]
        nb = (np.maximum(1, np.round(HIST_BINS * ext / ext.max()))).astype(int)
        sel = sels[w]
        h, _, _ = np.histogram2d(pos[sel, i], pos[sel, j], bins=nb, range=[[lower[i], upper[i]], [lower[j], upper[j]]])
        hists.append(h / sel.sum() if sel.sum() else h)
    vmax = max(float(h.max()) for h in hists) or 1.0
    cols = 3 if dims < 3 else GOAL_WINDOWS
    rows = math.ceil(len(panels) / cols)
    height = sum(_panel_size(lower, upper, pl, 3.4) for pl in planes(dims)) * (2 if dims < 3 else 1)
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, height + 0.6 * rows), dpi=110, squeeze=False)
    im = None
    for k, ax in enumerate(axes.flat):
        if k >= len(panels):
            ax.axis("off")
            continue
        w, (i, j) = panels[k]
        im = ax.imshow(hists[k].T, origin="lower", extent=(lower[i], upper[i], lower[j], upper[j]),
                       cmap="Blues", vmin=0, vmax=vmax, interpolation="nearest")
        _draw_area(ax, area, plane=(i, j))
        sel = sels[w]
        if sel.sum() <= 400:  # few goals: also show each one
            ax.plot(pos[sel, i], pos[sel, j], ".", color="k", ms=2.5, zorder=4)
        _setup_axes(ax, lower, upper, labels[w] if dims < 3 or i == 0 and j == 1 else "", (i, j), dims)
    fig.suptitle("Self-generated goals over time (colour: share of the window's goals per cell; "
                 "red: reachable " + ("area)" if dims < 3 else "set, projected; rows: planes y1-y2, y1-y3, y2-y3)"),
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.92, 0.95))
    cax = fig.add_axes((0.93, 0.15, 0.015, 0.7))
    fig.colorbar(im, cax=cax).ax.tick_params(labelsize=7)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def fig_regions_over_time(result: dict, path: Path, area) -> Path | None:
    """The region tree's leaves at REGION_PANELS times (paper Fig. 8), the last panel coloured by
    interest; for a 3-D Y, one row per orthogonal projection (the leaves' boxes projected)."""
    lower, upper = _task_box(result)
    if len(lower) < 2:
        return None
    splits = result.get("splits") or []
    plt = _plt()
    # lazy (heavy): matplotlib
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Rectangle
    _, ma, _ = _goal_arrays(result)
    n_goals = len(result.get("goals") or [])
    stamps = [0.0] + [float(v) for v in (np.linspace(0, n_goals, REGION_PANELS)[1:-1] if n_goals else [])]
    dims = len(lower)
    cols = 3 if dims < 3 else REGION_PANELS
    rows = math.ceil(REGION_PANELS / cols) * len(planes(dims))
    height = sum(_panel_size(lower, upper, pl, 3.4) for pl in planes(dims)) * (2 if dims < 3 else 1)
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, height + 0.6 * rows), dpi=110, squeeze=False)
    flat = list(axes.flat)

    def when(goals: float) -> str:
        k = int(goals)
        if 0 < k <= len(ma):
            return f"after {k} goals\n(~{ma[k - 1]:,.0f} micro-actions)"
        return f"after {k} goals"

    final = result.get("regions") or []
    per_plane = REGION_PANELS if dims < 3 else cols
    for p, (i, j) in enumerate(planes(dims)):
        row = flat[p * per_plane:(p + 1) * per_plane]
        first = p == 0

        def rect(lo, hi):
            lo, hi = np.asarray(lo, float), np.asarray(hi, float)
            return Rectangle((lo[i], lo[j]), hi[i] - lo[i], hi[j] - lo[j])

        # early panels: leaf outlines from the split history
        for ax, s_ in zip(row, stamps):
            boxes = leaves_after(splits, lower, upper, s_)
            _draw_area(ax, area, fill=True, plane=(i, j))
            ax.add_collection(PatchCollection([rect(lo, hi) for lo, hi in boxes], facecolor="none", edgecolor="k",
                                              linewidth=0.6, alpha=1.0 if dims < 3 else 0.5))
            _setup_axes(ax, lower, upper, f"{when(s_)}: {len(boxes)} region{'s' if len(boxes) != 1 else ''}"
                        if first else "", (i, j), dims)
        # last panel: the final tree, coloured by interest
        ax = row[len(stamps)]
        if final:
            coll = PatchCollection([rect(r["lower"], r["upper"]) for r in final], cmap="magma", edgecolor="0.6",
                                   linewidth=0.3, alpha=1.0 if dims < 3 else 0.35)
            coll.set_array(np.array([r["interest"] for r in final], float))
            ax.add_collection(coll)
            cb = fig.colorbar(coll, ax=ax, fraction=0.046, pad=0.03)
            cb.set_label("interest", fontsize=8)
            cb.ax.tick_params(labelsize=7)
        _draw_area(ax, area, plane=(i, j))
        _setup_axes(ax, lower, upper, f"final: {len(final)} regions\ncoloured by interest" if first else "",
                    (i, j), dims)
        for ax in row[len(stamps) + 1:]:
            ax.axis("off")
    fig.suptitle("Region tree over time (grey / red: reachable " + ("area)" if dims < 3 else
                 "set, projected; rows: planes y1-y2, y1-y3, y2-y3)"), fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def fig_competence_map(result: dict, path: Path, area) -> Path | None:
    """Goals coloured by the competence of their attempt (paper Fig. 5/6); for a 3-D Y the three
    orthogonal projections side by side."""
    lower, upper = _task_box(result)
    pos, _, comp = _goal_arrays(result)
    ok = np.isfinite(comp)
    if len(lower) < 2 or not ok.any():
        return None
    plt = _plt()
    dims = len(lower)
    pls = planes(dims)
    width = 6.0 if dims < 3 else 4.6
    height = max(_panel_size(lower, upper, pl, width) for pl in pls)
    fig, axes = plt.subplots(1, len(pls), figsize=(width * len(pls), 0.87 * height + 0.6), dpi=110, squeeze=False)
    order = np.argsort(-comp[ok])  # draw the worst on top
    sc = None
    for ax, (i, j) in zip(axes.flat, pls):
        _draw_area(ax, area, fill=True, plane=(i, j))
        sc = ax.scatter(pos[ok, i][order], pos[ok, j][order], c=comp[ok][order], cmap="RdYlGn",
                        vmin=-1.0, vmax=0.0, s=16, edgecolors="none", zorder=4)
        _setup_axes(ax, lower, upper, f"Competence map: {int(ok.sum())} goals (red contour: reachable "
                    + ("area)" if dims < 3 else f"set, projected), plane {AXIS_NAMES[i]}-{AXIS_NAMES[j]}"),
                    (i, j), dims)
    cb = fig.colorbar(sc, ax=list(axes.flat), fraction=0.046 / len(pls), pad=0.03, shrink=0.8)
    cb.set_label("competence Γ of the goal's attempt (0 = reached)", fontsize=8)
    cb.ax.tick_params(labelsize=7)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


def fig_teacher(result: dict, path: Path, area) -> Path | None:
    """Where a teacher beyond the paper sent its goals (``result["teacher"]``), plane y1-y2:
    alp-gmm: its mixtures at up to REGION_PANELS fits, each Gaussian's 2-sigma ellipse coloured by
    its mean ALP, over the goals chosen until the next fit; discretized-progress: its grid's final
    absolute progress per cell and the mean normalised competence of each cell's window."""
    t = result.get("teacher")
    lower, upper = _task_box(result)
    if not t or len(lower) < 2:
        return None
    plt = _plt()
    # lazy (heavy): matplotlib
    from matplotlib.patches import Ellipse
    width = 4.6
    height = _panel_size(lower, upper, (0, 1), width)
    if t["teacher"] == "alp-gmm":
        fits = t["fits"]
        if not fits:
            return None
        pick = sorted({int(round(i)) for i in np.linspace(0, len(fits) - 1, min(REGION_PANELS, len(fits)))})
        pos = _goal_arrays(result)[0]
        fig, axes = plt.subplots(1, len(pick), figsize=(width * len(pick), 0.87 * height + 0.6), dpi=110,
                                 squeeze=False)
        top = max(max(m[-1] for m in f["means"]) for f in fits) or 1.0
        for ax, i in zip(axes.flat, pick):
            f = fits[i]
            end = fits[i + 1]["goals"] if i + 1 < len(fits) else len(pos)
            _draw_area(ax, area, plane=(0, 1))
            ax.scatter(pos[f["goals"]:end, 0], pos[f["goals"]:end, 1], s=5, c="0.5", zorder=3)
            for m, c in zip(f["means"], f["covariances"]):
                vals, vecs = np.linalg.eigh(np.asarray(c)[:2, :2])
                angle = math.degrees(math.atan2(vecs[1, -1], vecs[0, -1]))
                ax.add_patch(Ellipse(m[:2], *(4 * np.sqrt(np.clip(vals[::-1], 0, None))), angle=angle, fill=False,
                                     lw=1.5, color=plt.cm.viridis(m[-1] / top), zorder=4))
            _setup_axes(ax, lower, upper, f"mixture fitted after {f['goals']} goals", (0, 1), len(lower))
    else:
        shape = t["shape"]
        grids = [np.abs(np.reshape(t["progress"], shape)), np.reshape(t["competence"], shape)]
        if len(shape) > 2:  # 3-D: the largest over y3 (progress), the mean over y3 (competence)
            grids = [grids[0].max(axis=tuple(range(2, len(shape)))), grids[1].mean(axis=tuple(range(2, len(shape))))]
        fig, axes = plt.subplots(1, 2, figsize=(width * 2, 0.87 * height + 0.6), dpi=110, squeeze=False)
        titles = ("|progress| per cell (final)", "window mean competence (0-1) per cell")
        for ax, g, title, cmap in zip(axes.flat, grids, titles, ("magma", "RdYlGn")):
            im = ax.imshow(g.T, origin="lower", extent=(lower[0], upper[0], lower[1], upper[1]), cmap=cmap,
                           aspect="auto")
            _draw_area(ax, area, plane=(0, 1))
            _setup_axes(ax, lower, upper, title, (0, 1), len(lower))
            fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03, shrink=0.8)
    fig.savefig(path, bbox_inches="tight")
    plt.close(fig)
    return path


# ----------------------------------------------------------------------------------- markdown
def _fmt(x: Any, digits: int = 4) -> str:
    if isinstance(x, float):
        return "nan" if math.isnan(x) else f"{x:.{digits}g}"
    if isinstance(x, int):
        return f"{x:,}"
    return str(x)


def _metric_rows(result: dict) -> list[tuple[str, Any]]:
    """The evaluation's other metrics at the last point (sagg_low_level.eval_metrics): share of test
    goals within tolerance and mean error per distance-from-base band; nothing for runs written
    before these metrics existed."""
    last = result["curve"][-1] if result.get("curve") else {}
    frame = result.get("eval_metrics") or {}
    if last.get("within_share") is None:
        return []
    rows = [(f"final share of test goals within {_fmt(float(frame.get('within', float('nan'))), 3)}",
             float(last["within_share"]))]
    edges = frame.get("band_edges")
    bands = last.get("band_mean_errors") or []
    if edges and len(edges) == len(bands) + 1:
        cells = [f"{_fmt(float(a), 3)}-{_fmt(float(b), 3)}: {'–' if e is None else _fmt(float(e), 3)}"
                 for a, b, e in zip(edges, edges[1:], bands)]
        rows.append(("final mean error per distance-from-base band", "; ".join(cells)))
    return rows


def _curve_rows(curve: list[dict], max_rows: int = 12) -> list[dict]:
    if len(curve) <= max_rows:
        return curve
    idx = np.unique(np.round(np.linspace(0, len(curve) - 1, max_rows)).astype(int))
    return [curve[i] for i in idx]


def synergy_rows(bp: dict) -> list[tuple[str, str]]:
    """The report rows of a synergy set-up's robot (``setup`` = quadruped / fishing, with its
    controller and outcome topic), from its bridge parameters."""
    return [("set-up", f"{bp.get('setup')} (synergies, fixed context; trajectories on "
                       f"{bp.get('controller')}, outcome on {bp.get('task_topic')})")]


# the extra row of the arm in the fixed context
FIXED_ARM_ROWS = [("context", "fixed (θ = joint targets, one position command from rest per experiment; "
                              "micro-actions = experiments)")]


def arm_rows(bp: dict) -> list[tuple[str, str]]:
    """The report rows of a simulated arm (``arm.*`` bridge parameters); none without them (a run
    on a real arm)."""
    if not bp:
        return []
    arm = {k[4:]: v for k, v in bp.items() if k.startswith("arm.")}
    links = (f"link ratio {arm['link_ratio']:g}" if arm.get("link_ratio") else f"{arm.get('link_profile')} links")
    return [("arm", f"{arm.get('dof')} DOF, {links}, length "
                    f"{arm.get('total_length')}, {arm.get('mode')}, motor noise {arm.get('motor_noise')}")]


def write_report(result: dict | str | Path, out_dir: str | Path, area=None, setup_rows=()) -> Path:
    """Write ``report.md`` and its PNG figures into ``out_dir`` and return the report's path.

    ``result`` is a result-like dict (or a path to ``result.json`` / ``summary.json``); ``area``
    (optional) the run's ReachableArea of Y when already computed; ``setup_rows``: the rows that
    describe the run's robot (the set-up registry's :meth:`~sagg_bringup.graph.setups.Setup.report_rows`)."""
    if not isinstance(result, dict):
        result = json.loads(Path(result).read_text())
    for key in ("strategy", "seed", "config", "micro_actions", "curve"):
        if key not in result:
            raise ValueError(f"result: missing key {key!r}; a result.json or summary.json is required")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if area is None:
        area = reachable_mask(result)
    figs = {
        "learning_curve": fig_learning_curve(result, out / "learning_curve.png"),
        "goals_over_time": fig_goals_over_time(result, out / "goals_over_time.png", area),
        "regions_over_time": fig_regions_over_time(result, out / "regions_over_time.png", area),
        "competence_map": fig_competence_map(result, out / "competence_map.png", area),
        "teacher": fig_teacher(result, out / "teacher.png", area),
    }
    graph = "bag" in result
    lines = [f"# {'Graph' if graph else 'In-process'} run: {result['strategy']}, seed {result['seed']}", ""]
    rows = _summary_rows(result) + list(setup_rows)
    lines += ["| | |", "|---|---|"] + [f"| {k} | {_fmt(v)} |" for k, v in rows] + [""]
    lines += _curve_section(result, figs) + _figure_sections(result, figs)
    if graph:
        lines += _recording_section(result["bag"])
    path = out / "report.md"
    path.write_text("\n".join(lines))
    return path


def _summary_rows(result: dict) -> list[tuple[str, Any]]:
    """The report's table: the run, its errors and metrics, goals and regions, memory, prior, Y."""
    lp = result["config"]["sagg_learner"]
    nan = float("nan")
    rows = [
        ("strategy", result["strategy"]), ("seed", result["seed"]),
        ("micro-actions", result["micro_actions"]),
        ("micro-actions / s (learning)", float(result.get("micro_actions_per_second", nan))),
    ]
    if "wall_seconds" in result:
        rows.append(("wall time (s)", float(result["wall_seconds"])))
    if "timing" in result:
        rows.append(("bridge timing", result["timing"]))
    rows += [
        ("final mean test error", float(result.get("final_mean_error", nan))),
        ("final median test error", float(result.get("final_median_error", nan))),
        ("initial mean test error", float(result["curve"][0]["mean_error"]) if result["curve"] else nan),
    ]
    rows += _metric_rows(result)
    rows += [
        ("goals", len(result.get("goals") or [])),
        ("regions (final)", len(result.get("regions") or [])),
        ("splits", len(result.get("splits") or [])),
    ]
    mem = result.get("memory") or {}
    if mem:
        rows.append(("memory samples", mem.get("samples")))
        rows.append(("memory digest", f"`{mem.get('digest')}`"))
    prior = result.get("prior")
    if prior:
        rows.append(("prior (another run's samples)",
                     f"{prior['samples']:,} samples, {prior['superseded']:,} superseded by the robot's"
                     + (f"; from {prior['source']}" if prior.get("source") else "")))
    gs = result.get("goal_stats") or {}
    if gs:
        rows.append(("reachable share of Y", float(gs.get("reachable_share_of_Y", nan))))
        rows.append(("goals in reachable area (all / 2nd half)",
                     f"{_fmt(float(gs.get('goal_share_reachable', nan)), 3)} / "
                     f"{_fmt(float(gs.get('goal_share_reachable_second_half', nan)), 3)}"))
    task = f"[{', '.join(_fmt(float(v)) for v in lp['task_space.lower'])}] – " \
           f"[{', '.join(_fmt(float(v)) for v in lp['task_space.upper'])}]"
    rows.append(("task space Y (lower – upper)", task))
    return rows


def _curve_section(result: dict, figs: dict) -> list[str]:
    """The learning curve: what the test error is, its figure and its table."""
    lp = result["config"]["sagg_learner"]
    lines = ["## Learning curve", "",
             f"Test error of the frozen model on {lp.get('eval.goals')} fixed test goals "
             f"(eval.seed {lp.get('eval.seed')}), reached from the rest posture without learning.", ""]
    if figs["learning_curve"]:
        lines += ["![learning curve](learning_curve.png)", ""]
    lines += ["| micro-actions | mean error | median error | within tolerance |", "|---:|---:|---:|---:|"]
    lines += [f"| {c['micro_actions']:,} | {c['mean_error']:.3f} | {c['median_error']:.3f} | "
              f"{_fmt(c['within_share'], 3) if c.get('within_share') is not None else '–'} |"
              for c in _curve_rows(result["curve"])] + [""]
    return lines


def _figure_sections(result: dict, figs: dict) -> list[str]:
    """The goals, regions, competence and (a teacher's) figures, each with what it shows."""
    sections = [
        ("goals_over_time", "Goals over time (cf. paper Fig. 7)",
         "2-D histograms of the self-generated goals (not subgoals) in equal windows of micro-actions."),
        ("regions_over_time", "Region splits over time (cf. paper Fig. 8)",
         "Leaves of the goal generator's region tree, rebuilt from the split history."),
        ("competence_map", "Competence map (cf. paper Fig. 5/6)",
         "Each goal coloured by the competence Γ of its reaching attempt."),
    ]
    if figs["teacher"]:  # only the teachers beyond the paper have a view of their own
        sections.append(("teacher", f"Where {result['strategy']} sent its goals", "The teacher's own model "
                         "of Y: its mixtures (alp-gmm) or its grid (discretized-progress)."))
    lines: list[str] = []
    for key, title, text in sections:
        lines += [f"## {title}", "", text, ""]
        lines += [f"![{key.replace('_', ' ')}]({key}.png)", ""] if figs[key] else ["(no figure: no goals, "
                                                                                     "or Y is 1-D)", ""]
    return lines


def _recording_section(bag: dict) -> list[str]:
    """A graph run's bag: topics and counts, what the recorder missed and what it did not use."""
    lines = ["## Recording", "", f"rosbag2 (mcap) at `{bag.get('path')}`.", "",
             "| topic | type | messages |", "|---|---|---:|"]
    lines += [f"| `{t}` | `{v['type']}` | {v['count']:,} |" for t, v in sorted(bag.get("topics", {}).items())]
    lines.append("")
    # the recorder never falls behind silently, and hostile messages are named
    dropped, rejected = bag.get("dropped") or {}, bag.get("rejected") or {}
    lines.append("Messages missed by the recorder (gaps in the publishers' sequence numbers): "
                 + (", ".join(f"`{t}` {n:,}" for t, n in sorted(dropped.items())) if dropped else "none") + "."
                 + (" Not estimated (the topic had several publishers): "
                    + ", ".join(f"`{t}`" for t in bag["dropped_not_estimated"]) + "."
                    if bag.get("dropped_not_estimated") else ""))
    lines.append("Messages recorded but not used (another publisher on the topic, or rejected content): "
                 + (", ".join(f"`{k}` {n:,}" for k, n in sorted(rejected.items())) if rejected else "none") + ".")
    lines.append("")
    return lines
