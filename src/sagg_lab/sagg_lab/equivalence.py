"""Before/after equivalence of learning, cell by cell (a change that only changes floats is shown
equivalent statistically, not bit for bit)::

    python -m sagg_lab.equivalence BEFORE_DIR AFTER_DIR [--alpha 0.2] [--out FILE.md]

Both directories hold the runs of the same command on two trees (``sagg bench quality --out``,
``sagg bench compare --out``): every ``.../seed-<s>/result.json``. A cell is a run's directory
without its seed (e.g. ``evolving/config/sagg-riac`` or ``runs/sagg-riac``) and an evaluation
point; per cell the test errors over seeds (the curve's ``mean_error`` at that point) before and
after: mean ± std, the two-sided Mann-Whitney p and the Welch p (``compare.pairwise_tests``, as
``sagg bench compare`` reports them). A cell is *within the seed spread* when its Mann-Whitney p
exceeds ``--alpha`` (default 0.2). The same seeds must be on both sides (checked).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from sagg_bringup.experiments.compare import pairwise_tests


def runs_by_cell(root: Path) -> dict[str, dict[int, dict]]:
    """{cell directory (relative, seed removed): {seed: result}} of every result.json under root."""
    out: dict[str, dict[int, dict]] = {}
    for f in sorted(Path(root).rglob("result.json")):
        rel = f.parent.relative_to(root)
        if not rel.name.startswith("seed-"):
            continue
        out.setdefault(str(rel.parent), {})[int(rel.name[len("seed-"):])] = json.loads(f.read_text())
    return out


def errors_at(results: dict[int, dict]) -> dict[int, dict[int, float]]:
    """{evaluation point: {seed: mean test error}}."""
    pts: dict[int, dict[int, float]] = {}
    for seed, r in results.items():
        for c in r["curve"]:
            pts.setdefault(int(c["micro_actions"]), {})[seed] = float(c["mean_error"])
    return pts


def compare_dirs(before: Path, after: Path, alpha: float = 0.2) -> list[dict]:
    """One row per (cell, evaluation point > 0) present in both directories."""
    b, a = runs_by_cell(before), runs_by_cell(after)
    rows = []
    for cell in sorted(set(b) & set(a)):
        eb, ea = errors_at(b[cell]), errors_at(a[cell])
        for point in sorted(set(eb) & set(ea)):
            if point == 0:
                continue
            if set(eb[point]) != set(ea[point]):
                raise ValueError(f"{cell} at {point}: seeds {sorted(eb[point])} before, {sorted(ea[point])} after")
            seeds = sorted(eb[point])
            x = np.array([eb[point][s] for s in seeds])
            y = np.array([ea[point][s] for s in seeds])
            t = pairwise_tests(x, y)
            rows.append({"cell": cell, "point": point, "seeds": len(seeds), "before": x.tolist(),
                         "after": y.tolist(), "mannwhitney_p": t["mannwhitney_p"], "welch_p": t["welch_p"],
                         "within": bool(t["mannwhitney_p"] > alpha),
                         "identical": bool(np.array_equal(x, y))})
    return rows


def _ms(v) -> str:
    v = np.asarray(v, float)
    return f"{v.mean():.4g} ± {v.std(ddof=1) if len(v) > 1 else 0.0:.2g}"


def table(rows: list[dict], alpha: float) -> str:
    lines = ["| cell | point | seeds | before | after | Mann-Whitney p | Welch p | within the spread |",
             "|---|---:|---:|---|---|---:|---:|---|"]
    for r in rows:
        verdict = "identical" if r["identical"] else ("yes" if r["within"] else f"**no** (p <= {alpha})")
        lines.append(f"| {r['cell']} | {r['point']} | {r['seeds']} | {_ms(r['before'])} | {_ms(r['after'])} | "
                     f"{r['mannwhitney_p']:.3g} | {r['welch_p']:.3g} | {verdict} |")
    n_out = sum(not r["within"] and not r["identical"] for r in rows)
    lines.append("")
    lines.append(f"{len(rows)} cells, {n_out} with a two-sided Mann-Whitney p <= {alpha}")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.equivalence", description=__doc__.split("\n\n")[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--alpha", type=float, default=0.2)
    ap.add_argument("--out", help="also write the table to this markdown file")
    a = ap.parse_args(argv)
    rows = compare_dirs(Path(a.before), Path(a.after), a.alpha)
    if not rows:
        print("no common cells (result.json under .../seed-<s>/ in both directories)", file=sys.stderr)
        return 2
    text = table(rows, a.alpha)
    print(text)
    if a.out:
        Path(a.out).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
