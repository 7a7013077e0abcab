"""Test helper: the sample memory stored in a learner checkpoint directory."""
from __future__ import annotations

import json
from pathlib import Path

from sagg_low_level.checkpoint import load_segments
from sagg_low_level.memory import SampleMemory


def checkpoint_memory(directory: str | Path) -> SampleMemory:
    """The sample memory of the learner checkpoint in ``directory`` (exact search; the digest does
    not depend on the search mode)."""
    meta = json.loads((Path(directory) / "learner.json").read_text())
    n, m = int(meta["joints"]), int(meta["task_dim"])
    return load_segments(directory, meta, SampleMemory(n, n, m))
