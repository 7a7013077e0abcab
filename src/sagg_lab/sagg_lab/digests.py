"""Digests of finished runs, for bit-identity proofs (a refactoring must not change behaviour)::

    python -m sagg_lab.digests RUN_DIR_OR_JSON...

Each argument is a ``result.json`` (``sagg experiment``), a ``summary.json`` (``sagg run``) or the
directory holding one. Per run it prints the number of samples and the memory digest the run
computed itself, and sha256 prefixes of the goals (seq, position, mode, competence) and of the
evaluation curve (micro-actions, mean and median error); for a graph run with a checkpoint, also of
the goal generator's final state file (region tree, split history, every goal: the generator's own
record). The ``splits`` of a ``summary.json`` are not digested: ``sagg run`` rebuilds them from the
depth-1 ``/sagg/regions`` snapshots, and when two snapshots coalesce the order of the two splits
between them is a matter of timing. Floats are digested as JSON text (``repr``: exact).
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np


def _sha(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def generator_state_sha(checkpoint_dir: Path) -> str | None:
    """sha256 prefix of every array of the goal generator's last checkpoint state, or None."""
    meta_path = checkpoint_dir / "generator.json"
    if not meta_path.is_file():
        return None
    meta = json.loads(meta_path.read_text())
    h = hashlib.sha256()
    with np.load(checkpoint_dir / meta["state_file"], allow_pickle=False) as z:
        for name in sorted(z.files):
            h.update(name.encode())
            h.update(np.ascontiguousarray(z[name]).tobytes())
    return h.hexdigest()[:16]


def run_digests(path: str | Path) -> dict:
    """The digests of one run (see the module docstring)."""
    p = Path(path)
    if p.is_dir():
        p = p / "result.json" if (p / "result.json").is_file() else p / "summary.json"
    d = json.loads(p.read_text())
    curve = d["curve"]
    out = {
        "file": str(p),
        "samples": d["memory"]["samples"],
        "memory": d["memory"]["digest"],
        "goals": len(d["goals"]),
        "goals_sha": _sha([[g["seq"], g["position"], g["mode"], g["competence"]] for g in d["goals"]]),
        "curve_sha": _sha([[c["micro_actions"], c["mean_error"], c["median_error"]] for c in curve]),
        "final_mean_error": curve[-1]["mean_error"] if curve else None,
    }
    state = generator_state_sha(p.parent / "checkpoint")
    if state is not None:
        out["generator_state_sha"] = state
    return out


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args:
        print(__doc__.strip().splitlines()[0], file=sys.stderr)
        return 2
    for a in args:
        r = run_digests(a)
        print(f"{r.pop('file')}: " + " ".join(f"{k} {v}" for k, v in r.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
