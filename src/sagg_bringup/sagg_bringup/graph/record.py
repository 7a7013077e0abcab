"""``sagg record [--out DIR] [--params FILE]``: the recorder alone, for graphs started with
``ros2 run`` / ``ros2 launch`` (or any driver), into an mcap rosbag2 bag.

The topic set is ``sagg run``'s (:func:`recorded_topics`: the ``/sagg`` topics, ``/joint_states``,
the commands and the task-space topic named by the parameter file, ``/clock``, ``/sagg/markers``).
A topic is subscribed when its first publisher appears, with the publishers' QoS (reliable unless
one of them is best effort; transient_local when all of them are, so the latched
``/sagg/regions``, ``/sagg/markers`` and the learner's ``/sagg/competence`` history arrive even when
the recorder starts late), and its connection is added to the bag with that QoS. Raw CDR is written
as received (:class:`~sagg_bringup.bags.recorder.TopicRecorder`: sequence gaps counted, handlers fed
from the expected publisher only).

Like ``sagg run``'s recorder it acknowledges the samples it has recorded on /sagg/recorded, so the
learner waits while it lags (``recorder_max_lag``; :mod:`.record_account`). Ctrl-C (SIGINT) or
SIGTERM stops it in two steps: it acknowledges nothing more (the learner stops within
``recorder_max_lag`` samples) and keeps taking messages until nothing came for ``quiet`` s once
every recorded topic's publishers are gone (the nodes exited), or, while some live on (a driver, or
nodes still running), the nodes' streams (samples, reports, goals, commands) were quiet for ``idle``
s; at most ``drain_limit`` s; a second signal stops at once. Then the bag is closed (mcap
footer and ``metadata.yaml``, whose ``custom_data`` holds the counts below) and the counts printed:
per topic the messages recorded, those the nodes announced as published (/diagnostics), those
published before the recorder subscribed, and those lost (:meth:`RecordAccount.losses`).
"""
from __future__ import annotations

import json
import os
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path

from sagg_common.params import ConfigError
from sagg_common.ros_params import reliable

from .markers import MarkerView, MARKER_TOPIC
from .record_account import RecordAccount
from ..bags.recorder import Acknowledger, BagWriter, TopicRecorder, TopicSpec, both
from ..bags.topics import COMMAND_TYPES, STREAM_TOPICS, awaited_topics, graph_topics

# exit code of `sagg record` when messages were lost (cli)
LOST_EXIT_CODE = 3


def recorded_topics(params_file: str | Path | None = None) -> list[TopicSpec]:
    """``sagg run``'s topics for the graph a parameter file (a config or a run's params.yaml)
    describes; the defaults (``/forward_position_controller/commands``, ``/tip_position``) without one."""
    extra = [TopicSpec("/clock", "rosgraph_msgs/msg/Clock", depth=100),
             TopicSpec(MARKER_TOPIC, "visualization_msgs/msg/MarkerArray", depth=1, transient_local=True)]
    if params_file is None:
        return graph_topics({}) + extra
    # lazy (heavy): ROS, mujoco (the set-up registry loads every runner)
    from .setups import recorded_topics as setup_topics
    return setup_topics(params_file) + extra


def publishers_qos(infos, spec: TopicSpec) -> TopicSpec:
    """``spec`` with the reliability and durability every publisher of ``infos`` offers (a reliable
    or transient_local subscription would not match a best-effort or volatile publisher)."""
    # lazy (heavy): ROS
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy
    best_effort = any(i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos)
    latched = bool(infos) and all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos)
    return replace(spec, transient_local=latched, best_effort=best_effort)


class LiveRecorder(TopicRecorder):
    """A :class:`~sagg_bringup.bags.recorder.TopicRecorder` whose topics are subscribed once they have a
    publisher of the expected type (checked by :meth:`poll`), with the publishers' QoS.

    ``gate`` topics (/sagg/sample) are subscribed only once every ``wait_for`` topic (the hardware
    topics, /sagg/competence) is subscribed and matched for ``settle`` s: a learner waiting for its
    sample subscriber (``min_sample_subscribers``, as with record:=true) then publishes no command,
    joint state or outcome before the recorder can receive it (on a loaded machine this process
    may learn of the bridge's /joint_states publisher seconds after the learner). A
    ``wait_for`` topic that has no publisher ``gate_timeout`` s after the gated topic's first one
    appeared no longer holds the gate (a parameter file naming another controller must not keep
    /sagg/sample unrecorded); it is logged."""

    def __init__(self, node, bag: BagWriter, topics: list[TopicSpec], handlers: dict | None = None,
                 gate: tuple[str, ...] = (), wait_for: tuple[str, ...] = (), settle: float = 0.5,
                 gate_timeout: float = 10.0):
        super().__init__(node, bag, [], handlers, settle=settle)
        self.waiting = {t.name: t for t in topics}
        self.qos: dict[str, TopicSpec] = {}
        self.gate, self.wait_for, self.gate_timeout = frozenset(gate), frozenset(wait_for), gate_timeout
        self.subs: dict = {}  # topic -> its subscription
        self._ready_since: float | None = None
        self._gate_seen: float | None = None  # when a gated topic's publisher was first seen

    def _gate_open(self) -> bool:
        now = time.monotonic()
        if self._gate_seen is None:
            self._gate_seen = now
        patient = now - self._gate_seen < self.gate_timeout
        held = [t for t in self.wait_for
                if (t in self.subs and self.subs[t].get_publisher_count() == 0)
                or (t not in self.subs and (patient or self.node.count_publishers(t) > 0))]
        if held:
            self._ready_since = None
            return False
        if self._ready_since is None:
            self._ready_since = now
            absent = sorted(t for t in self.wait_for if t not in self.subs)
            if absent:
                self.node.get_logger().warning(
                    f"no publisher on {', '.join(absent)} after {self.gate_timeout:.0f} s: subscribing "
                    f"{', '.join(sorted(self.gate))} without them (--params names the graph's topics?)")
        return now - self._ready_since >= self.settle

    def poll(self) -> None:
        for name, spec in list(self.waiting.items()):
            infos = [i for i in self.node.get_publishers_info_by_topic(name) if i.topic_type == spec.msgtype]
            if not infos or (name in self.gate and not self._gate_open()):
                continue
            del self.waiting[name]
            t = publishers_qos(infos, spec)
            self.bag.add_topic(t)
            self.qos[name] = t
            self.subs[name] = self._subscribe(t)
            self.node.get_logger().info(f"subscribed to {name} ({len(infos)} publisher(s))")  # (as ros2 bag record)


def record(out: str | Path, params_file: str | Path | None = None, domain_id: int | None = None,
           duration: float | None = None, progress: bool = True, markers: bool = True,
           quiet: float = 0.5, idle: float = 2.0, drain_limit: float = 20.0) -> dict:
    """Record until Ctrl-C / SIGTERM (or ``duration`` s), then take what the nodes still publish
    (module doc); returns ``{"path", "topics", "interrupted", "qos", "published", "before", "lost",
    "drain"}``. ``markers``: also publish the live view on /sagg/markers (:mod:`.markers`) from
    what is recorded."""
    # lazy (heavy): ROS
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    out = Path(out)
    if out.exists():
        raise ConfigError(f"--out: '{out}' exists; allowed: a new path (the bag directory)")
    topics = recorded_topics(params_file)
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ConfigError(f"--domain-id: got {domain_id}; allowed: an integer in [0, 232]")
    ctx = Context()
    kw = {} if domain_id is None else {"domain_id": int(domain_id)}
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO, **kw)
    stop: list[int] = []
    old = {s: signal.signal(s, lambda signum, frame: stop.append(signum)) for s in (signal.SIGINT, signal.SIGTERM)}
    session = _Recording(ctx, out, topics, markers, progress)
    try:
        session.start()
        session.record_until(stop, duration)
        drain = session.drain(stop, quiet, idle, drain_limit)
        counts = session.counts(drain)
    finally:
        session.close()
        rclpy.shutdown(context=ctx)
        for s, h in old.items():
            signal.signal(s, h)
    rec = session.rec
    res = {"path": str(out), "topics": session.bag.topics(), "interrupted": bool(stop),
           "first_sample_index": session.account.first_index,
           "qos": {t: {"transient_local": s.transient_local, "best_effort": s.best_effort} for t, s in rec.qos.items()},
           "published": counts["published"], "before": counts["before"], "lost": counts["lost"], "drain": drain,
           "rejected": counts["rejected"], "lost_not_estimated": sorted(rec.drops_unknown)}
    for line in counts_report(res, progress):
        print(line, file=sys.stderr)
    return res


class _Recording:
    """One ``sagg record`` session on a node of its own (``sagg_record``): the bag, the live
    recorder, the account of samples and losses (:class:`.record_account.RecordAccount`) with its
    acknowledgements, and the live view (``markers``)."""

    def __init__(self, ctx, out: Path, topics: list[TopicSpec], markers: bool, progress: bool):
        # lazy (heavy): ROS
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        self.out, self.topics, self.progress = out, topics, progress
        self.node = rclpy.create_node("sagg_record", context=ctx)
        self.executor = SingleThreadedExecutor(context=ctx)
        self.executor.add_node(self.node)
        out.parent.mkdir(parents=True, exist_ok=True)
        self.bag = BagWriter(out, [])
        self.view = None
        self.rec: LiveRecorder | None = None
        self.ack: Acknowledger | None = None
        self.account = RecordAccount({t.name for t in topics})
        self.handlers = {"/sagg/sample": self.account.on_sample, "/sagg/competence": self.account.on_report,
                         "/sagg/status": self.account.on_status}
        if markers:
            self.view = MarkerView(self.node, topics)
            for topic, h in self.view.handlers().items():
                self.handlers[topic] = h if topic not in self.handlers else both(self.handlers[topic], h)
        self.stream = [t.name for t in topics if t.name in STREAM_TOPICS or t.msgtype in COMMAND_TYPES]
        self.status = "recording"
        self._last_print = 0.0

    def start(self) -> None:
        """The live recorder (topics subscribed as their publishers appear), the acknowledgements
        and /diagnostics (what the nodes announce as published)."""
        # lazy (heavy): ROS
        from diagnostic_msgs.msg import DiagnosticArray
        self.rec = LiveRecorder(self.node, self.bag, self.topics, self.handlers, gate=("/sagg/sample",),
                                wait_for=awaited_topics(self.topics))
        self.account.st.on_reject = self.rec.log_problem
        self.ack = Acknowledger(self.node, self.account.acknowledged)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.account.on_diagnostics, reliable(100))

    def close(self) -> None:
        if self.rec is not None:
            self.rec.destroy()
        self.bag.close()
        self.executor.shutdown()
        self.node.destroy_node()

    def take(self) -> None:
        """One loop: subscribe new topics, the callbacks queued, the acknowledgement, the view."""
        self.rec.poll()
        self.executor.spin_once(timeout_sec=0.05)
        for _ in range(1000):  # drain what is queued
            before = self.bag.written
            self.executor.spin_once(timeout_sec=0)
            if self.bag.written == before:
                break
        self.ack.tick()
        if self.view is not None:
            self.view.maybe_publish()

    def stream_messages(self) -> int:
        """Messages recorded on the nodes' streams (samples, reports, goals, commands)."""
        return sum(self.bag.counts.get(t, 0) for t in self.stream)

    def others(self) -> int:
        """Every recorded message but our own view's."""
        return self.bag.written - self.bag.counts.get(MARKER_TOPIC, 0)

    def show(self, now: float) -> None:
        if self.progress and now - self._last_print >= 2.0:
            self._last_print = now
            print(f"\r{self.status} {self.out}: {self.bag.written:,} messages on {len(self.rec.qos)} topics "
                  f"({len(self.rec.waiting)} without publisher yet)", end="", file=sys.stderr, flush=True)

    def record_until(self, stop: list[int], duration: float | None) -> None:
        """Record until a signal or ``duration`` s."""
        t0 = time.monotonic()
        while not stop and (duration is None or time.monotonic() - t0 < duration):
            self.take()
            self.show(time.monotonic())

    def drain(self, stop: list[int], quiet: float, idle: float, drain_limit: float) -> dict:
        """Stopping: the learner gets no further acknowledgement, and what the nodes published comes
        in (module doc: ``quiet``, ``idle``, ``drain_limit``, or a second signal). Returns the drain's
        seconds, the messages it took on the nodes' streams and why it ended."""
        self.ack.freeze()
        signals = len(stop)
        self.status = "stopping (Ctrl-C again: at once)"
        drain = {"seconds": 0.0, "ended": "", "messages": 0}
        t_drain = t_last = t_any = time.monotonic()
        last = n0 = self.stream_messages()
        last_any = self.others()
        while len(stop) <= signals:
            self.take()
            now = time.monotonic()
            self.show(now)
            if self.others() != last_any:
                last_any, t_any = self.others(), now
            n = self.stream_messages()
            if n != last:
                last, t_last = n, now
                continue
            # every recorded topic (but our own view) without publisher: the nodes have exited, and
            # what they published is in once nothing came for `quiet` s; while some live on (a
            # driver, or nodes still running), the streams' silence for `idle` s ends it
            alive = [t for t in self.rec.qos if t != MARKER_TOPIC and self.node.count_publishers(t) > 0]
            if not alive:
                if now - t_any >= quiet:
                    drain["ended"] = f"nothing came for {quiet} s and every publisher is gone"
                    break
            elif now - t_last >= idle:
                drain["ended"] = f"the nodes' streams quiet for {idle} s (publishers still on {', '.join(alive)})"
                break
            if now - t_drain >= drain_limit:
                drain["ended"] = f"drain_limit ({drain_limit} s) reached"
                break
        else:
            drain["ended"] = "a second signal"
        drain.update(seconds=round(time.monotonic() - t_drain, 3), messages=self.stream_messages() - n0)
        return drain

    def counts(self, drain: dict) -> dict[str, dict]:
        """What was published, published before the recorder subscribed, lost and rejected, per topic;
        written into the bag's ``custom_data`` with the ``drain``."""
        account, rec, bag = self.account, self.rec, self.bag
        received = {t: bag.counts.get(t, 0) for t in bag.counts}
        before = account.before(received, rec.first_seq)
        lost = account.losses(received, before, rec.dropped)
        published = account.published()
        rejected = {**rec.rejected, **account.st.rejected}  # messages recorded but not used (docs/safety.md)
        for key, value in (("sagg.recorder", "sagg record"), ("sagg.published", published),
                           ("sagg.published_before_subscribed", before), ("sagg.lost", lost),
                           ("sagg.lost_not_estimated", sorted(rec.drops_unknown)), ("sagg.drain", drain),
                           ("sagg.first_sample_index", account.first_index), ("sagg.rejected", rejected)):
            bag.set_custom_data(key, value if isinstance(value, str) else json.dumps(value, sort_keys=True))
        return {"published": published, "before": before, "lost": lost, "rejected": rejected}


def counts_report(res: dict, full: bool = True) -> list[str]:
    """The lines ``sagg record`` prints at the end (``full``: all of them, else only a loss)."""
    lines = []
    if full:
        lines.append(f"\nbag closed: {res['path']} ({sum(v['count'] for v in res['topics'].values()):,} messages: "
                     + ", ".join(f"{t} {v['count']}" for t, v in sorted(res['topics'].items())) + ")")
        d = res["drain"]
        lines.append(f"stopped after {d['seconds']:.1f} s of taking what was still coming ({d['messages']:,} "
                     f"messages on the nodes' streams): {d['ended']}")
        for key, text in (("published", "published by the nodes (as last announced on /diagnostics)"),
                          ("before", "published before the recorder subscribed (not in the bag)"),
                          ("rejected", "recorded but not used (another publisher, or content rejected)")):
            if res[key]:
                lines.append(f"{text}: " + ", ".join(f"{t} {n}" for t, n in sorted(res[key].items())))
        if res["first_sample_index"]:
            lines.append(f"the bag's samples start at index {res['first_sample_index']} (the learner's earlier "
                         "ones were published before the recorder subscribed, or not at all while nobody "
                         "subscribed: start sagg record first and the learner with min_sample_subscribers:=1)")
        if res["lost_not_estimated"]:
            lines.append("no loss estimate from sequence numbers (several publishers): "
                         + ", ".join(res["lost_not_estimated"]))
    if res["lost"]:
        lines.append("sagg record: LOST (published while recording, not in the bag): "
                     + ", ".join(f"{t} {n}" for t, n in res["lost"].items()) + f"; exit code {LOST_EXIT_CODE}")
    return lines


def default_out() -> Path:
    return Path("runs") / f"record-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
