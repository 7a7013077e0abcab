"""Whether a competence report can come from the learner this generator serves (ROS-free).

The publishers of ``/sagg/competence`` are told apart by their sequence numbers
(:mod:`sagg_common.sources`), which cannot tell a *silent* learner from a publisher that replays
another run (``ros2 bag play`` of an old bag while the learner holds): the replay's chain is then
the only live one, and once its report numbers pass the learner's they would be taken. What tells
them apart is the *content*, checked against what this generator itself knows:

- :func:`goal_mismatch`: a report names its goal (``goal_seq``), and every goal was chosen here
  after report ``after_report``. The learner's reports about goal ``g`` are sent after it asked
  for ``g`` and before it asks for ``g + 1``, so their numbers lie in
  ``(goals[g].after_report, goals[g+1].after_report]``; the report of the attempt itself
  (``KIND_GOAL``) aims at exactly the goal's position; and a goal not chosen here cannot be named
  while this generator holds the learner's goals. It may not hold them: a generator started
  without the run's checkpoint knows none (then a report is held until the learner's own request
  says it sent that many reports), and a resumed one chooses its journaled goals again as their
  reports come in (held until then).
- :class:`ProcessedDigests`: a report numbered like one already processed (a duplicate: the
  learner's history re-sent after a restart) must have the same content; another content is
  another run's report.

Either finding marks the report's source as foreign for as long as it publishes. What is left:
a replay that starts beyond the reports processed, whose reached points (not goals) happen to
name the goal in progress here, is not told apart (docs/notes/hostile-input.md).
"""
from __future__ import annotations

import numpy as np

from sagg_common.report_kinds import KIND_GOAL

UNKNOWN = None  # goal_mismatch: the goal was not chosen yet (cannot be checked now)


def goal_mismatch(goals, seq: int, goal_seq: int, kind: int, target, start,
                  complete: bool = True) -> str | None:
    """Why report ``seq`` about goal ``goal_seq`` cannot be the learner's ('' if it can;
    :data:`UNKNOWN` if it cannot be told now). ``goals``: the generator's goal records in order
    (``goals[k].seq == k + 1``); ``complete``: they are all the goals the learner was given (false
    while a resumed generator has journaled goals to choose again); goal 0 is "no goal"
    (exploration, actuator strategies): nothing to check. The goal's own report aims at the goal
    up to rounding: the learner computes its last subgoal as ``start + 1·(goal − start)`` (a few
    ulps of the larger of the coordinates: 1e-9 of it is far above rounding and far below any two
    goals' distance)."""
    if goal_seq == 0:
        return ""
    if goal_seq > len(goals):
        if not complete or not goals:
            return UNKNOWN
        return f"it names goal {goal_seq}, but {len(goals)} goals were chosen"
    rec = goals[goal_seq - 1]
    if rec.seq != goal_seq:
        return ""  # (goal records not numbered from 1: nothing to check against)
    if seq <= rec.after_report:
        return (f"it names goal {goal_seq}, chosen after report {rec.after_report}: its reports are "
                f"numbered from {rec.after_report + 1}")
    if goal_seq < len(goals) and seq > goals[goal_seq].after_report:
        return (f"it names goal {goal_seq}, but goal {goal_seq + 1} was asked for after report "
                f"{goals[goal_seq].after_report}: goal {goal_seq}'s reports end there")
    if kind != KIND_GOAL:
        return ""
    target = np.asarray(target, dtype=float)
    scale = 1.0 + max(np.abs(target).max(initial=0.0), np.abs(rec.position).max(initial=0.0),
                      np.abs(np.asarray(start, dtype=float)).max(initial=0.0))
    if target.shape != rec.position.shape or np.abs(target - rec.position).max(initial=0.0) > 1e-9 * scale:
        return f"its target {np.round(target, 6).tolist()} is not goal {goal_seq}'s position"
    return ""


class ProcessedDigests:
    """The content of the last ``size`` reports processed, by number, to compare duplicates with."""

    __slots__ = ("size", "keys")

    def __init__(self, size: int):
        self.size = int(size)
        self.keys: dict[int, tuple] = {}

    @staticmethod
    def key(goal_seq: int, kind: int, target, competence: float) -> tuple:
        """What a report says that the generator uses (the point, the competence) and whose it is."""
        return (int(goal_seq), int(kind), float(competence), np.asarray(target, dtype=float).tobytes())

    def add(self, seq: int, key: tuple) -> None:
        keys = self.keys
        keys[seq] = key
        if len(keys) > self.size:
            del keys[next(iter(keys))]  # (insertion order = report order: the oldest)

    def differs(self, seq: int, key: tuple) -> bool:
        """Whether report ``seq`` was processed with another content (unknown numbers: False)."""
        old = self.keys.get(seq)
        return old is not None and old != key
