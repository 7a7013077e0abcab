"""The archive of finished comparison runs: what a paper-scale result needs to be resumed, re-decided
and drawn later, small enough to commit (``sagg reproduce ... --archive DIR``).

Paper-scale reproduction takes more compute than one working session has (docs/reproduction), and a
session's raw run directories are not kept. So every finished run of a ``sagg bench compare``
directory (``EXP/runs/<strategy>/seed-<s>/result.json``) is also written, compacted, to
``ARCHIVE/runs/<strategy>/seed-<s>/result.json``, with the experiment's settings fingerprint
``ARCHIVE/compare.json``; a later session restores them into its own comparison directory before
running, so only what is missing runs (the comparison's own resume check validates each restored
result against the settings, exactly as a local one).

Compacting (JSON on one line) drops what grows with the run's length and is not needed by any
summary, verdict or figure of a comparison: the per-goal list ``goals`` (replaced by ``goal_histogram``, the counts the
report's goal histograms draw), the region tree ``regions`` and its split history ``splits``
(drawn only by a single run's report). Everything else (curve, final
errors, goal_stats, phases, coverage, memory digest, config, commit) is kept as computed.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np

from sagg_common.journal import write_json_atomic

HISTOGRAM_BINS = 40          # cells per task dimension of the goal histogram (the report's figure)
DROPPED = ("goals", "regions", "splits")


def goal_histogram(positions: np.ndarray, lower, upper, bins: int = HISTOGRAM_BINS) -> dict:
    """Counts of goal positions (first two task dimensions) on a ``bins`` × ``bins`` grid over Y,
    sparse: ``cells`` = [[i, j, count], ...] for the non-empty cells (i along y1, j along y2);
    goals outside Y are left out, as ``numpy.histogram2d`` does."""
    pos = np.asarray(positions, dtype=float).reshape(-1, len(lower))[:, :2]
    lo, hi = [float(v) for v in lower[:2]], [float(v) for v in upper[:2]]
    counts, _, _ = np.histogram2d(pos[:, 0], pos[:, 1], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]])
    ii, jj = np.nonzero(counts)
    return {"bins": bins, "lower": lo, "upper": hi,
            "cells": [[int(i), int(j), int(counts[i, j])] for i, j in zip(ii, jj)]}


def histogram_of(result: dict) -> dict | None:
    """A result's goal histogram: the archived one, else computed from its ``goals`` (None when the
    strategy chose no goals)."""
    if result.get("goal_histogram"):
        return result["goal_histogram"]
    goals = result.get("goals") or []
    if not goals:
        return None
    lp = result["config"]["sagg_learner"]
    return goal_histogram(np.array([g["position"] for g in goals]), lp["task_space.lower"],
                          lp["task_space.upper"])


def histogram_counts(hist: dict) -> np.ndarray:
    """The dense ``bins`` × ``bins`` counts of a :func:`goal_histogram`."""
    counts = np.zeros((hist["bins"], hist["bins"]))
    for i, j, n in hist["cells"]:
        counts[i, j] = n
    return counts


def compact(result: dict) -> dict:
    """The archived form of a ``result.json`` (module docstring)."""
    out = {k: v for k, v in result.items() if k not in DROPPED}
    hist = histogram_of(result)
    if hist is not None:
        out["goal_histogram"] = hist
    return out


def _run_files(root: Path) -> list[Path]:
    runs = root / "runs"
    return sorted(runs.glob("*/seed-*/result.json")) if runs.is_dir() else []


def archive_run(result_file: Path, exp_dir: Path, archive_dir: Path) -> Path:
    """Write the compacted ``result_file`` (a run of the comparison in ``exp_dir``) to the same
    relative place under ``archive_dir``, and the comparison's ``compare.json`` beside it."""
    result_file, exp_dir, archive_dir = Path(result_file), Path(exp_dir), Path(archive_dir)
    target = archive_dir / result_file.relative_to(exp_dir)
    target.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(target, compact(json.loads(result_file.read_text())), compact=True)
    if (exp_dir / "compare.json").exists():
        shutil.copyfile(exp_dir / "compare.json", archive_dir / "compare.json")
    return target


def archive_experiment(exp_dir: Path, archive_dir: Path) -> int:
    """Archive every finished run of the comparison in ``exp_dir``; returns how many."""
    files = _run_files(Path(exp_dir))
    for f in files:
        archive_run(f, exp_dir, archive_dir)
    return len(files)


def restore_experiment(archive_dir: Path, exp_dir: Path) -> int:
    """Copy the archived runs that ``exp_dir`` lacks into it (and ``compare.json`` when it has none,
    so the settings check of the resumed comparison applies to them); returns how many."""
    archive_dir, exp_dir = Path(archive_dir), Path(exp_dir)
    if not (archive_dir / "compare.json").exists():
        return 0
    exp_dir.mkdir(parents=True, exist_ok=True)
    if not (exp_dir / "compare.json").exists():
        shutil.copyfile(archive_dir / "compare.json", exp_dir / "compare.json")
    n = 0
    for f in _run_files(archive_dir):
        target = exp_dir / f.relative_to(archive_dir)
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(f, target)
            n += 1
    return n
