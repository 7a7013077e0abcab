"""A replay of another run's reports never reaches the goal generator, even while the learner is
silent: what tells them apart is their content against the generator's own
goals and reports (sagg_goal_generator.report_origin), not their publisher."""
from __future__ import annotations

import time

import numpy as np
import pytest
import rclpy
import yaml
from rclpy.serialization import serialize_message

from sagg_bringup.graph.processes import pick_domain_id
from sagg_common.report_kinds import KIND_GOAL, KIND_REACHED, KIND_SUBGOAL
from sagg_common.sources import SourceChains
from sagg_goal_generator.core import GoalRecord
from sagg_goal_generator.node import GoalGeneratorNode
from sagg_goal_generator.report_origin import UNKNOWN, ProcessedDigests, goal_mismatch
from sagg_msgs.msg import CompetenceReport
from sagg_msgs.srv import NextGoal

GRACE = 0.2  # plausibility.source_grace of the generators built here (s)


def records(*after_reports, dim=2):
    return [GoalRecord(k + 1, np.full(dim, float(k + 1)), 1, a) for k, a in enumerate(after_reports)]


def test_goal_mismatch_follows_the_goal_intervals():
    goals = records(0, 5, 9)  # goal 1 after report 0, goal 2 after 5, goal 3 after 9
    assert goal_mismatch(goals, 3, 0, KIND_REACHED, [7.0, 7.0], [0, 0]) == ""  # no goal: nothing to check
    assert goal_mismatch(goals, 3, 1, KIND_REACHED, [7.0, 7.0], [0, 0]) == ""
    assert goal_mismatch(goals, 5, 1, KIND_REACHED, [7.0, 7.0], [0, 0]) == ""  # the last of goal 1's
    assert "goal 2 was asked for after report 5" in goal_mismatch(goals, 6, 1, KIND_REACHED, [7.0, 7.0], [0, 0])
    assert "numbered from 6" in goal_mismatch(goals, 5, 2, KIND_REACHED, [7.0, 7.0], [0, 0])
    assert goal_mismatch(goals, 10_000, 3, KIND_REACHED, [7.0, 7.0], [0, 0]) == ""  # the goal in progress
    assert "3 goals were chosen" in goal_mismatch(goals, 12, 4, KIND_REACHED, [7.0, 7.0], [0, 0])
    # goals this generator may not hold: a resumed one with journaled goals to choose again, a new one
    assert goal_mismatch(goals, 12, 4, KIND_REACHED, [7.0, 7.0], [0, 0], complete=False) is UNKNOWN
    assert goal_mismatch([], 12, 4, KIND_REACHED, [7.0, 7.0], [0, 0]) is UNKNOWN
    # the goal's own report aims at the goal's position, up to the learner's rounding
    start = np.array([123.456, -0.1])
    rounded = start + 1.0 * (goals[2].position - start)
    assert goal_mismatch(goals, 12, 3, KIND_GOAL, rounded, start) == ""
    assert goal_mismatch(goals, 12, 3, KIND_SUBGOAL, [0.5, 0.5], start) == ""  # (subgoals: not checked)
    assert "not goal 3's position" in goal_mismatch(goals, 12, 3, KIND_GOAL, [3.0, 3.001], start)
    assert "not goal 3's position" in goal_mismatch(goals, 12, 3, KIND_GOAL, [3.0], start)


def test_processed_digests_tell_another_content_and_forget_the_oldest():
    d = ProcessedDigests(3)
    for seq in range(1, 5):
        d.add(seq, ProcessedDigests.key(1, KIND_REACHED, [float(seq), 0.0], 0.0))
    assert not d.differs(4, ProcessedDigests.key(1, KIND_REACHED, [4.0, 0.0], 0.0))
    assert d.differs(4, ProcessedDigests.key(1, KIND_REACHED, [4.0, 1e-12], 0.0))
    assert d.differs(3, ProcessedDigests.key(2, KIND_REACHED, [3.0, 0.0], 0.0))  # another goal
    assert not d.differs(1, ProcessedDigests.key(9, KIND_REACHED, [0.0, 0.0], -1.0))  # forgotten: unknown


def test_a_tag_stays_with_its_chain():
    c = SourceChains(1.0)
    c.classify(1, 0.0)
    c.tag("foreign")
    assert c.tagged() == "foreign"
    c.classify(2, 0.1)
    assert c.tagged() == "foreign"  # the same publisher's next message
    c.classify(1, 5.0)  # another publisher (numbers from 1 again)
    assert c.tagged() is None
    c.classify(None, 5.1)  # no numbers: nothing to tag
    assert c.tagged() is None


# ------------------------------------------------------------------ the generator node
@pytest.fixture()
def node(tmp_path):
    params = {"/**": {"ros__parameters": {"seed": 3, "strategy": "sagg-riac",
                                          "task_space": {"lower": [-10.0, -10.0], "upper": [10.0, 10.0]}}},
              "sagg_goal_generator": {"ros__parameters": {"plausibility": {"source_grace": GRACE}}}}
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params))
    rclpy.init(args=["--ros-args", "--params-file", str(path)], domain_id=pick_domain_id())
    built = []
    try:
        def make():
            built.append(GoalGeneratorNode())
            return built[-1]
        yield make
    finally:
        for n in built:
            n.close()
            n.destroy_node()
        rclpy.try_shutdown()


class Publisher:
    """One publisher of /sagg/competence: its DDS sequence numbers and its reports' numbers."""

    def __init__(self, g):
        self.g, self.number = g, 0

    def send(self, seq, goal_seq, kind, point, competence=-0.5):
        m = CompetenceReport()
        m.seq, m.goal_seq, m.kind, m.competence = seq, goal_seq, kind, competence
        if kind == KIND_REACHED:
            m.target, m.reached, m.competence = [], [float(v) for v in point], 0.0
        else:
            m.target, m.reached = [float(v) for v in point], [float(v) for v in point]
        m.start = [0.0, 0.0]
        self.number += 1
        self.g.on_report(serialize_message(m), {"publication_sequence_number": self.number,
                                                "source_timestamp": None})


def ask(g, after: int) -> GoalRecord:
    response = g.on_next_goal(NextGoal.Request(after_report=after), NextGoal.Response())
    assert response.goal.seq == len(g.gen.goals)
    return g.gen.goals[-1]


def learn(g, learner: Publisher, goals: int, seq: int = 0) -> int:
    """The learner's protocol: ask for a goal after its last report, two reached points, the goal."""
    for _ in range(goals):
        rec = ask(g, seq)
        for k in range(2):
            seq += 1
            learner.send(seq, rec.seq, KIND_REACHED, rec.position * (k + 1) / 3)
        seq += 1
        learner.send(seq, rec.seq, KIND_GOAL, rec.position)
    return seq


def test_a_replay_from_the_start_of_another_run_is_found_out_by_its_duplicates(node):
    g = node()
    learner = Publisher(g)
    sent = learn(g, learner, 5)
    assert g.gen.reports == sent == 15
    time.sleep(GRACE * 1.5)  # the learner holds: its chain is not live any more
    replay = Publisher(g)  # another run's bag from its start, beyond the learner's reports
    rng = np.random.default_rng(7)
    for seq in range(1, sent + 30):
        replay.send(seq, (seq - 1) // 3 + 1, KIND_REACHED, rng.uniform(-9, 9, 2))
    assert g.gen.reports == sent and not g.early
    # (a new publisher's first message is a gap in the stream: sources.SourceChains)
    assert g.guard.counts["report.sequence_gap"] == 1
    assert g.guard.counts["report.foreign"] == 1 and g.foreign_reports == sent + 28  # named once
    time.sleep(GRACE * 1.5)
    sent = learn(g, learner, 2, sent)  # the learner goes on: every report of it is taken
    assert g.gen.reports == sent == 21 and g.gen.skipped_reports == 0


def test_a_replay_beyond_the_learners_reports_is_dropped_and_the_learner_goes_on(node):
    g = node()
    learner = Publisher(g)
    sent = learn(g, learner, 4)
    rec = ask(g, sent)  # goal 5: the learner sends one reached point, then holds
    sent += 1
    learner.send(sent, rec.seq, KIND_REACHED, [0.25, 0.25])
    reports = g.gen.reports
    time.sleep(GRACE * 1.5)
    replay = Publisher(g)  # another run's reports numbered after ours, about goals not chosen here
    for seq in range(sent + 1, sent + 40):
        replay.send(seq, 7 + (seq - sent) // 3, KIND_REACHED, [5.0, -5.0])
    g._check_early(now=time.monotonic() + 60.0)  # long after report_reorder_wait: nothing skipped
    assert g.gen.reports == reports and g.gen.skipped_reports == 0 and not g.early
    assert g.guard.counts["report.foreign"] == 1 and g.foreign_reports == 38  # (1st: a gap)
    time.sleep(GRACE * 1.5)
    stray = Publisher(g)  # names our goal in progress, aims elsewhere
    stray.send(sent + 1, rec.seq, KIND_GOAL, [5.0, -5.0])
    stray.send(sent + 1, rec.seq, KIND_GOAL, [5.0, -5.0])
    assert g.guard.counts["report.foreign"] == 2 and g.gen.reports == reports
    time.sleep(GRACE * 1.5)
    for k in range(3):  # the learner goes on with goal 5: every report of it is taken
        sent += 1
        learner.send(sent, rec.seq, KIND_REACHED if k < 2 else KIND_GOAL,
                     rec.position if k == 2 else [0.5 + k, 0.5])
    assert g.gen.reports == sent and g.gen.goals[rec.seq - 1].competence == -0.5
    ask(g, sent)
    assert len(g.gen.goals) == 6 and g.gen.skipped_reports == 0


def test_a_report_about_a_finished_goal_after_the_next_was_asked_is_foreign(node):
    g = node()
    learner = Publisher(g)
    sent = learn(g, learner, 3)
    time.sleep(GRACE * 1.5)
    stray = Publisher(g)
    stray.send(sent + 1, 1, KIND_REACHED, [1.0, 1.0])  # (a new publisher's first message: a gap)
    stray.send(sent + 1, 1, KIND_REACHED, [1.0, 1.0])  # goal 1's reports ended at report 3
    assert g.gen.reports == sent and g.guard.counts["report.foreign"] == 1 and not g.early


def test_a_restarted_generator_takes_the_learners_history_once_the_learner_asks(node):
    """Without a checkpoint the generator knows none of the goals the learner's history names:
    those reports wait for the learner's request, which says they were sent; then all are taken."""
    first = node()
    learner = Publisher(first)
    sent = learn(first, learner, 3)
    tree = first.gen.tree.leaves()
    second = node()  # a new generator, no checkpoint
    history = Publisher(second)
    for seq in range(1, sent + 1):
        rec = first.gen.goals[(seq - 1) // 3]
        kind = KIND_GOAL if seq % 3 == 0 else KIND_REACHED
        history.send(seq, rec.seq, kind, rec.position if kind == KIND_GOAL else rec.position * (seq % 3) / 3)
    assert second.gen.reports == 0 and len(second.early) == sent  # (report 1's goal too)
    ask(second, sent)
    assert second.gen.reports == sent and len(second.gen.tree.leaves()) == len(tree)
