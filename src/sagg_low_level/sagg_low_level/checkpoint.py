"""Checkpoint and resume of the low-level learner (ROS-free; used by the learner node).

Files in the checkpoint directory (``g`` = generation):

- ``learner.json``: what generation ``g`` holds: counters (micro-actions, reports sent, attempts,
  goals done, exploration phases, last competence), the learner's random state
  (``bit_generator.state``), the memory's segment files (name, first index, count, sha256), length
  (and, after a shutdown, digest), and the seed / strategy / dimensions it belongs to (a checkpoint
  of another run is refused);
- ``learner_samples_<g>.npz``: the samples stored since the previous generation (append-only
  segments: a checkpoint writes only the new samples, so the total cost stays linear in the run's
  length; a full memory file at every checkpoint would write O(N^2) bytes over a long run);
- ``learner_journal_<k>.bin``: the write-ahead journal (:class:`~sagg_common.journal.Journal`) of
  everything after checkpoint ``k``: one record per stored sample and per report, written *before*
  the sample or report is published. Generation ``g`` keeps journal ``g - 1`` as well.

A checkpoint is taken every ``every`` micro-actions (by the node, right after it has published the
queued samples and reports) and at shutdown. Resume = load ``learner.json``'s generation, then
apply every journal ``>= g`` in order (a torn trailing record, from a kill in mid-write, is
dropped); so the memory holds every sample whose record was written, exactly once (records of
samples already in the memory are skipped by index). Since every sample and report is journaled
before it is published, everything any subscriber ever saw is restored.

What is not restored, by design (documented in the README): the coroutine's position inside the
current reaching attempt (or actuator babbling cycle). The resumed learner observes the robot and
starts a new attempt (a return to rest when due, then a goal request after the reports it has
sent); the interrupted attempt is abandoned (its goal gets no final report). Its random stream is
the checkpoint's state, jumped ahead (``bit_generator.jumped()``) when the journal had records past
the checkpoint, so numbers already drawn are not drawn again. ACTUATOR-RIAC's region tree over
(α, Δα) is saved whole at each checkpoint (``learner_riac_<g>.npz``, with its split stream's
state) and restored as it was then: the prediction errors of the samples journaled after the
checkpoint are not in it (they were measured against the model of that moment).

Republishing: the resumed node republishes the journaled samples and reports of the journals it
found (the last two checkpoint intervals); receivers drop indices / sequence numbers they have.
``republish_from`` adds the stored samples from that index on (from the memory), before the
journaled ones: a recorder killed with the graph loses the tail its bag had not written yet, which
may start before the journals (``sagg run --resume`` passes the number of samples its bags hold;
:func:`published` says what a resume would republish).
"""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np

from sagg_common.checkpointer import Checkpointer
from sagg_common.journal import restore_rng, rng_state, save_npz_atomic, write_json_atomic
from sagg_common.region_arrays import restore_tree, splits_arrays, splits_from_arrays, tree_arrays

from .learner import EvolvingContextLearner, Report
from .memory import SampleMemory

REC_SAMPLE, REC_REPORT = 1, 2
_COUNTERS = ("micro_actions", "reports_sent", "attempts", "goals_done", "exploration_phases")
FORMAT = "sagg.learner_checkpoint/2"


def _sha(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a, dtype="<f8").data)
    return h.hexdigest()


def load_segments(directory: str | Path, meta: dict, memory: SampleMemory) -> SampleMemory:
    """Add the samples of ``meta['segments']`` (files in ``directory``) to the empty ``memory``,
    checking each segment's first index and sha256."""
    directory = Path(directory)
    for seg in meta["segments"]:
        with np.load(directory / seg["file"], allow_pickle=False) as z:
            a, da, dy = z["alpha"], z["delta_alpha"], z["delta_y"]
        if seg["start"] != len(memory) or len(a) != seg["count"] or _sha(a, da, dy) != seg["sha256"]:
            raise ValueError(f"checkpoint_dir: segment {seg['file']} does not match learner.json")
        for i in range(len(a)):
            memory.add(a[i], da[i], dy[i])
    if len(memory) != meta["memory_samples"]:
        raise ValueError(f"checkpoint_dir: {len(memory)} samples in the segments, learner.json says "
                         f"{meta['memory_samples']}")
    return memory


def checkpoint_memory(directory: str | Path) -> SampleMemory:
    """The sample memory of the learner checkpoint in ``directory`` (exact search; the digest does
    not depend on the search mode): for tools that check a run's stored samples."""
    meta = json.loads((Path(directory) / "learner.json").read_text())
    n, m = int(meta["joints"]), int(meta["task_dim"])
    return load_segments(directory, meta, SampleMemory(n, n, m))


class LearnerCheckpointer(Checkpointer):
    """Checkpoints and journal of one :class:`EvolvingContextLearner` in ``directory`` (every
    ``every`` micro-actions)."""

    prefix, npz_kinds = "learner", ("samples", "riac")
    meta_name, meta_format, owner = "learner.json", FORMAT, "learner"

    def __init__(self, directory: str | Path, learner: EvolvingContextLearner, every: int,
                 fsync: bool = False):
        super().__init__(directory, every, fsync)
        self.learner = learner
        self.segments: list[dict] = []

    # ------------------------------------------------------------------ journal records
    def _counters(self) -> list[float]:
        lr = self.learner
        return [float(getattr(lr, c)) for c in _COUNTERS] + [float(lr.last_competence)]

    def on_sample(self, idx: int) -> None:
        """Journal sample ``idx`` (call before publishing it)."""
        mem = self.learner.memory
        self.journal.append(REC_SAMPLE, np.concatenate((
            [float(idx)], self._counters(), mem.alpha[idx], mem.delta_alpha[idx], mem.delta_y[idx])))

    def on_report(self, r: Report) -> None:
        """Journal report ``r`` (call before publishing it)."""
        target = np.asarray(r.target, float).ravel()
        self.journal.append(REC_REPORT, np.concatenate((
            [float(r.seq), float(r.goal_seq), float(r.kind), float(r.micro_actions), float(r.competence),
             float(len(target))], self._counters(), target, np.asarray(r.reached, float).ravel(),
            np.asarray(r.start, float).ravel())))

    # ------------------------------------------------------------------ files
    def _identity(self) -> dict:
        lr = self.learner
        return {"seed": lr.p["seed"], "strategy": lr.strategy, "joints": lr.robot.n, "task_dim": lr.m}

    def _progress(self) -> int:
        return self.learner.micro_actions

    def save(self, digest: bool = False) -> None:
        """New generation: switch the journal, write the samples stored since the last segment,
        then the JSON pointing at the segments; then delete journals < g - 1. ``digest``: also
        store the memory's digest (O(N): at shutdown)."""
        lr = self.learner
        mem = lr.memory
        g = self._next_journal()
        start = self.segments[-1]["start"] + self.segments[-1]["count"] if self.segments else 0
        if len(mem) > start:
            a, da, dy = mem.alpha[start:], mem.delta_alpha[start:], mem.delta_y[start:]
            path = self._path("samples", g)
            save_npz_atomic(path, alpha=a, delta_alpha=da, delta_y=dy)
            self.segments.append({"file": path.name, "start": start, "count": len(a), "sha256": _sha(a, da, dy)})
        riac = None
        tree = lr.riac_tree
        if tree is not None:
            path = self._path("riac", g)
            save_npz_atomic(path, **tree_arrays(tree), **splits_arrays(tree.splits, tree.dim))
            riac = {"file": path.name, "split_rng": rng_state(tree.rng)}
        write_json_atomic(self.dir / "learner.json", {
            "format": FORMAT, "generation": g, **self._identity(),
            **{c: int(getattr(lr, c)) for c in _COUNTERS},
            "last_competence": float(lr.last_competence), "rng": rng_state(lr.rng),
            "segments": self.segments, "memory_samples": len(mem),
            "memory_digest": mem.digest() if digest else None, "riac": riac})
        self._saved(g, "riac")

    def maybe_save(self) -> bool:
        # (the base's, without the _progress() call: this runs on every flush of the learner node)
        if self.learner.micro_actions - self.saved_at >= self.every:
            self.save()
            return True
        return False

    def _save_final(self) -> None:
        self.save(digest=True)  # shutdown: with the memory digest

    # ------------------------------------------------------------------ resume
    def resume(self, republish_from: int = -1) -> list:
        """Restore the learner from the directory (if it holds a checkpoint) and start a new
        generation. Returns what to republish, in order: sample indices (int) and
        :class:`Report` objects from the journals found, preceded by the stored samples from
        ``republish_from`` (>= 0) up to the first journaled one. Without a checkpoint: starts
        generation 1 from the learner as it is and returns []."""
        meta = self._load_meta()
        if meta is None:
            return []
        lr = self.learner
        if len(lr.memory):
            raise ValueError("resume: the learner's memory must be empty")
        mem = load_segments(self.dir, meta, lr.memory)
        if meta.get("memory_digest") is not None and mem.digest() != meta["memory_digest"]:
            raise ValueError("checkpoint_dir: the restored memory does not match the digest in "
                             f"{self.dir / self.meta_name}")
        self.segments = list(meta["segments"])
        for c in _COUNTERS:
            setattr(lr, c, int(meta[c]))
        lr.last_competence = float(meta["last_competence"])
        restore_rng(lr.rng, meta["rng"])
        if meta.get("riac"):
            tree = lr.make_riac_tree()
            with np.load(self.dir / meta["riac"]["file"], allow_pickle=False) as z:
                restore_tree(tree, z)
                tree.splits = splits_from_arrays(z)
            restore_rng(tree.rng, meta["riac"]["split_rng"])
            lr.riac_tree = tree
        g = int(meta["generation"])
        n, m = lr.robot.n, lr.m
        replay: list = []
        applied = 0
        for k, kind, v in self.journal_records(g):
            counters = v[1:7] if kind == REC_SAMPLE else v[6:12]
            if kind == REC_SAMPLE:
                idx = int(v[0])
                a, da, dy = v[7:7 + n], v[7 + n:7 + 2 * n], v[7 + 2 * n:7 + 2 * n + m]
                if idx == len(mem):
                    mem.add(a, da, dy)
                elif idx > len(mem):
                    raise ValueError(f"checkpoint_dir: journal {k} jumps to sample {idx} with "
                                     f"{len(mem)} samples restored (a journal file is missing)")
                replay.append(idx)
            elif kind == REC_REPORT:
                tlen = int(v[5])
                rest = v[12:]
                replay.append(Report(int(v[0]), int(v[1]), int(v[2]), rest[:tlen].copy(),
                                     rest[tlen:tlen + m].copy(), rest[tlen + m:tlen + 2 * m].copy(),
                                     float(v[4]), int(v[3])))
            else:
                continue
            if k >= g and counters[0] >= lr.micro_actions and counters[1] >= lr.reports_sent:
                for c, val in zip(_COUNTERS, counters[:5]):
                    setattr(lr, c, int(val))
                if not math.isnan(counters[5]):
                    lr.last_competence = float(counters[5])
                applied += 1
        if lr.micro_actions != len(mem):
            raise ValueError(f"checkpoint_dir: {lr.micro_actions} micro-actions but {len(mem)} samples restored")
        if lr.prior is not None:  # the prior samples the restored ones supersede
            lr.prior.cover_all(mem.alpha)
        if applied:
            # numbers drawn after the checkpoint must not be drawn again
            lr.rng = np.random.Generator(lr.rng.bit_generator.jumped())
        if republish_from >= 0:  # stored samples a receiver lacks, older than the journals
            first = next((i for i in replay if isinstance(i, int)), len(mem))
            replay[:0] = range(republish_from, first)
        self.resumed_from = {"generation": g, "journal_records_applied": applied,
                             "torn_bytes": self.torn_bytes, "samples": len(mem),
                             "reports": lr.reports_sent, "republish": len(replay)}
        self.generation = max([g] + self._generations("journal"))
        self.save()
        return replay


def published(directory: str | Path) -> dict | None:
    """What the learner checkpoint in ``directory`` holds and what a resume would republish, read
    only (None without a checkpoint): ``samples`` and ``reports`` (every one the learner ever
    published: checkpoint plus journal records), ``first_sample`` / ``first_report`` (the oldest
    journaled ones a resume republishes by itself; None when the journals hold none)."""
    directory = Path(directory)
    if not (directory / "learner.json").is_file():
        return None
    meta = json.loads((directory / "learner.json").read_text())
    ck = LearnerCheckpointer(directory, None, 1)  # (reading: no learner)
    samples, reports = int(meta["memory_samples"]), int(meta["reports_sent"])
    first_sample = first_report = None
    for _, kind, v in ck.journal_records(int(meta["generation"])):
        if kind == REC_SAMPLE:
            first_sample = int(v[0]) if first_sample is None else first_sample
            samples = max(samples, int(v[0]) + 1)
        elif kind == REC_REPORT:
            first_report = int(v[0]) if first_report is None else first_report
            reports = max(reports, int(v[0]))
    return {"samples": samples, "reports": reports, "first_sample": first_sample,
            "first_report": first_report, "torn_bytes": ck.torn_bytes}
