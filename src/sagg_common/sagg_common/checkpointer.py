"""The life cycle shared by the learner's and the goal generator's checkpointers (ROS-free).

A :class:`Checkpointer` owns a checkpoint directory: numbered files (:class:`GenerationFiles`), the
write-ahead :class:`~sagg_common.journal.Journal` of the current generation, the metadata JSON
that names what a generation holds, and the schedule (a checkpoint every ``every`` units of
progress, and a final one at :meth:`close`). What a generation holds and how it is restored is the
subclass's: it sets ``prefix``, ``npz_kinds``, ``meta_name``, ``meta_format`` and ``owner`` and
defines :meth:`_identity`, :meth:`_progress`, ``save`` and ``resume`` (with the helpers below).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Iterator

import numpy as np

from .journal import GenerationFiles, Journal, read_journal


class Checkpointer(GenerationFiles):
    """Checkpoints and journal of one component in ``directory``, every ``every`` units of
    :meth:`_progress` (an integer >= 1); ``fsync``: fsync the journal after every record."""

    meta_name: str    # the metadata JSON in the directory, e.g. "learner.json"
    meta_format: str  # its "format" value (a checkpoint of another format is refused)
    owner: str        # what is checkpointed, for messages: "learner", "generator"

    def __init__(self, directory: str | Path, every: int, fsync: bool = False):
        if int(every) < 1:
            raise ValueError(f"checkpoint_every: got {every}; allowed: an integer >= 1")
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        self.every = int(every)
        self.fsync = fsync
        self.generation = 0
        self.saved_at = 0
        self.journal: Journal | None = None
        self.torn_bytes = 0
        self.resumed_from: dict | None = None

    # ------------------------------------------------------------------ to define
    def _identity(self) -> dict:
        """The run a checkpoint belongs to (seed, strategy, dimensions): stored in the metadata,
        compared at resume."""
        raise NotImplementedError

    def _progress(self) -> int:
        """The counter ``every`` is measured in (micro-actions, reports processed)."""
        raise NotImplementedError

    def save(self) -> None:
        raise NotImplementedError

    def _save_final(self) -> None:
        """The checkpoint taken at :meth:`close`."""
        self.save()

    def check_resume(self, resume: bool) -> None:
        """Refuse a directory that holds a checkpoint unless asked to continue it (``resume``):
        a node started on another run's parameters (a ``params.yaml`` of an older ``sagg run`` names
        its run's ``checkpoint_dir``) must neither continue that run nor overwrite its checkpoint.
        ValueError naming the directory and what is allowed; nothing is written."""
        meta = self.dir / self.meta_name
        if not resume and meta.exists():
            raise ValueError(
                f"'{self.dir}' holds a {self.owner} checkpoint ({self.meta_name}) and parameter 'resume' is "
                "false: not starting, so that run is neither continued nor overwritten (its files are left "
                "unchanged); allowed: resume:=true to continue it (`sagg run --resume DIR` does), or a "
                "checkpoint_dir without a checkpoint (a params.yaml written by an older `sagg run` names its "
                "run's checkpoint_dir: remove that line to start a new run)")

    # ------------------------------------------------------------------ schedule
    def maybe_save(self) -> bool:
        if self._progress() - self.saved_at >= self.every:
            self.save()
            return True
        return False

    def close(self) -> None:
        """Final checkpoint and close the journal."""
        self._save_final()
        self.journal.close()

    # ------------------------------------------------------------------ helpers of save / resume
    def _next_journal(self) -> int:
        """Start the journal of the next generation ``g`` (closing the current one); returns ``g``.
        Called first in ``save``: whatever happens after the files are written goes to it."""
        g = self.generation + 1
        old = self.journal
        self.journal = Journal(self._path("journal", g), self.fsync)
        if old is not None:
            old.close()
        return g

    def _saved(self, g: int, kind: str) -> None:
        """Generation ``g`` is complete (its metadata written): delete journals < ``g - 1`` (journal
        ``g - 1`` is republished at a resume) and the files of ``kind`` older than ``g``."""
        self.generation = g
        self.saved_at = self._progress()
        self._prune("journal", g - 1)
        self._prune(kind, g)

    def _load_meta(self) -> dict | None:
        """The metadata of the checkpoint in the directory, checked to be of this format and this
        run (ValueError naming the mismatch otherwise); None when the directory holds no checkpoint,
        after saving generation 1 from the component as it is."""
        meta_path = self.dir / self.meta_name
        if not meta_path.exists():
            self.save()
            return None
        meta = json.loads(meta_path.read_text())
        if meta.get("format") != self.meta_format:
            raise ValueError(f"checkpoint_dir: {meta_path} has format {meta.get('format')!r}; "
                             f"allowed: {self.meta_format!r}")
        for k, v in self._identity().items():
            if meta.get(k) != v:
                raise ValueError(f"checkpoint_dir: {meta_path} belongs to a run with {k} = {meta.get(k)!r}, "
                                 f"this {self.owner} has {v!r}; allowed: a checkpoint of the same run or an "
                                 "empty directory")
        return meta

    def journal_records(self, g: int) -> Iterator[tuple[int, int, np.ndarray]]:
        """``(k, kind, values)`` of every complete record of the journals ``k >= g - 1`` found, in
        order; the torn bytes dropped are added to ``torn_bytes``."""
        for k in self._generations("journal"):
            if k < g - 1:
                continue
            records, torn = read_journal(self._path("journal", k))
            self.torn_bytes += torn
            for kind, v in records:
                yield k, kind, v
