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

import json
import signal
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from sagg_common.diagnostics import goal_problem, report_problem, sample_problem
from sagg_common.journal import write_json_atomic
from sagg_common.msg_codecs import decode_report, decode_sample
from sagg_common.params import ConfigError, flatten
from sagg_common.publishers import describe
from sagg_common.report_kinds import KIND_NAMES
from sagg_goal_generator.core import SCHEMA as GEN_SCHEMA, GoalGenerator
from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame
from sagg_low_level.learner import SCHEMA as LEARNER_SCHEMA
from sagg_sim_bridge.arms import arm_base_point, arm_spec_from_params
from sagg_sim_bridge.params import SCHEMA as BRIDGE_SCHEMA

from .bag_reader import bag_messages, open_bag
from .bag_recover import is_unfinished, recover_bag
from ..inprocess.arm_params import node_schemas
from ..inprocess.evaluator import evaluate_frozen, evaluation_setup
from .recorder import BagWriter, msg_class
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
    reader = open_bag(path)
    try:
        conns = {c.topic: c for c in reader.connections}
        total = {c.topic: c.msgcount for c in reader.connections}
    finally:
        reader.close()
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
    command_pubs = [t for t in wanted if t in commands]
    ctx = Context()
    kw = {} if domain_id is None else {"domain_id": int(domain_id)}
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO, **kw)
    node = rclpy.create_node("sagg_replay", context=ctx)
    stop: list[int] = []
    old = {s: signal.signal(s, lambda signum, frame: stop.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    pubs = {}
    counts = {t: 0 for t in wanted}
    nbytes = {t: 0 for t in wanted}
    n_total = sum(total[t] for t in wanted)
    try:
        for t in wanted:
            pubs[t] = node.create_publisher(msg_class(conns[t].msgtype), t, _rclpy_qos(conns[t]))
        if wait_subscribers:
            end = time.monotonic() + wait_timeout
            while not stop and any(p.get_subscription_count() < wait_subscribers for p in pubs.values()):
                if time.monotonic() > end:
                    raise ConfigError(
                        f"--wait-subscribers: fewer than {wait_subscribers} subscriber(s) on "
                        f"{', '.join(t for t, p in pubs.items() if p.get_subscription_count() < wait_subscribers)}"
                        f" after {wait_timeout:.0f} s")
                time.sleep(0.05)
        seen: dict[str, int] = {}  # command topic -> its publisher's subscriber count when last checked

        def check_commands(topic: str) -> None:
            n = pubs[topic].get_subscription_count()
            if seen.get(topic) != n:
                names = foreign_subscribers(node, topic)
                if names:
                    raise _refuse_commands(topic, names)
                seen[topic] = n

        if command_pubs:
            end = time.monotonic() + discovery
            while not stop and time.monotonic() < end:  # the graph's subscribers are discovered meanwhile
                time.sleep(0.05)
            for t in command_pubs:
                check_commands(t)
        rounds = 0
        t_last = 0.0
        done = 0
        while not stop:
            rounds += 1
            t_wall0 = time.monotonic()
            t_bag0 = None
            for topic, _, ts, raw in bag_messages([path], set(wanted)):
                if t_bag0 is None:
                    t_bag0 = ts
                if rate > 0:
                    delay = t_wall0 + (ts - t_bag0) / 1e9 / rate - time.monotonic()
                    while delay > 0 and not stop:
                        time.sleep(min(delay, 0.1))
                        delay = t_wall0 + (ts - t_bag0) / 1e9 / rate - time.monotonic()
                if stop:
                    break
                if topic in commands:
                    check_commands(topic)
                pubs[topic].publish(bytes(raw))
                counts[topic] += 1
                nbytes[topic] += len(raw)
                done += 1
                now = time.monotonic()
                if progress and now - t_last > 1.0:
                    t_last = now
                    out(f"replay {path.name}: {done - (rounds - 1) * n_total:,}/{n_total:,} messages"
                        + (f" (round {rounds})" if loop else "") + f", bag time {(ts - t_bag0) / 1e9:.1f} s")
            if not loop:
                break
        for p in pubs.values():  # reliable messages still in flight reach the subscribers
            p.wait_for_all_acked(Duration(seconds=5.0))
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    res = {"bag": str(path), "rate": rate, "interrupted": bool(stop), "topics": {
        t: {"type": conns[t].msgtype, "count": counts[t], "bytes": nbytes[t]} for t in wanted}}
    if progress:
        out(f"replayed {sum(counts.values()):,} messages ({sum(nbytes.values()):,} bytes) on {len(wanted)} topic(s)"
            + (" (interrupted)" if stop else ""))
    return res


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
    reports: dict[int, tuple] = {}
    goals: dict[int, tuple] = {}
    snapshots: dict[int, bytes] = {}  # /sagg/regions by reports folded in (the last one of each count)
    dup = {"samples": 0, "reports": 0, "goals": 0}
    # every recorded message is checked as the nodes check it (docs/safety.md): a bad one is dropped and
    # counted, never stored, and never takes the index / seq of a real one
    dropped: dict[str, int] = {}
    ahead: set[int] = set()  # indices of well-formed samples received before the one expected

    def drop(kind: str) -> None:
        dropped[kind] = dropped.get(kind, 0) + 1

    j_lo, j_hi = full["sagg_learner"]["joint_limits.lower"], full["sagg_learner"]["joint_limits.upper"]
    j_tol = full["sagg_learner"].get("plausibility.joint_tolerance", 0.1)
    if len(j_lo) != mem.alpha.shape[1]:  # (a params file without the arm's joints: the arm's limits)
        j_lo, j_hi = spec.limits()
    window = full["sagg_goal_generator"].get("report_window", 10000)
    wanted = {"/sagg/sample", "/sagg/competence", "/sagg/goal", "/sagg/regions"}
    foreign = foreign_messages(paths)
    for topic, _, ts, raw in bag_messages(paths, wanted):
        if (topic, ts) in foreign:  # the recorder attributed it to another publisher than the expected one
            drop(f"{topic.rsplit('/', 1)[-1]} from another publisher")
            continue
        try:
            if topic == "/sagg/sample":
                sample = decode_sample(raw)
                idx, a, da, dy = sample.index, sample.alpha, sample.delta_alpha, sample.delta_y
                if idx < len(mem):
                    dup["samples"] += 1
                    continue
                if sample_problem(idx, len(mem), a, da, dy, j_lo, j_hi, gen.dim, j_tol):
                    if idx > len(mem) and not sample_problem(idx, idx, a, da, dy, j_lo, j_hi, gen.dim, j_tol):
                        ahead.add(int(idx))
                    drop("sample")
                    continue
                learner.store(a, da, dy)
            elif topic == "/sagg/competence":
                r = decode_report(raw)
                target = r.target if len(r.target) else r.reached
                if not 0 < r.seq <= len(reports) + window or report_problem(
                        r.kind, target, r.competence, gen.dim, KIND_NAMES):
                    drop("report")
                    continue
                if r.seq in reports:
                    dup["reports"] += 1
                reports.setdefault(int(r.seq), r)
            elif topic == "/sagg/goal":
                # lazy (heavy): ROS
                from rclpy.serialization import deserialize_message
                from sagg_msgs.msg import Goal
                g = deserialize_message(bytes(raw), Goal)
                if goal_problem(g.position, gen.lower, gen.upper)[1] or not 0 < int(g.seq) <= len(goals) + window:
                    drop("goal")
                    continue
                key = (int(g.mode), int(g.after_report), np.asarray(g.position, float).tobytes())
                if int(g.seq) in goals:
                    dup["goals"] += 1
                    if goals[int(g.seq)] != key:
                        raise ConfigError(f"bag: goal {g.seq} recorded twice with different values")
                goals.setdefault(int(g.seq), key)
            else:
                # lazy (heavy): ROS
                from rclpy.serialization import deserialize_message
                from sagg_msgs.msg import RegionTree
                snapshots[int(deserialize_message(bytes(raw), RegionTree).reports)] = bytes(raw)
        except ConfigError:
            raise
        except Exception:  # noqa: BLE001 - an undecodable message is dropped, never a crash
            drop(f"{topic.rsplit('/', 1)[-1]} undecodable")
    if len(mem) + 1 in ahead:  # the recording goes on after a hole: samples are missing, not forged
        raise ConfigError(f"bag: /sagg/sample index {len(mem)} is not recorded but later samples are "
                          f"({len(ahead)} of them, from {min(ahead)}): samples are missing")
    # the generator, fed as the node feeds it: reports in seq order, each goal chosen once the
    # reports it follows are in
    seqs = sorted(reports)
    if seqs != list(range(1, len(seqs) + 1)):
        missing = sorted(set(range(1, (seqs[-1] if seqs else 0) + 1)) - set(seqs))
        raise ConfigError(f"bag: /sagg/competence is missing report(s) {missing[:10]}")
    by_after = {}
    for seq, (mode, after, pos) in sorted(goals.items()):
        by_after.setdefault(after, []).append((seq, mode, pos))
    mismatches = []
    report_ma: dict[int, int] = {}
    # lazy (heavy): ROS
    from rclpy.serialization import deserialize_message
    from sagg_msgs.msg import RegionTree
    checked: list[int] = []
    differ: list[int] = []

    def same_tree(raw: bytes) -> bool:
        rec = deserialize_message(raw, RegionTree)
        leaves = gen.tree.leaves()
        return len(rec.regions) == len(leaves) and all(
            int(r.id) == g.id and np.asarray(r.lower).tobytes() == g.lower.tobytes()
            and np.asarray(r.upper).tobytes() == g.upper.tobytes() and int(r.count) == g.count
            and np.float64(r.interest).tobytes() == np.float64(g.interest).tobytes()
            for r, g in zip(rec.regions, leaves))

    def check_snapshot() -> None:
        if gen.reports in snapshots:
            checked.append(gen.reports)
            if not same_tree(snapshots[gen.reports]):
                differ.append(gen.reports)

    check_snapshot()

    def choose_due() -> None:
        for seq, mode, pos in by_after.pop(gen.reports, []):
            rec = gen.next_goal()
            if (rec.seq, rec.mode, rec.position.tobytes()) != (seq, mode, pos):
                mismatches.append(seq)

    for seq in seqs:
        choose_due()
        r = reports[seq]
        report_ma[seq] = int(r.micro_actions)
        gen.report(r.kind, r.target if len(r.target) else r.reached, r.competence)
        check_snapshot()
    choose_due()
    if by_after:
        mismatches.extend(s for v in by_after.values() for s, _, _ in v)
    # every recorded snapshot equals the relearned tree after the same number of reports
    regions_match = bool(checked) and not differ and (max(snapshots) in checked)
    outp = Path(out_dir)
    outp.mkdir(parents=True, exist_ok=True)
    mem.save(outp / "memory.npz")
    write_json_atomic(outp / "regions.json", {"regions": gen.region_snapshot(), "splits": gen.tree.splits,
                                              "reports": gen.reports, "goals": len(gen.goals)})
    curve = []
    if evaluate and len(mem):
        errors = evaluate_frozen(learner, spec, lp, test_goals)
        frame = metric_frame(test_goals, arm_base_point(spec))  # bands from the arm's base (eval_metrics)
        curve.append({"micro_actions": len(mem), **error_metrics(errors, frame)})
    summary = {
        "format": "sagg.relearn/1", "bags": [str(p) for p in paths], "recovered": recovered,
        "strategy": lp["strategy"], "seed": lp["seed"],
        "memory": {"samples": len(mem), "digest": mem.digest(), "bytes": int(mem.nbytes)},
        "reports": gen.reports, "goals": len(gen.goals), "regions": len(gen.tree.leaves()),
        "splits": len(gen.tree.splits), "duplicates_dropped": dup, "rejected": dropped,
        "goals_match": not mismatches and len(gen.goals) == len(goals), "goal_mismatches": mismatches[:100],
        "regions_match": regions_match, "regions_snapshots_checked": len(checked),
        "regions_snapshots_differing": differ[:100],
        "last_regions_snapshot_reports": max(snapshots) if snapshots else None,
        "curve": curve, "final_mean_error": curve[-1]["mean_error"] if curve else None,
        "final_median_error": curve[-1]["median_error"] if curve else None,
        "final_within_share": curve[-1]["within_share"] if curve else None,
        "band_mean_errors": curve[-1]["band_mean_errors"] if curve else None,
        "eval_metrics": frame_summary(frame) if curve else None,
        "test_goals": test_goals.tolist(), "seconds": time.perf_counter() - t0,
    }
    if report and curve:
        goals_out = [{"seq": g.seq, "position": g.position.tolist(), "mode": g.mode, "competence": g.competence,
                      "micro_actions": report_ma.get(g.after_report, 0)} for g in gen.goals]
        pos = np.array([g["position"] for g in goals_out], float).reshape(-1, gen.dim)
        gma = np.array([g["micro_actions"] for g in goals_out], float)
        summary.update({
            "config": {"sagg_goal_generator": gp, "sagg_learner": lp, "sagg_sim_bridge": bp},
            "micro_actions": len(mem), "goals": goals_out, "regions": gen.region_snapshot(),
            "splits": gen.tree.splits, "goal_stats": goal_share_stats(pos, gma, area, len(mem)),
            **({} if (teacher := gen.teacher.snapshot()) is None else {"teacher": teacher})})
        write_report(summary, outp, area=area, setup_rows=arm_rows(bp))
        summary["goals"] = len(gen.goals)  # summary.json keeps counts; regions.json has the tree
        summary["regions"] = len(gen.tree.leaves())
        summary["splits"] = len(gen.tree.splits)
    write_json_atomic(outp / "summary.json", summary)
    out(f"relearned {len(mem):,} samples (digest {mem.digest()[:16]}), {gen.reports:,} reports, "
        f"{len(gen.goals)} goals (match recorded: {summary['goals_match']}), {len(gen.tree.leaves())} regions "
        f"(equal to all {len(checked)} recorded /sagg/regions snapshots: {regions_match})"
        + (f"; mean test error {curve[-1]['mean_error']:.3f} (median {curve[-1]['median_error']:.3f}, "
           f"{curve[-1]['within_share']:.0%} within {frame['within']:.3g})" if curve else "")
        + (f"; rejected {sum(dropped.values())} message(s): {dropped}" if dropped else "")
        + f" -> {outp}")
    return summary
