"""``sagg replay`` and ``sagg relearn``: using the bags ``sagg run`` records.

- :func:`replay`: republishes a bag's raw CDR with rclpy publishers of the recorded types (a
  ``publish()`` of the serialized bytes: what was recorded is what goes out, bit for bit), with the
  recorded timing scaled by ``rate`` (0 = as fast as possible) and each topic's recorded QoS
  (reliability, durability, depth; /sagg/regions is transient_local), so Foxglove, PlotJuggler or
  a second learner see the run. It joins the caller's ``ROS_DOMAIN_ID`` (the usual ROS default),
  unlike ``sagg run``'s private one, where a real robot's driver may listen: the command topics
  (:data:`~sagg_bringup.bags.topics.COMMAND_TYPES`) are left out unless ``include_commands``, and even
  then refused while a node other than sagg's simulator (:data:`SIM_BRIDGE_NODE`) subscribes to one.
- :func:`relearn`: rebuilds, offline, the learner's sample memory from ``/sagg/sample`` (index
  order) and the goal generator's region tree by feeding the recorded ``/sagg/competence`` reports
  and choosing the goals into the core :class:`~sagg_goal_generator.core.GoalGenerator` exactly as
  the node does (report ``seq`` order; a goal is chosen when the reports 1..``after_report`` are in;
  the report's ``target``, or ``reached`` when it has none), checks every chosen goal against the
  recorded ``/sagg/goal`` and the final tree against the last recorded ``/sagg/regions``, and
  evaluates the memory on the run's test goals with ``sagg run``'s own evaluation code.

Several bags may be given (a resumed run records ``bag``, ``bag2``, ...): messages are read in
bag order; samples, reports and goals republished after a resume are dropped by index / sequence
number (they carry the same values).
"""
from __future__ import annotations

import signal
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError, flatten
from sagg_common.publishers import describe
from sagg_goal_generator.core import SCHEMA as GEN_SCHEMA, GoalGenerator
from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame
from sagg_low_level.learner import SCHEMA as LEARNER_SCHEMA
from sagg_sim_bridge.arms import arm_base_point, arm_spec_from_params
from sagg_sim_bridge.params import SCHEMA as BRIDGE_SCHEMA

from .bag_reader import bag_messages, open_bag
from .bag_recover import is_unfinished, recover_bag
from ..inprocess.arm_params import node_schemas
from ..inprocess.evaluator import evaluate_frozen, evaluation_setup
from .recorded import Recorded, Refed, refeed
from .recorder import msg_class
from .topics import SIM_BRIDGE_NODE, command_topics
from ..report.report import arm_rows, write_report
from ..inprocess.results import goal_share_stats


# ------------------------------------------------------------------------------------ replay
def _rclpy_qos(conn):
    """The recorded offered QoS of a connection as an rclpy profile (reliable, depth 1000,
    volatile where nothing usable was recorded)."""
    # lazy (heavy): ROS, rosbags
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rosbags.interfaces import QosDurability, QosReliability
    profiles = getattr(conn.ext, "offered_qos_profiles", None) or []
    q = profiles[0] if profiles else None
    depth = int(q.depth) if q is not None and q.depth > 0 else 1000
    reliable = q is None or q.reliability != QosReliability.BEST_EFFORT
    latched = q is not None and q.durability == QosDurability.TRANSIENT_LOCAL
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def foreign_subscribers(node, topic: str) -> list[str]:
    """The subscribers of ``topic`` that are not sagg's simulator (one not yet named by discovery
    counts as foreign: it may be a driver), described for a message."""
    return [describe(i) for i in node.get_subscriptions_info_by_topic(topic)
            if i.node_name != SIM_BRIDGE_NODE]


def _refuse_commands(topic: str, names: list[str]) -> ConfigError:
    return ConfigError(f"--include-commands: {topic} has subscriber(s) other than sagg's simulator "
                       f"({SIM_BRIDGE_NODE}): {'; '.join(names)}; a driver there would move its robot, so no "
                       "command is published; allowed: only the simulator on the command topics (stop that "
                       "node, or replay without --include-commands)")


def replay(bag: str | Path, rate: float = 1.0, topics: list[str] | None = None, loop: bool = False,
           wait_subscribers: int = 0, wait_timeout: float = 30.0, domain_id: int | None = None,
           progress: bool = True, out: Callable[[str], None] | None = None, include_commands: bool = False,
           discovery: float = 1.0) -> dict:
    """Republish ``bag``; returns per-topic counts and bytes published. Stops cleanly on SIGINT
    (the current message is finished, publishers are flushed). Command topics only with
    ``include_commands``, and then only while no node but sagg's simulator subscribes to them:
    checked after ``discovery`` s (the graph's subscribers are known by then) and again whenever a
    command publisher's subscriber count changes; a foreign subscriber stops the replay with a
    ConfigError naming the topic and the node(s) (exit code 2)."""
    # lazy (heavy): ROS
    import rclpy
    from rclpy.context import Context
    from rclpy.duration import Duration
    from rclpy.signals import SignalHandlerOptions

    if not rate >= 0 or rate == float("inf"):
        raise ConfigError(f"--rate: got {rate}; allowed: a number >= 0 (0 = as fast as possible)")
    if wait_subscribers < 0:
        raise ConfigError(f"--wait-subscribers: got {wait_subscribers}; allowed: an integer >= 0")
    out = out or (lambda s: print(s, file=sys.stderr, flush=True))
    path = Path(bag)
    if is_unfinished(path):  # a recording whose recorder was killed: recovered first, saying so
        recover_bag(path, out)
    conns, total = _bag_topics(path)
    wanted, commands = _replayed_topics(path, conns, topics, include_commands, progress, out)
    ctx = Context()
    kw = {} if domain_id is None else {"domain_id": int(domain_id)}
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO, **kw)
    node = rclpy.create_node("sagg_replay", context=ctx)
    stop: list[int] = []
    old = {s: signal.signal(s, lambda signum, frame: stop.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    play = _Playback(path, wanted, commands, sum(total[t] for t in wanted), stop)
    try:
        for t in wanted:
            play.pubs[t] = node.create_publisher(msg_class(conns[t].msgtype), t, _rclpy_qos(conns[t]))
        if wait_subscribers:
            play.wait_subscribers(wait_subscribers, wait_timeout)
        play.guard = _CommandGuard(node, play.pubs)
        play.guard.first_check([t for t in wanted if t in commands], discovery, stop)
        play.run(rate, loop, progress, out)
        for p in play.pubs.values():  # reliable messages still in flight reach the subscribers
            p.wait_for_all_acked(Duration(seconds=5.0))
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    res = {"bag": str(path), "rate": rate, "interrupted": bool(stop), "topics": {
        t: {"type": conns[t].msgtype, "count": play.counts[t], "bytes": play.nbytes[t]} for t in wanted}}
    if progress:
        out(f"replayed {sum(play.counts.values()):,} messages ({sum(play.nbytes.values()):,} bytes) on "
            f"{len(wanted)} topic(s)" + (" (interrupted)" if stop else ""))
    return res


def _bag_topics(path: Path) -> tuple[dict, dict[str, int]]:
    """The bag's connections by topic and their message counts."""
    reader = open_bag(path)
    try:
        return {c.topic: c for c in reader.connections}, {c.topic: c.msgcount for c in reader.connections}
    finally:
        reader.close()


def _replayed_topics(path: Path, conns: dict, topics: list[str] | None, include_commands: bool, progress: bool,
                     out: Callable[[str], None]) -> tuple[list[str], set[str]]:
    """The topics to republish (``topics``, else all of the bag's; command topics only with
    ``include_commands``, said when left out) and the bag's command topics; ConfigError for a topic
    not in the bag, a command topic named without ``include_commands``, or nothing left to replay."""
    wanted = list(conns) if not topics else list(topics)
    unknown = [t for t in wanted if t not in conns]
    if unknown:
        raise ConfigError(f"--topics: {', '.join(unknown)} not in the bag; allowed: {', '.join(sorted(conns))}")
    commands = set(command_topics({t: c.msgtype for t, c in conns.items()}))
    named = [t for t in wanted if t in commands]
    if named and topics and not include_commands:
        raise ConfigError(f"--topics: {', '.join(named)} carr{'ies' if len(named) == 1 else 'y'} commands (whatever "
                          "subscribes moves its robot); allowed: add --include-commands to publish them")
    if not include_commands:
        wanted = [t for t in wanted if t not in commands]
        if commands and progress:
            out(f"replay {path.name}: command topic(s) left out: {', '.join(sorted(commands))} "
                "(--include-commands to publish them)")
    if not wanted:
        raise ConfigError("--topics: nothing to replay (only command topics); allowed: other topics, or "
                          "--include-commands")
    return wanted, commands


class _CommandGuard:
    """Refuses to publish on a command topic while a node other than sagg's simulator subscribes to
    it: checked when the topic's subscriber count differs from the last check."""

    def __init__(self, node, pubs: dict):
        self.node, self.pubs = node, pubs
        self.seen: dict[str, int] = {}  # command topic -> its publisher's subscriber count when last checked

    def check(self, topic: str) -> None:
        n = self.pubs[topic].get_subscription_count()
        if self.seen.get(topic) != n:
            names = foreign_subscribers(self.node, topic)
            if names:
                raise _refuse_commands(topic, names)
            self.seen[topic] = n

    def first_check(self, command_pubs: list[str], discovery: float, stop: list[int]) -> None:
        """Before the first message: wait ``discovery`` s (the graph's subscribers are discovered
        meanwhile), then check every command topic to be published."""
        if not command_pubs:
            return
        end = time.monotonic() + discovery
        while not stop and time.monotonic() < end:
            time.sleep(0.05)
        for t in command_pubs:
            self.check(t)


class _Playback:
    """The publishing side of a replay: its publishers by topic, the messages and bytes published
    per topic, and the bag's messages sent in recorded time (until ``stop`` holds a signal)."""

    def __init__(self, path: Path, wanted: list[str], commands: set[str], n_total: int, stop: list[int]):
        self.path, self.wanted, self.commands, self.n_total, self.stop = path, wanted, commands, n_total, stop
        self.pubs: dict = {}
        self.guard: _CommandGuard | None = None
        self.counts = {t: 0 for t in wanted}
        self.nbytes = {t: 0 for t in wanted}

    def wait_subscribers(self, wanted_count: int, timeout: float) -> None:
        """Until every publisher has ``wanted_count`` subscribers; ConfigError after ``timeout`` s."""
        end = time.monotonic() + timeout
        while not self.stop and any(p.get_subscription_count() < wanted_count for p in self.pubs.values()):
            if time.monotonic() > end:
                raise ConfigError(
                    f"--wait-subscribers: fewer than {wanted_count} subscriber(s) on "
                    f"{', '.join(t for t, p in self.pubs.items() if p.get_subscription_count() < wanted_count)}"
                    f" after {timeout:.0f} s")
            time.sleep(0.05)

    def run(self, rate: float, loop: bool, progress: bool, out: Callable[[str], None]) -> None:
        """The bag's messages of the wanted topics, once or round after round (``loop``), at
        ``rate`` times the recorded pace (0: as fast as possible), a progress line each second."""
        rounds, t_last, done = 0, 0.0, 0
        while not self.stop:
            rounds += 1
            t_wall0 = time.monotonic()
            t_bag0 = None
            for topic, _, ts, raw in bag_messages([self.path], set(self.wanted)):
                if t_bag0 is None:
                    t_bag0 = ts
                if rate > 0:
                    self._wait_until(t_wall0 + (ts - t_bag0) / 1e9 / rate)
                if self.stop:
                    break
                self._publish(topic, raw)
                done += 1
                now = time.monotonic()
                if progress and now - t_last > 1.0:
                    t_last = now
                    out(f"replay {self.path.name}: {done - (rounds - 1) * self.n_total:,}/{self.n_total:,} messages"
                        + (f" (round {rounds})" if loop else "") + f", bag time {(ts - t_bag0) / 1e9:.1f} s")
            if not loop:
                break

    def _wait_until(self, t_wall: float) -> None:
        """Sleep until the monotonic time ``t_wall`` in steps of at most 0.1 s, or until stopped."""
        delay = t_wall - time.monotonic()
        while delay > 0 and not self.stop:
            time.sleep(min(delay, 0.1))
            delay = t_wall - time.monotonic()

    def _publish(self, topic: str, raw) -> None:
        if topic in self.commands:
            self.guard.check(topic)
        self.pubs[topic].publish(bytes(raw))
        self.counts[topic] += 1
        self.nbytes[topic] += len(raw)


# ------------------------------------------------------------------------------------ relearn
def params_path(bag: Path, params_file: str | Path | None) -> Path:
    """``params_file``, else ``params.yaml`` next to the bag (``sagg run``'s DIR/params.yaml)."""
    return Path(params_file) if params_file else bag.parent / "params.yaml"


def params_from(bag: Path, params_file: str | Path | None) -> dict[str, dict]:
    """The nodes' parameters (:func:`params_path`), resolved against the full node schemas."""
    path = params_path(bag, params_file)
    if not path.is_file():
        raise ConfigError(f"--params: '{path}' not found; allowed: the run's params.yaml "
                          "(sagg run writes DIR/params.yaml)")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ConfigError(f"--params: '{path}' is not valid YAML ({exc})") from exc
    out = {}
    for name, schema in node_schemas().items():
        body = (doc or {}).get(name, {}).get("ros__parameters", {})
        flat = flatten(body)
        out[name] = {p.name: p.validate(flat[p.name]) if p.name in flat else p.default for p in schema}
    return out


def relearn(bags: list[str | Path], out_dir: str | Path, params_file: str | Path | None = None,
            evaluate: bool = True, report: bool = True, out: Callable[[str], None] = print) -> dict:
    """Rebuild memory and region tree from ``bags``; write DIR/memory.npz, regions.json, summary.json
    (and, with ``report``, report.md + figures of the relearned run via :mod:`.report`). An
    unfinished bag (its recorder was killed) is recovered first (:mod:`.bag_recover`), saying so."""
    paths = [Path(b) for b in bags]
    if not paths:
        raise ConfigError("relearn: no bag given")
    recovered = [recover_bag(p, out) for p in paths if is_unfinished(p)]
    full = params_from(paths[0], params_file)
    gp = {p.name: full["sagg_goal_generator"][p.name] for p in GEN_SCHEMA}
    lp = {p.name: full["sagg_learner"][p.name] for p in LEARNER_SCHEMA}
    bp = {p.name: full["sagg_sim_bridge"][p.name] for p in BRIDGE_SCHEMA}
    t0 = time.perf_counter()
    spec = arm_spec_from_params(bp)
    area, test_goals, learner = evaluation_setup(lp, spec)
    mem = learner.memory
    gen = GoalGenerator(gp)
    rec = Recorded(learner, gen, full, spec)
    rec.read(paths)
    rec.check_complete()
    fed = refeed(gen, rec)
    outp = Path(out_dir)
    outp.mkdir(parents=True, exist_ok=True)
    mem.save(outp / "memory.npz")
    write_json_atomic(outp / "regions.json", {"regions": gen.region_snapshot(), "splits": gen.tree.splits,
                                              "reports": gen.reports, "goals": len(gen.goals)})
    curve, frame = [], None
    if evaluate and len(mem):
        errors = evaluate_frozen(learner, spec, lp, test_goals)
        frame = metric_frame(test_goals, arm_base_point(spec))  # bands from the arm's base (eval_metrics)
        curve.append({"micro_actions": len(mem), **error_metrics(errors, frame)})
    summary = _relearn_summary(paths, recovered, lp, mem, gen, rec, fed, curve, frame, test_goals)
    summary["seconds"] = time.perf_counter() - t0
    if report and curve:
        _write_relearn_report(summary, outp, gen, fed, area, {"sagg_goal_generator": gp, "sagg_learner": lp,
                                                             "sagg_sim_bridge": bp})
    write_json_atomic(outp / "summary.json", summary)
    out(_relearned_line(summary, mem, gen, rec, fed, curve, frame, outp))
    return summary


def _relearn_summary(paths, recovered, lp, mem, gen, rec: Recorded, fed: Refed, curve, frame,
                     test_goals) -> dict:
    """summary.json of a relearn (``seconds`` added by the caller)."""
    last = curve[-1] if curve else {}
    return {
        "format": "sagg.relearn/1", "bags": [str(p) for p in paths], "recovered": recovered,
        "strategy": lp["strategy"], "seed": lp["seed"],
        "memory": {"samples": len(mem), "digest": mem.digest(), "bytes": int(mem.nbytes)},
        "reports": gen.reports, "goals": len(gen.goals), "regions": len(gen.tree.leaves()),
        "splits": len(gen.tree.splits), "duplicates_dropped": rec.dup, "rejected": rec.dropped,
        "goals_match": not fed.mismatches and len(gen.goals) == len(rec.goals),
        "goal_mismatches": fed.mismatches[:100],
        "regions_match": fed.regions_match(rec.snapshots), "regions_snapshots_checked": len(fed.checked),
        "regions_snapshots_differing": fed.differ[:100],
        "last_regions_snapshot_reports": max(rec.snapshots) if rec.snapshots else None,
        "curve": curve, "final_mean_error": last.get("mean_error"),
        "final_median_error": last.get("median_error"),
        "final_within_share": last.get("within_share"),
        "band_mean_errors": last.get("band_mean_errors"),
        "eval_metrics": frame_summary(frame) if curve else None,
        "test_goals": test_goals.tolist(),
    }


def _write_relearn_report(summary: dict, outp: Path, gen: GoalGenerator, fed: Refed, area,
                          config: dict[str, dict]) -> None:
    """report.md and its figures of the relearned run (:func:`~sagg_bringup.report.report.write_report`
    reads the goals, regions and splits from ``summary``, which keeps their counts afterwards:
    regions.json has the tree)."""
    goals_out = [{"seq": g.seq, "position": g.position.tolist(), "mode": g.mode, "competence": g.competence,
                  "micro_actions": fed.report_ma.get(g.after_report, 0)} for g in gen.goals]
    pos = np.array([g["position"] for g in goals_out], float).reshape(-1, gen.dim)
    gma = np.array([g["micro_actions"] for g in goals_out], float)
    n = summary["memory"]["samples"]
    summary.update({
        "config": config, "micro_actions": n, "goals": goals_out, "regions": gen.region_snapshot(),
        "splits": gen.tree.splits, "goal_stats": goal_share_stats(pos, gma, area, n),
        **({} if (teacher := gen.teacher.snapshot()) is None else {"teacher": teacher})})
    write_report(summary, outp, area=area, setup_rows=arm_rows(config["sagg_sim_bridge"]))
    summary["goals"] = len(gen.goals)
    summary["regions"] = len(gen.tree.leaves())
    summary["splits"] = len(gen.tree.splits)


def _relearned_line(summary, mem, gen, rec: Recorded, fed: Refed, curve, frame, outp: Path) -> str:
    """The one line relearn says when it is done."""
    regions_match = summary["regions_match"]
    return (f"relearned {len(mem):,} samples (digest {mem.digest()[:16]}), {gen.reports:,} reports, "
            f"{len(gen.goals)} goals (match recorded: {summary['goals_match']}), {len(gen.tree.leaves())} regions "
            f"(equal to all {len(fed.checked)} recorded /sagg/regions snapshots: {regions_match})"
            + (f"; mean test error {curve[-1]['mean_error']:.3f} (median {curve[-1]['median_error']:.3f}, "
               f"{curve[-1]['within_share']:.0%} within {frame['within']:.3g})" if curve else "")
            + (f"; rejected {sum(rec.dropped.values())} message(s): {rec.dropped}" if rec.dropped else "")
            + f" -> {outp}")
