"""What a run's bags recorded, read back for ``sagg relearn`` (:func:`~sagg_bringup.bags.bags.relearn`):
samples, competence reports, goals and region-tree snapshots, each message checked as the nodes check
it; and the goal generator fed the recorded reports as the node feeds it, its goals and trees
compared with the recorded ones."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sagg_common.diagnostics import goal_problem, report_problem, sample_problem
from sagg_common.msg_codecs import decode_report, decode_sample
from sagg_common.params import ConfigError
from sagg_common.report_kinds import KIND_NAMES
from sagg_goal_generator.core import GoalGenerator

from .bag_reader import bag_messages
from .recorder import BagWriter


def foreign_messages(paths: list[Path]) -> set[tuple[str, int]]:
    """(topic, timestamp) of the messages ``sagg run``'s recorder attributed to another publisher
    than their topic's expected node (``BagWriter.FOREIGN_FILE`` in each bag directory, if any)."""
    out: set[tuple[str, int]] = set()
    for p in paths:
        f = Path(p) / BagWriter.FOREIGN_FILE
        if f.is_file():
            try:
                doc = json.loads(f.read_text())
                out |= {(str(m[0]), int(m[1])) for m in doc["messages"]}
            except (ValueError, KeyError, TypeError, IndexError) as exc:
                raise ConfigError(f"bag: '{f}' is not a list of foreign messages ({exc})") from exc
    return out


class Recorded:
    """What relearn reads from the bags: samples (stored into ``learner`` in index order), reports by
    seq, goals by seq and /sagg/regions snapshots by the reports folded in (the last one of each
    count). Every recorded message is checked as the nodes check it (docs/safety.md): a bad one is
    dropped and counted (``dropped``), never stored, and never takes the index / seq of a real one;
    one republished after a resume is counted in ``dup``."""

    TOPICS = {"/sagg/sample", "/sagg/competence", "/sagg/goal", "/sagg/regions"}

    def __init__(self, learner, gen: GoalGenerator, full: dict[str, dict], spec):
        self.learner, self.gen = learner, gen
        self.mem = learner.memory
        self.reports: dict[int, object] = {}
        self.goals: dict[int, tuple] = {}
        self.snapshots: dict[int, bytes] = {}
        self.dup = {"samples": 0, "reports": 0, "goals": 0}
        self.dropped: dict[str, int] = {}
        self.ahead: set[int] = set()  # indices of well-formed samples received before the one expected
        self.j_lo, self.j_hi = full["sagg_learner"]["joint_limits.lower"], full["sagg_learner"]["joint_limits.upper"]
        self.j_tol = full["sagg_learner"].get("plausibility.joint_tolerance", 0.1)
        if len(self.j_lo) != self.mem.alpha.shape[1]:  # (a params file without the arm's joints: the arm's limits)
            self.j_lo, self.j_hi = spec.limits()
        self.window = full["sagg_goal_generator"].get("report_window", 10000)

    def drop(self, kind: str) -> None:
        self.dropped[kind] = self.dropped.get(kind, 0) + 1

    def read(self, paths: list[Path]) -> None:
        """Every message of the four topics, in bag order; one the recorder attributed to another
        publisher than its topic's expected node, or one that does not decode, is dropped."""
        take = {"/sagg/sample": self.sample, "/sagg/competence": self.report, "/sagg/goal": self.goal,
                "/sagg/regions": self.regions}
        foreign = foreign_messages(paths)
        for topic, _, ts, raw in bag_messages(paths, set(self.TOPICS)):
            if (topic, ts) in foreign:  # the recorder attributed it to another publisher than the expected one
                self.drop(f"{topic.rsplit('/', 1)[-1]} from another publisher")
                continue
            try:
                take[topic](raw)
            except ConfigError:
                raise
            except Exception:  # noqa: BLE001 - an undecodable message is dropped, never a crash
                self.drop(f"{topic.rsplit('/', 1)[-1]} undecodable")

    def sample(self, raw) -> None:
        sample = decode_sample(raw)
        idx, a, da, dy = sample.index, sample.alpha, sample.delta_alpha, sample.delta_y
        n, dim = len(self.mem), self.gen.dim
        if idx < n:
            self.dup["samples"] += 1
            return
        if sample_problem(idx, n, a, da, dy, self.j_lo, self.j_hi, dim, self.j_tol):
            if idx > n and not sample_problem(idx, idx, a, da, dy, self.j_lo, self.j_hi, dim, self.j_tol):
                self.ahead.add(int(idx))
            self.drop("sample")
            return
        self.learner.store(a, da, dy)

    def report(self, raw) -> None:
        r = decode_report(raw)
        target = r.target if len(r.target) else r.reached
        if not 0 < r.seq <= len(self.reports) + self.window or report_problem(
                r.kind, target, r.competence, self.gen.dim, KIND_NAMES):
            self.drop("report")
            return
        if r.seq in self.reports:
            self.dup["reports"] += 1
        self.reports.setdefault(int(r.seq), r)

    def goal(self, raw) -> None:
        # lazy (heavy): ROS
        from rclpy.serialization import deserialize_message
        from sagg_msgs.msg import Goal
        g = deserialize_message(bytes(raw), Goal)
        if (goal_problem(g.position, self.gen.lower, self.gen.upper)[1]
                or not 0 < int(g.seq) <= len(self.goals) + self.window):
            self.drop("goal")
            return
        key = (int(g.mode), int(g.after_report), np.asarray(g.position, float).tobytes())
        if int(g.seq) in self.goals:
            self.dup["goals"] += 1
            if self.goals[int(g.seq)] != key:
                raise ConfigError(f"bag: goal {g.seq} recorded twice with different values")
        self.goals.setdefault(int(g.seq), key)

    def regions(self, raw) -> None:
        # lazy (heavy): ROS
        from rclpy.serialization import deserialize_message
        from sagg_msgs.msg import RegionTree
        self.snapshots[int(deserialize_message(bytes(raw), RegionTree).reports)] = bytes(raw)

    def check_complete(self) -> None:
        """ConfigError when samples or reports are missing: a later sample recorded after a hole
        (samples lost, not forged), or a gap in the reports' seq."""
        if len(self.mem) + 1 in self.ahead:  # the recording goes on after a hole
            raise ConfigError(f"bag: /sagg/sample index {len(self.mem)} is not recorded but later samples are "
                              f"({len(self.ahead)} of them, from {min(self.ahead)}): samples are missing")
        seqs = sorted(self.reports)
        if seqs != list(range(1, len(seqs) + 1)):
            missing = sorted(set(range(1, (seqs[-1] if seqs else 0) + 1)) - set(seqs))
            raise ConfigError(f"bag: /sagg/competence is missing report(s) {missing[:10]}")


@dataclass
class Refed:
    """What feeding the recorded reports to a fresh generator found: the recorded goals it chose
    otherwise (``mismatches``, by seq), each report's micro-action count, the report counts whose
    recorded /sagg/regions snapshot was compared (``checked``) and those that differed."""

    mismatches: list[int] = field(default_factory=list)
    report_ma: dict[int, int] = field(default_factory=dict)
    checked: list[int] = field(default_factory=list)
    differ: list[int] = field(default_factory=list)

    def regions_match(self, snapshots: dict[int, bytes]) -> bool:
        """Every recorded snapshot equals the relearned tree after the same number of reports."""
        return bool(self.checked) and not self.differ and (max(snapshots) in self.checked)


def refeed(gen: GoalGenerator, rec: Recorded) -> Refed:
    """The generator fed as the node feeds it: reports in seq order, each goal chosen once the
    reports it follows are in; every chosen goal compared with the recorded one, the tree with each
    recorded snapshot."""
    by_after = {}
    for seq, (mode, after, pos) in sorted(rec.goals.items()):
        by_after.setdefault(after, []).append((seq, mode, pos))
    fed = Refed()

    def check_snapshot() -> None:
        if gen.reports in rec.snapshots:
            fed.checked.append(gen.reports)
            if not same_tree(gen, rec.snapshots[gen.reports]):
                fed.differ.append(gen.reports)

    def choose_due() -> None:
        for seq, mode, pos in by_after.pop(gen.reports, []):
            chosen = gen.next_goal()
            if (chosen.seq, chosen.mode, chosen.position.tobytes()) != (seq, mode, pos):
                fed.mismatches.append(seq)

    check_snapshot()
    for seq in sorted(rec.reports):
        choose_due()
        r = rec.reports[seq]
        fed.report_ma[seq] = int(r.micro_actions)
        gen.report(r.kind, r.target if len(r.target) else r.reached, r.competence)
        check_snapshot()
    choose_due()
    if by_after:
        fed.mismatches.extend(s for v in by_after.values() for s, _, _ in v)
    return fed


def same_tree(gen: GoalGenerator, raw: bytes) -> bool:
    """Whether a recorded /sagg/regions message equals the generator's leaves, bit for bit."""
    # lazy (heavy): ROS
    from rclpy.serialization import deserialize_message
    from sagg_msgs.msg import RegionTree
    rec = deserialize_message(raw, RegionTree)
    leaves = gen.tree.leaves()
    return len(rec.regions) == len(leaves) and all(
        int(r.id) == g.id and np.asarray(r.lower).tobytes() == g.lower.tobytes()
        and np.asarray(r.upper).tobytes() == g.upper.tobytes() and int(r.count) == g.count
        and np.float64(r.interest).tobytes() == np.float64(g.interest).tobytes()
        for r, g in zip(rec.regions, leaves))
