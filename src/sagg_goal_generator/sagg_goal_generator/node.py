"""The goal-generator node (``goal_generator``): the SAGG-RIAC high level on ROS 2.

Wraps :class:`~sagg_goal_generator.core.GoalGenerator`:

- subscribes ``/sagg/competence`` (every report of the learner, in order) and feeds each to the core,
  from one source (``sagg_common.sources``) and only if its content can be the learner's
  (``report_origin``: its goal, its number, and what an earlier report with its number said);
- serves ``/sagg/next_goal``: a request ``after_report = N`` is answered only once reports 1..N
  have been processed, so the goal is the same function of the report sequence as in-process
  (deterministic lockstep). A request that arrives early waits in the :class:`GoalServer`'s
  thread until report N has been processed;
- publishes every goal on ``/sagg/goal`` and the region tree on ``/sagg/regions`` (transient_local,
  depth 1) on every split and at most every 0.5 s otherwise.

For the actuator strategies it chooses no goals but stays alive (and still takes the reports, as
the in-process driver does, so the region tree can be visualised).
"""
from __future__ import annotations

import array
import math
import struct
import sys
import threading
import time
from typing import NamedTuple

import numpy as np

from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticArray

from sagg_common.msg_codecs import decode_report, encode_region_tree
from sagg_common.diagnostics import InputGuard, diagnostic_array, report_problem
from sagg_common.params import GOAL_STRATEGIES, ConfigError
from sagg_common import sources
from sagg_common.publishers import describe
from sagg_common.report_kinds import KIND_NAMES
from sagg_common.ros_params import declare_schema, reliable, run_node, spin
from sagg_msgs.msg import CompetenceReport, Goal, RegionTree
from sagg_msgs.srv import NextGoal

from .checkpoint import GeneratorCheckpointer
from .core import GoalGenerator
from .report_origin import UNKNOWN, ProcessedDigests, goal_mismatch
from .schema import CORE_SCHEMA, SCHEMA

NODE_NAME = "sagg_goal_generator"
FOREIGN = "foreign"  # the tag of a /sagg/competence source found to send another run's reports


class Early(NamedTuple):
    """A report kept until it is next in line (or its goal can be checked)."""
    kind: int
    target: np.ndarray
    competence: float
    received: float  # time.monotonic() when it came
    goal_seq: int
    start: np.ndarray
    key: tuple       # ProcessedDigests.key


class GoalServer:
    """``/sagg/next_goal``, served by a node of its own that a second executor spins in a thread.

    A request ``after_report = N`` must wait until reports 1..N are processed, and the reports keep
    arriving on the generator node's executor meanwhile: the service callback therefore blocks, in
    this thread, on the generator node's condition variable (which every processed report
    notifies). This is how public rclpy answers a request late: it has no deferred response, and
    the EventsExecutor does not run coroutine callbacks. The generator node's hot path (one report
    per micro-action) stays on its own executor. The server node ignores the command line's
    arguments (parameter files, remappings): it has neither parameters nor relative names."""

    def __init__(self, owner: "GoalGeneratorNode"):
        self.node = Node(NODE_NAME + "_goals", context=owner.context, use_global_arguments=False,
                         start_parameter_services=False)
        self.node.create_service(NextGoal, "/sagg/next_goal", owner.on_next_goal)
        self.stopping = threading.Event()
        self.thread = threading.Thread(target=self._spin, args=(SingleThreadedExecutor(context=owner.context),),
                                       name="goal_server", daemon=True)
        self.thread.start()

    def _spin(self, executor) -> None:
        try:
            spin(self.node, executor, should_stop=self.stopping.is_set)
        except Exception:  # noqa: BLE001 - the context was shut down under the thread: nothing to serve
            if self.node.context.ok():
                raise

    def close(self) -> None:
        """Stop the thread (a request still waiting gets an empty response, which the learner
        rejects as it would any goal outside Y), destroy the server node."""
        self.stopping.set()
        self.thread.join(timeout=5.0)
        self.node.destroy_node()


def _locked(cond: threading.Condition, callback):
    """``callback`` run holding ``cond``, then waking the requests waiting on it."""
    def run(*args):
        with cond:
            callback(*args)
            cond.notify_all()
    return run


class GoalGeneratorNode(Node):
    def __init__(self):
        super().__init__(NODE_NAME)
        self.params = declare_schema(self, SCHEMA)
        core = {p.name: self.params[p.name] for p in CORE_SCHEMA}
        try:
            self.gen = GoalGenerator(core)
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
        self.active = core["strategy"] in GOAL_STRATEGIES
        self.exit_code = 0
        # the generator's state is shared with the goal server's thread: every callback holds this
        self.cond = threading.Condition()
        self.guard = InputGuard(self.get_logger().error)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable(10))
        self.create_timer(1.0, _locked(self.cond, self.publish_diagnostics))
        self.goal_pub = self.create_publisher(Goal, "/sagg/goal", reliable(100))
        self.published = {"/sagg/goal": 0}  # (logged at shutdown: what a bag must hold)
        self.region_pub = self.create_publisher(RegionTree, "/sagg/regions", reliable(1, transient_local=True))
        # hot path: raw CDR decoded with sagg_common.cdr (no message objects)
        # transient_local: after a restart, the reports missed come again from the learner's history
        # reports from one source (docs/safety.md; sagg_common.sources, told apart by the publishers'
        # sequence numbers): while a second source sends well-formed reports, every report is
        # dropped (which is real cannot be told) and named; once one source has been quiet for
        # source_grace the subscription is made again, and the learner's transient_local history
        # (10000 reports, the report_window) delivers the real reports dropped meanwhile (duplicates
        # are dropped by seq). A publisher that sends nothing changes nothing.
        self.report_sources: sources.SourceChains | None = None
        self.source_hold = ""  # the current second source, in words ('' = none)
        self.report_sub = None
        self.resubscribe_due = False  # reports were dropped for a foreign publisher
        self.resubscriptions = 0
        self.duplicate_reports = 0  # reports already processed, received again (dropped)
        # reports ahead of the next one, or about a goal not chosen yet (held until the learner's
        # request covers them), by seq
        self.early: dict[int, Early] = {}
        # what tells a silent learner from a replay of another run: the reports' content against
        # this generator's goals and the reports it processed (report_origin)
        self.processed = ProcessedDigests(self.params["report_window"])
        self.announced = 0  # the learner said (in a goal request) it sent reports 1..announced
        self.foreign_reports = 0
        self._subscribe_reports()
        self.checkpointer = None
        self.replay_goals: list = []  # journaled goals to choose again after a resume
        self.goals_to_publish: list = []  # journaled goals to publish again after a resume
        self._setup_checkpoint()
        self.splits_published = -1
        self.regions_dirty = True
        self.create_timer(self.params["regions_period"], _locked(self.cond, self.on_regions_timer))
        self.publish_regions()
        self.server = GoalServer(self)  # last: requests are served once the node is complete
        self.get_logger().info(
            f"strategy {core['strategy']}: "
            + ("serving /sagg/next_goal" if self.active else "idle (actuator strategy: no goals)"))

    # ------------------------------------------------------------ reports
    def _subscribe_reports(self) -> None:
        if self.report_sub is not None:
            self.destroy_subscription(self.report_sub)
        self.report_sub = self.create_subscription(CompetenceReport, "/sagg/competence",
                                                   sources.with_message_info(_locked(self.cond, self.on_report)),
                                                   reliable(10000, transient_local=True), raw=True)
        # a new subscription's messages are new chains: the learner's history first
        self.report_sources = sources.SourceChains(self.params["plausibility.source_grace"])

    def _check_report_sources(self) -> None:
        """After reports were dropped for a second source: once one source has been quiet for
        ``source_grace``, subscribe again (the learner's history brings the dropped reports back)."""
        if self.resubscribe_due and not self.report_sources.ambiguous(time.monotonic()):
            self.resubscribe_due = False
            self.resubscriptions += 1
            self.source_hold = ""
            self.get_logger().info("/sagg/competence has one source again: subscribing again for the "
                                   "reports dropped meanwhile")
            self._subscribe_reports()

    def _second_source(self, seq: int, verdict: int) -> None:
        """A well-formed report while /sagg/competence has two sources (or after skipped publisher
        numbers): dropped, named, and taken again from the learner's history later."""
        if not self.source_hold:
            pubs = "; ".join(describe(i) for i in self.get_publishers_info_by_topic("/sagg/competence")) or "none"
            self.source_hold = (f"/sagg/competence: reports from two sources (the topic's publishers: {pubs}); "
                                "reports are dropped until one has been quiet for "
                                f"{self.params['plausibility.source_grace']:g} s "
                                "(plausibility.source_grace), then taken again from the learner's history")
        kind = "report.second_source" if verdict == sources.AMBIGUOUS else "report.sequence_gap"
        self.guard.reject(kind, f"report {seq} dropped: " + (self.source_hold if verdict == sources.AMBIGUOUS else
                                                             "publisher numbers skipped (messages missed or another "
                                                             "publisher); taken again from the learner's history"))
        self.resubscribe_due = True

    def on_report(self, raw: bytes, info: dict = sources.NO_INFO) -> None:
        gen = self.gen
        try:
            msg = decode_report(raw)
        except (ValueError, IndexError, struct.error, UnicodeDecodeError) as exc:
            self.guard.reject("report.undecodable", f"/sagg/competence: undecodable message ({exc})")
            return
        window = self.params["report_window"]
        if msg.seq > gen.reports + window:
            # (checked before anything else: a forged seq of 10^12 must cost nothing)
            self.guard.reject("report.out_of_window",
                              f"competence report seq {msg.seq}: allowed: {gen.reports + 1}..{gen.reports + window} "
                              "(report_window beyond the last report processed); dropped")
            return
        # Reached points / exploration samples carry the reached point (target may be empty).
        target = np.asarray(msg.target if len(msg.target) else msg.reached, dtype=float)
        problem = self._report_problem(msg, target)
        if problem:
            # rejected before its seq is consumed: the real report with this number is still taken
            self.guard.reject("report.invalid", f"competence report {msg.seq}: {problem}; dropped")
            return
        # a well-formed report: from one source only (duplicates too: they are part of the chain)
        verdict = self.report_sources.classify(info["publication_sequence_number"], time.monotonic())
        if verdict != sources.ACCEPT:
            self._second_source(msg.seq, verdict)
            return
        if self.report_sources.tagged() is FOREIGN:
            self.foreign_reports += 1  # (named once, when its source was found out)
            return
        key = ProcessedDigests.key(msg.goal_seq, msg.kind, target, msg.competence)
        if msg.seq <= gen.reports and self.processed.differs(msg.seq, key):
            self._foreign(msg.seq, f"report {msg.seq} was processed with another content")
            return
        if msg.seq <= gen.reports:
            # already processed: re-sent from the learner's history after a restart or a resume (the
            # normal case there, not a bad input: it changes nothing); counted, logged once
            self.duplicate_reports += 1
            if self.duplicate_reports == 1:
                self.get_logger().info(f"competence report {msg.seq}: already have reports 1..{gen.reports} "
                                       "(re-sent after a restart or resume): dropped; such reports are counted "
                                       "on /diagnostics (duplicate_reports), not logged again")
            return
        why = goal_mismatch(gen.goals, msg.seq, msg.goal_seq, msg.kind, target, msg.start, not self.replay_goals)
        if why:
            self._foreign(msg.seq, why)
            return
        if msg.seq != gen.reports + 1 or (why is UNKNOWN and msg.seq > self.announced):
            # early: kept until the reports before it come (reordered, or re-delivered from the
            # learner's history after a re-subscription; skipped only after report_reorder_wait),
            # or until its goal is chosen here or the learner's request says it sent it (a
            # restarted generator; report_origin). The latest with a number is kept.
            self.early[msg.seq] = Early(msg.kind, target, msg.competence, time.monotonic(), msg.goal_seq,
                                        msg.start, key)
            return
        self._take(msg.seq, msg.kind, target, msg.competence, key)
        if self.early:
            self._drain_early()

    def _take(self, seq: int, kind: int, target, competence: float, key: tuple) -> None:
        self.gen.report(kind, target, competence)
        self.processed.add(seq, key)
        self._after_report()

    def _foreign(self, seq: int, why: str, source: bool = True) -> None:
        """A report that cannot be the learner's: dropped, named, and (``source``: it has just
        arrived) its source ignored while it lives."""
        self.foreign_reports += 1
        if source:
            self.report_sources.tag(FOREIGN)
        self.guard.reject("report.foreign", f"competence report {seq} dropped: {why}; not from the learner "
                                            "this generator serves (another run's reports: a replayed bag?). Its "
                                            "publisher's reports are dropped while it publishes")

    def _vouched(self) -> list[int]:
        """The kept early reports that the learner's request covers or whose goal was chosen here
        (the reports missing before them were really sent)."""
        goals = self.gen.goals
        return [q for q, e in self.early.items()
                if q <= self.announced
                or goal_mismatch(goals, q, e.goal_seq, e.kind, e.target, e.start,
                                 not self.replay_goals) is not UNKNOWN]

    def _check_early(self, now: float | None = None) -> None:
        """Skip the reports missing before the kept early ones after report_reorder_wait."""
        now = time.monotonic() if now is None else now
        if self.early and min(e.received for e in self.early.values()) <= now - self.params["report_reorder_wait"]:
            self._drain_early(skip=True)

    def _drain_early(self, skip: bool = False) -> None:
        """Process the kept early reports that are now next in line; ``skip``: first count the
        missing ones before the earliest vouched one as lost (they did not come within
        report_reorder_wait). A kept report about a goal still unknown waits for the learner's
        request; one whose goal turned out to be another is dropped (report_origin)."""
        gen = self.gen
        vouched = self._vouched() if skip and gen.reports + 1 not in self.early else None
        if vouched:
            first = min(vouched)
            lost = first - gen.reports - 1
            self.guard.reject("report.lost", f"competence report {first} follows report {gen.reports}: {lost} "
                                             "report(s) lost, counted as skipped (goals no longer match an "
                                             "in-process run)")
            for _ in range(lost):
                gen.skip_report()
        while gen.reports + 1 in self.early:
            seq = gen.reports + 1
            e = self.early[seq]
            why = goal_mismatch(gen.goals, seq, e.goal_seq, e.kind, e.target, e.start, not self.replay_goals)
            if why is UNKNOWN and seq > self.announced:
                break
            del self.early[seq]
            if why:
                self._foreign(seq, why, source=False)
                continue
            self._take(seq, e.kind, e.target, e.competence, e.key)
        for seq in [q for q in self.early if q <= gen.reports]:
            del self.early[seq]

    def _after_report(self) -> None:
        gen = self.gen
        if self.checkpointer is not None:
            self._after_report_checkpoint()
        self.regions_dirty = True
        if len(gen.tree.splits) != self.splits_published:
            self.publish_regions()

    def _report_problem(self, msg, target: np.ndarray) -> str:
        """What is wrong with a report's content ('' if nothing)."""
        return report_problem(msg.kind, target, msg.competence, self.gen.dim, KIND_NAMES)

    def publish_diagnostics(self) -> None:
        gen = self.gen
        state = {"reports": str(gen.reports), "skipped_reports": str(gen.skipped_reports),
                 "goals": str(len(gen.goals)), "regions": str(len(gen.tree.leaves()))}
        state["publishers /sagg/competence"] = "; ".join(
            describe(i) for i in self.get_publishers_info_by_topic("/sagg/competence")) or "none"
        if self.source_hold:
            state["second source"] = self.source_hold
        state["report_resubscriptions"] = str(self.resubscriptions)
        state["duplicate_reports"] = str(self.duplicate_reports)
        state["foreign_reports"] = str(self.foreign_reports)
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().to_msg(), NODE_NAME, self.guard, state))

    def _goal_subscribers_ok(self) -> bool:
        need = self.params["min_goal_subscribers"]
        ok = need == 0 or self.goal_pub.get_subscription_count() >= need
        if not ok:
            self.get_logger().info(f"goal requests wait for {need} subscriber(s) on /sagg/goal "
                                   "(min_goal_subscribers; set 0 when nothing records)", throttle_duration_sec=5.0)
        return ok

    # ------------------------------------------------------------ goals
    def on_next_goal(self, request: NextGoal.Request, response: NextGoal.Response):
        """Runs in the :class:`GoalServer`'s thread, holding the generator's condition variable
        except while it waits for the reports 1..after_report (or for /sagg/goal's subscribers)."""
        with self.cond:
            return self._answer(request, response)

    def _answer(self, request: NextGoal.Request, response: NextGoal.Response):
        if not self.active:
            self.get_logger().error(
                f"goal requested but strategy is {self.gen.strategy}: no goals for actuator strategies",
                throttle_duration_sec=5.0)
            response.goal.after_report = request.after_report
            return response
        after = request.after_report
        if after > self.announced:
            self.announced = after
            if self.early:
                self._drain_early()
        rec = self._goal_for(after)
        if rec is not None:  # a repeated request (learner's goal_retry): the same goal
            return self._fill(response, rec)
        if after < self.gen.reports:
            self.get_logger().error(
                f"goal requested after report {after} but {self.gen.reports} reports were already "
                "processed: the learner and the generator disagree")
        if after > self.gen.reports or not self._goal_subscribers_ok():
            # woken by every report and regions tick (the subscriber count has no event of its own)
            while after > self.gen.reports or not self._goal_subscribers_ok():
                if self.server.stopping.is_set():
                    return response  # shutting down: an empty response, no goal chosen
                self.cond.wait(timeout=0.1)
            # a request whose goal was already chosen (answered meanwhile through a repeated
            # request, goal_retry) gets that goal, not a new one
            return self._fill(response, self._goal_for(after))
        return self._fill(response)

    def _fill(self, response: NextGoal.Response, rec=None) -> NextGoal.Response:
        if rec is None:
            rec = self._goal_for(self.gen.reports)
        if rec is None:  # (else: a repeated request, answered with the same goal)
            rec = self.gen.next_goal()
            if self.checkpointer is not None:
                self.checkpointer.on_goal(rec)  # journaled before it is answered or published
        self._publish_goal(rec, response.goal)
        return response

    def _goal_for(self, after_report: int):
        """The goal already chosen after report ``after_report`` (a repeated or late request gets it
        again), or None. Goals are in increasing after_report order; a repeated request is never
        far behind, so only the last 16 are searched."""
        for rec in reversed(self.gen.goals[-16:]):
            if rec.after_report == after_report:
                return rec
            if rec.after_report < after_report:
                break
        return None

    def _publish_goal(self, rec, g=None) -> None:
        """Fill ``g`` (a Goal, new if None) from ``rec`` and publish it on /sagg/goal."""
        g = Goal() if g is None else g
        g.header.stamp = self.get_clock().now().to_msg()
        g.header.frame_id = "task_space"
        g.seq = rec.seq
        g.after_report = rec.after_report
        g.mode = rec.mode
        g.position = array.array("d", rec.position.tobytes())
        self.goal_pub.publish(g)
        self.published["/sagg/goal"] += 1

    # ------------------------------------------------------------ checkpoint / resume
    def _setup_checkpoint(self) -> None:
        p = self.params
        if not p["checkpoint_dir"]:
            return
        try:
            ck = GeneratorCheckpointer(p["checkpoint_dir"], self.gen, p["checkpoint_every"], p["journal_fsync"])
            ck.check_resume(p["resume"])  # another run's checkpoint: refused unless asked to continue it
            self.replay_goals = ck.resume()
        except (ValueError, OSError) as exc:
            raise ConfigError(f"parameter 'checkpoint_dir': {exc}") from exc
        self.checkpointer = ck
        # goals of the last journals: published again (a kill may have cut their publication short;
        # receivers key goals by seq), once /sagg/goal has its subscribers (on_regions_timer)
        self.goals_to_publish = list(ck.republish)
        if ck.resumed_from is not None:
            info = ck.resumed_from
            self.get_logger().info(
                f"resumed from {p['checkpoint_dir']} (generation {info['generation']}): {info['reports']} "
                f"reports, {info['goals']} goals, {info['pending_goals']} journaled goals to choose again, "
                f"{info['torn_bytes']} torn bytes dropped")
        self._replay_due_goals()

    def _replay_due_goals(self) -> None:
        """Choose again the journaled goals whose reports are all in (same draws as before the
        crash); each must equal its journal record."""
        gen = self.gen
        while self.replay_goals and self.replay_goals[0].after_report == gen.reports:
            want = self.replay_goals.pop(0)
            rec = gen.next_goal()
            if rec.seq != want.seq or rec.position.tobytes() != want.position.tobytes():
                self.get_logger().error(
                    f"resumed goal {rec.seq} differs from the journaled goal {want.seq}: using the journaled one")
                gen.goals[-1] = rec = want
            self.goals_to_publish.append(rec)
        if self.replay_goals and self.replay_goals[0].after_report < gen.reports:
            self.get_logger().error(f"journaled goal {self.replay_goals[0].seq} followed report "
                                    f"{self.replay_goals[0].after_report}, already passed: dropping the replay")
            self.replay_goals = []

    def _after_report_checkpoint(self) -> None:
        if self.replay_goals:
            self._replay_due_goals()
        else:
            self.checkpointer.maybe_save()

    def close(self) -> None:
        """At shutdown: the final checkpoint (unless journaled goals still wait for their reports:
        the journal then keeps them for the next resume)."""
        self.server.close()
        if self.checkpointer is not None:
            if self.replay_goals:
                self.checkpointer.journal.close()
            else:
                self.checkpointer.close()
            self.checkpointer = None

    # ------------------------------------------------------------ regions
    def on_regions_timer(self) -> None:
        if self.resubscribe_due:
            self._check_report_sources()
        if self.early:
            self._check_early()
        if self.goals_to_publish and self._goal_subscribers_ok():
            for rec in self.goals_to_publish:
                self._publish_goal(rec)
            self.goals_to_publish = []
        if self.regions_dirty:
            self.publish_regions()

    def publish_regions(self) -> None:
        """The leaves as a RegionTree, encoded straight from the tree (sagg_common.cdr: cheaper than
        building one Region message object per leaf, on every split)."""
        gen = self.gen
        leaves = gen.tree.leaves()
        counts = [r.count for r in leaves]
        raw = encode_region_tree(
            self.get_clock().now().nanoseconds, len(gen.goals), gen.reports, len(gen.tree.splits),
            ([r.id for r in leaves], np.array([r.lower for r in leaves]), np.array([r.upper for r in leaves]),
             [r.interest for r in leaves], counts,
             [r.mean_value() if c else math.nan for r, c in zip(leaves, counts)]), frame_id="task_space")
        self.region_pub.publish(raw)
        self.splits_published = len(gen.tree.splits)
        self.regions_dirty = False


def main(args: list[str] | None = None) -> int:
    code = run_node(NODE_NAME, GoalGeneratorNode, args, executor="events")
    sys.exit(code)


if __name__ == "__main__":
    main()
