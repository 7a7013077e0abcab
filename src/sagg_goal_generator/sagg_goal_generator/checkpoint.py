"""Checkpoint and resume of the goal generator (ROS-free; used by the goal-generator node).

Files in the checkpoint directory (``g`` = generation):

- ``generator.json``: generation, reports processed, the two random states
  (``bit_generator.state`` of the goal stream and of the split stream), the number of splits, the
  state file's name and the seed / strategy / task space it belongs to;
- ``generator_state_<g>.npz``: the region tree (every region: box, split, children, the points and
  competences of the leaves, the order of the leaves), the split history, every goal (seq,
  position, mode, after_report, competence) and the arrays of the strategy's teacher
  (``teacher_<name>``; its JSON values are ``teacher`` in ``generator.json``: e.g. alp-gmm's
  history, mixtures and fit stream; none for sagg-riac and sagg-random);
- ``generator_journal_<k>.bin``: write-ahead journal of the goals chosen after checkpoint ``k``
  (one record per goal, written before the goal is answered or published). Generation ``g``
  keeps journal ``g - 1`` too: a resumed node publishes the goals of both again on /sagg/goal
  (a kill can cut a publication short; receivers key goals by seq).

Why goals are journaled but reports are not: the generator's state is a deterministic function of
its seed and of the interleaving of reports and goal choices. Reports it misses while it is down
(or since its last checkpoint) are re-sent by the learner's ``/sagg/competence`` writer, which keeps
a deep transient_local history; the generator drops sequence numbers it already has. Goals chosen
since the checkpoint are the journal's: at resume they are chosen again, in the same order, as soon
as the reports they followed are back in (``after_report``), which reproduces the same random
draws and tree, and each is checked against the journaled one. A resumed generator therefore
continues exactly where the killed one was (a lockstep run is unchanged by the kill; tested).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sagg_common.checkpointer import Checkpointer
from sagg_common.journal import Journal, restore_rng, rng_state, save_npz_atomic, write_json_atomic
from sagg_common.region_arrays import restore_tree, splits_arrays, splits_from_arrays, tree_arrays

from .core import GoalGenerator, GoalRecord

REC_GOAL = 3
TEACHER_PREFIX = "teacher_"
FORMAT = "sagg.generator_checkpoint/1"


class GeneratorCheckpointer(Checkpointer):
    """Checkpoints and goal journal of one :class:`GoalGenerator` in ``directory`` (every ``every``
    reports processed)."""

    prefix, npz_kinds = "generator", ("state",)
    meta_name, meta_format, owner = "generator.json", FORMAT, "generator"

    def __init__(self, directory: str | Path, gen: GoalGenerator, every: int, fsync: bool = False):
        super().__init__(directory, every, fsync)
        self.gen = gen
        self.republish: list[GoalRecord] = []  # goals of the last journals already in the state

    def on_goal(self, rec: GoalRecord) -> None:
        """Journal a goal just chosen (call before answering or publishing it)."""
        self.journal.append(REC_GOAL, np.concatenate((
            [float(rec.seq), float(rec.after_report), float(rec.mode)], rec.position)))

    def _identity(self) -> dict:
        g = self.gen
        return {"seed": g.params["seed"], "strategy": g.strategy, "task_space.lower": g.lower.tolist(),
                "task_space.upper": g.upper.tolist()}

    def _progress(self) -> int:
        return self.gen.reports

    def save(self) -> None:
        gen = self.gen
        g = self._next_journal()
        goals = gen.goals
        teacher_arrays, teacher_meta = gen.teacher.state()
        state = self._path("state", g)
        save_npz_atomic(
            state, **tree_arrays(gen.tree), **splits_arrays(gen.tree.splits, gen.dim),
            goal_seq=np.array([r.seq for r in goals], np.int64),
            goal_position=np.array([r.position for r in goals], float).reshape(-1, gen.dim),
            goal_mode=np.array([r.mode for r in goals], np.int64),
            goal_after=np.array([r.after_report for r in goals], np.int64),
            goal_competence=np.array([np.nan if r.competence is None else r.competence for r in goals], float),
            **{TEACHER_PREFIX + k: v for k, v in teacher_arrays.items()})
        write_json_atomic(self.dir / "generator.json", {
            "format": FORMAT, "generation": g, **self._identity(), "reports": gen.reports,
            "ignored_outside": gen.ignored_outside, "goals": len(goals), "rng": rng_state(gen.rng),
            "split_rng": rng_state(gen.tree.rng), "splits": len(gen.tree.splits), "state_file": state.name,
            "teacher": teacher_meta})
        self._saved(g, "state")  # journal g - 1 is kept: its goals are published again at a resume

    def resume(self) -> list[GoalRecord]:
        """Restore the generator (if the directory holds a checkpoint). Returns the journaled goals
        chosen after the checkpoint, oldest first: the caller chooses them again (``next_goal``)
        when ``gen.reports`` reaches their ``after_report`` and compares. The journal stays open
        (appending) until those goals are replayed; then call :meth:`save`."""
        meta = self._load_meta()
        if meta is None:
            return []
        gen = self.gen
        restore_state(gen, self.dir, meta)
        g = int(meta["generation"])
        pending: list[GoalRecord] = []
        self.republish = []
        for _, kind, v in self.journal_records(g):
            if kind != REC_GOAL:
                continue
            seq = int(v[0])
            if seq <= len(gen.goals):
                self.republish.append(gen.goals[seq - 1])
            elif seq == len(gen.goals) + len(pending) + 1:
                pending.append(GoalRecord(seq, v[3:].copy(), int(v[2]), int(v[1])))
        self.generation = max([g] + self._generations("journal"))
        # keep appending to the newest journal: goals replayed from it are in it already
        self.journal = Journal(self._path("journal", self.generation), self.fsync)
        self.saved_at = gen.reports
        self.resumed_from = {"generation": g, "reports": gen.reports, "goals": len(gen.goals),
                             "pending_goals": len(pending), "torn_bytes": self.torn_bytes}
        return pending


def restore_state(gen: GoalGenerator, directory: Path, meta: dict) -> None:
    """Put the state of ``generator.json`` (``meta``) and its state file into ``gen``: the tree,
    the split history, the goals, the teacher's state, the counters and both random streams."""
    with np.load(directory / meta["state_file"], allow_pickle=False) as z:
        restore_tree(gen.tree, z)
        gen.tree.splits = splits_from_arrays(z)
        gen.goals = [GoalRecord(int(s), p.copy(), int(m), int(a), None if np.isnan(c) else float(c))
                     for s, p, m, a, c in zip(z["goal_seq"], z["goal_position"], z["goal_mode"],
                                              z["goal_after"], z["goal_competence"])]
        gen.teacher.restore({k[len(TEACHER_PREFIX):]: z[k] for k in z.files if k.startswith(TEACHER_PREFIX)},
                            meta.get("teacher", {}))
    gen.reports = int(meta["reports"])
    gen.ignored_outside = int(meta["ignored_outside"])
    restore_rng(gen.rng, meta["rng"])
    restore_rng(gen.tree.rng, meta["split_rng"])


def teacher_snapshot(directory: str | Path, params: dict) -> dict | None:
    """The teacher's ``snapshot`` (what reports draw) as of the generator checkpoint in
    ``directory`` (the node's last one: it writes one at shutdown), read only; None without a
    checkpoint or for a teacher without a view of its own (sagg-riac, sagg-random). ``params``:
    the generator node's parameters of the run."""
    directory = Path(directory)
    if not (directory / "generator.json").is_file():
        return None
    gen = GoalGenerator(params)
    restore_state(gen, directory, json.loads((directory / "generator.json").read_text()))
    return gen.teacher.snapshot()


def checkpoint_splits(directory: str | Path) -> list[dict] | None:
    """The split history (the dicts of ``RegionTree.splits``) in the generator checkpoint in
    ``directory`` (the node's last one: it writes one at shutdown), read only; None without one."""
    directory = Path(directory)
    if not (directory / "generator.json").is_file():
        return None
    meta = json.loads((directory / "generator.json").read_text())
    with np.load(directory / meta["state_file"], allow_pickle=False) as z:
        return splits_from_arrays(z)


def published(directory: str | Path) -> dict | None:
    """What the generator checkpoint in ``directory`` holds, read only (None without a
    checkpoint): ``goals`` (every goal it chose: the state's and the journaled ones) and
    ``first_goal``, the oldest journaled goal a resume publishes again (None when none is)."""
    directory = Path(directory)
    if not (directory / "generator.json").is_file():
        return None
    meta = json.loads((directory / "generator.json").read_text())
    ck = GeneratorCheckpointer(directory, None, 1)  # (reading: no generator)
    goals, first = int(meta["goals"]), None
    for _, kind, v in ck.journal_records(int(meta["generation"])):
        if kind == REC_GOAL:
            first = int(v[0]) if first is None else first
            goals = max(goals, int(v[0]))
    return {"goals": goals, "first_goal": first, "torn_bytes": ck.torn_bytes}
