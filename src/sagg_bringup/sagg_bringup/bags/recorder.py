"""Recording the graph's topics into an mcap rosbag2 bag (no rosbag2 on PyPI: rosbags writes it).

Two parts:

- :class:`BagWriter` (ROS-free): a rosbags ``Writer`` (rosbag2 format version 9, mcap storage)
  with the sagg_msgs types registered from their ``.msg`` text, one connection per topic, and
  per-topic message counts.
- :class:`TopicRecorder`: raw (``raw=True``) rclpy subscriptions on an existing node; the CDR bytes
  are written exactly as received (docs/architecture.md: they are valid CDR, unlike the output of
  ``rclpy.serialization.serialize_message``), and optional per-topic handlers get the deserialized
  message as well.

Timestamps are the receive times (ns since the epoch), as ``ros2 bag record`` does.
"""
from __future__ import annotations

import importlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import yaml

from sagg_common.journal import write_json_atomic
from sagg_common.msg_codecs import MESSAGES, find_msg_dir
from sagg_common.publishers import PublisherStream, PublisherWatch

from .bag_channels import add_type_hashes

# topics whose publisher keeps only the latest message by design (a reader may skip snapshots):
# not counted as dropped
NO_DROP_COUNT = ("/sagg/regions", "/sagg/markers")


@dataclass(frozen=True)
class TopicSpec:
    """One recorded topic: name, ROS type (``pkg/msg/Name``), subscription depth, durability, and
    the node expected to publish it (its handler gets no message while another node publishes too)."""

    name: str
    msgtype: str
    # (deep: a lockstep learner can outrun the recorder by more than 10000 messages on a loaded
    # machine, and the reader would drop the oldest; counted in bag.dropped either way)
    depth: int = 100000
    transient_local: bool = False
    best_effort: bool = False  # (`sagg record` takes the publishers' reliability)
    publisher: str | None = None  # the node whose messages the handler accepts (None: any single publisher)
    optional: bool = False  # recorded when published, but no part of the contract: nothing waits for it


def make_typestore(msg_dir: Path | None = None):
    """A rosbags typestore with the ROS 2 Jazzy types plus sagg_msgs (parsed from .msg text)."""
    # lazy (heavy): rosbags
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    msg_dir = msg_dir or find_msg_dir()
    types = {}
    for name in MESSAGES:
        types.update(get_types_from_msg((msg_dir / f"{name}.msg").read_text(), f"sagg_msgs/msg/{name}"))
    store.register(types)
    return store


def _qos(spec: TopicSpec):
    # lazy (heavy): rosbags
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)
    zero = QosTime(0, 0)  # rosbag2's "unspecified" (the rmw default)
    return Qos(QosHistory.KEEP_LAST, spec.depth,
               QosReliability.BEST_EFFORT if spec.best_effort else QosReliability.RELIABLE,
               QosDurability.TRANSIENT_LOCAL if spec.transient_local else QosDurability.VOLATILE,
               zero, zero, QosLiveliness.AUTOMATIC, zero, False)


def publishers_qos(infos) -> list:
    """The offered QoS of the publishers ``infos`` (``Node.get_publishers_info_by_topic``) as
    rosbags ``Qos``, as ``ros2 bag record`` writes them (history unknown, depth 0: DDS does not
    tell the reader; infinite durations as INT64_MAX ns)."""
    # lazy (heavy): rosbags
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)

    def dur(d) -> QosTime:
        return QosTime(*divmod(int(d.nanoseconds), 1_000_000_000))

    out = []
    for i in infos:
        q = i.qos_profile
        out.append(Qos(QosHistory(int(q.history)), int(q.depth), QosReliability(int(q.reliability)),
                       QosDurability(int(q.durability)), dur(q.deadline), dur(q.lifespan),
                       QosLiveliness(int(q.liveliness)), dur(q.liveliness_lease_duration),
                       bool(q.avoid_ros_namespace_conventions)))
    return out


class BagWriter:
    """An mcap rosbag2 bag (version 9) being written; one connection per topic.

    A topic's connection is created at its first message (or at :meth:`close`), so that the
    recorder can give it the offered QoS of the topic's publishers (:meth:`offer`), as ``ros2 bag
    record`` does; without an offer, the spec's QoS is written. metadata.yaml says
    ``ros_distro: jazzy`` (the distribution whose types and QoS the bag holds)."""

    ROS_DISTRO = "jazzy"
    FOREIGN_FILE = "foreign_messages.json"

    def __init__(self, path: str | Path, topics: list[TopicSpec], typestore=None):
        # lazy (heavy): rosbags
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f"bag path '{self.path}' exists already; allowed: a new path")
        self.typestore = typestore or make_typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._conn = {}
        self._specs = {t.name: t for t in topics}
        self._offered: dict[str, list] = {}
        self.counts: dict[str, int] = {}
        self.written = 0  # messages written, all topics
        # recorded messages attributed to a publisher other than their topic's expected one
        # (TopicRecorder's publisher streams): written to FOREIGN_FILE at close, for relearn
        self.foreign: list[tuple[str, int, str]] = []
        self.types: dict[str, str] = {}
        try:
            for t in topics:
                self.add_topic(t)
        except Exception:
            self.abort()
            raise
        self.closed = False

    def add_topic(self, t: TopicSpec) -> None:
        """One more topic (e.g. first seen after the bag was opened); its connection is made at its
        first message (or at :meth:`close`), with its publishers' QoS when :meth:`offer` gave them."""
        self.typestore.hash_rihs01(t.msgtype)  # an unknown type fails here, not mid-run
        self._specs[t.name] = t
        self.counts[t.name] = 0
        self.types[t.name] = t.msgtype

    def offer(self, topic: str, qos_profiles: list) -> None:
        """The offered QoS of ``topic``'s publishers (before its first message is written)."""
        if topic not in self._conn and qos_profiles:
            self._offered[topic] = list(qos_profiles)

    def _connect(self, topic: str):
        t = self._specs[topic]
        conn = self._conn[topic] = self._writer.add_connection(
            topic, t.msgtype, typestore=self.typestore, serialization_format="cdr",
            offered_qos_profiles=self._offered.get(topic) or [_qos(t)])
        return conn

    def set_custom_data(self, key: str, value: str) -> None:
        """A ``custom_data`` entry of metadata.yaml (rosbag2's string map; before :meth:`close`)."""
        self._writer.set_custom_data(key, value)

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        conn = self._conn.get(topic) or self._connect(topic)
        self._writer.write(conn, int(timestamp_ns), data)
        self.counts[topic] += 1
        self.written += 1

    def close(self) -> None:
        """Write the mcap footer and metadata.yaml (idempotent)."""
        if not self.closed:
            self.closed = True
            for topic in self._specs:
                if topic not in self._conn:
                    self._connect(topic)
            self._writer.close()
            doc = self._set_distro()
            self._set_type_hashes(doc)
            if self.foreign:
                self._write_foreign()

    def _write_foreign(self) -> None:
        """``FOREIGN_FILE`` in the bag directory: (topic, bag timestamp, why) of every recorded
        message the recorder attributed to another publisher than the topic's expected node (rclpy
        gives no publisher GID per message in Jazzy: the attribution is the recorder's publisher
        stream, :class:`~sagg_common.publishers.PublisherStream`). ``sagg relearn`` skips them, so
        a forged message never displaces the real one with the same index or seq."""
        write_json_atomic(self.path / self.FOREIGN_FILE, {
            "format": "sagg.foreign/1",
            "doc": "messages of this bag not from their topic's expected publisher (sagg run's recorder)",
            "messages": [list(m) for m in self.foreign]})

    def _set_distro(self) -> dict:
        """metadata.yaml's ``ros_distro`` (rosbags writes its own name there); returns the document."""
        meta = self.path / "metadata.yaml"
        doc = yaml.safe_load(meta.read_text())
        doc["rosbag2_bagfile_information"]["ros_distro"] = self.ROS_DISTRO
        meta.write_text(yaml.safe_dump(doc, sort_keys=False))
        return doc

    def _set_type_hashes(self, doc: dict) -> None:
        """``topic_type_hash`` (RIHS01) on every mcap channel, as rosbag2 writes it (rosbags does
        not: :mod:`.bag_channels`), and ``ros_distro`` in the mcap's copy of the bag information."""
        hashes = {t: self.typestore.hash_rihs01(ty) for t, ty in self.types.items()}
        for rel in doc["rosbag2_bagfile_information"]["relative_file_paths"]:
            add_type_hashes(self.path / rel, hashes, self.ROS_DISTRO)

    def abort(self) -> None:
        self.closed = True
        try:
            self._writer.close()
        except Exception:  # noqa: BLE001 - best effort
            pass

    def topics(self) -> dict[str, dict]:
        return {t: {"type": self.types[t], "count": self.counts[t]} for t in self.counts}


ACK_TOPIC = "/sagg/recorded"


class Acknowledger:
    """The recorder's side of the learner's backpressure (``recorder_max_lag``): ``source()``, the
    samples recorded and accepted contiguously (from index 0, or from where the recorder's stream
    started: :meth:`~sagg_bringup.graph.run_state.RunState.start_samples_at`), on /sagg/recorded
    (std_msgs/UInt64) at every :meth:`tick` where it changed, and at least every ``period`` s (a
    learner that subscribes later, e.g. a resumed one, gets it too). The publisher is created at
    the first value ``source()`` knows (not None): the learner waits while /sagg/recorded has a
    publisher, so a recorder that does not know yet where its stream starts must not have one.
    :meth:`freeze` keeps the value from then on (a recorder that is stopping: the learner stops
    within ``recorder_max_lag`` samples, so the stream ends inside what the recorder still takes)."""

    def __init__(self, node, source: Callable[[], int | None], period: float = 0.5):
        self.node, self.source, self.period = node, source, period
        self.pub = None
        self.acked, self.t = -1, 0.0
        self.frozen: int | None = None
        self.tick()

    def tick(self) -> None:
        n = self.source() if self.frozen is None else self.frozen
        if n is None:
            return
        if self.pub is None:
            # lazy (heavy): ROS interface package
            from std_msgs.msg import UInt64
            self._uint64 = UInt64
            self.pub = self.node.create_publisher(UInt64, ACK_TOPIC, 10)
        now = time.monotonic()
        if n != self.acked or now - self.t >= self.period:
            self.acked, self.t = n, now
            self.pub.publish(self._uint64(data=int(n)))

    def freeze(self) -> None:
        """Acknowledge nothing more (the last value is still re-published every ``period`` s)."""
        if self.pub is not None:
            self.frozen = self.acked


def both(first: Callable, second: Callable) -> Callable:
    """Both handlers; the first one's answer (truthy: message used) is the recorder's, which
    advances the expected publisher's stream with it (dropping it left the stream at 0: while a
    second publisher was on the topic, every real message was then rejected as foreign)."""
    def handler(msg):
        used = first(msg)
        second(msg)
        return used
    return handler


def msg_class(msgtype: str):
    pkg, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


def _follow(tails: list[int], seq: int, streams: int = 4, max_gap: int = 100_000) -> int:
    """Messages missed before publication number ``seq``, given the last numbers ``tails`` of the
    topic's recent publisher streams (updated; most recent last). A number continues the stream
    whose last number is the largest below it; one at or below every tail, or too far ahead, starts
    a new stream (another publisher) and counts nothing."""
    best = -1
    for i, t in enumerate(tails):
        if t < seq and (best < 0 or t > tails[best]):
            best = i
    if best >= 0 and seq - tails[best] <= max_gap:
        gap = seq - tails[best] - 1
        tails.append(seq)
        del tails[best]
        return gap
    tails.append(seq)
    if len(tails) > streams:
        del tails[0]
    return 0


class TopicRecorder:
    """Raw subscriptions on ``node`` writing every message of ``topics`` into ``bag``.

    ``handlers[topic](msg)`` is called (in the executor's thread) with the deserialized message
    after it has been written, for the topics that have one; for a topic with an expected
    publisher, only for messages continuing that publisher's stream
    (:class:`~sagg_common.publishers.PublisherStream`), which a handler's truthy return (message
    used) advances.

    ``gate``: topics subscribed only once every topic of ``wait_for`` has had a matched publisher
    for ``settle`` seconds (:meth:`poll_gate`; the publisher side of the match, which decides
    delivery, completes a little after ours). The learner starts acting only when ``/sagg/sample`` has a subscriber
    (``min_sample_subscribers``), so gating that subscription on the hardware topics means no
    command, joint state or outcome is published before the recorder can receive it."""

    def __init__(self, node, bag: BagWriter, topics: list[TopicSpec],
                 handlers: dict[str, Callable] | None = None, gate: tuple[str, ...] = (),
                 wait_for: tuple[str, ...] = (), settle: float = 0.5):
        self.node = node
        self.settle = settle
        self._matched_since: float | None = None
        self.bag = bag
        self.handlers = handlers or {}
        self.first_ns: dict[str, int] = {}
        self.last_ns: dict[str, int] = {}
        self._subs = []
        # handlers take messages only from the expected publisher (docs/safety.md): while a topic has
        # another, its messages are recorded (the bag is what happened) but not handled; counted
        self.watch = PublisherWatch(node)
        self.streams: dict = {}              # topic -> PublisherStream (topics with an expected publisher)
        self.rejected: dict[str, int] = {}   # "<topic> <why>" -> messages not handed to the handler
        self.dropped: dict[str, int] = {}    # topic -> messages published but never received (missed)
        self.drops_unknown: set[str] = set()  # topics that had several publishers: no drop estimate
        self.last_seq: dict[str, list] = {}  # topic -> the last publication numbers of its recent streams
        # topic -> publication number of the first message received (while it had one publisher):
        # the messages numbered below it were published before this subscription matched
        self.first_seq: dict[str, int] = {}
        self._offered: set[str] = set()      # topics whose publishers' QoS went to the bag
        self.problems: dict[str, str] = {}   # topic -> the last publisher problem seen
        self._logged: dict[str, float] = {}  # when each kind was last logged
        self._gated = [t for t in topics if t.name in gate]
        self._wait_for = set(wait_for)
        self._waiting_subs = []
        for t in [t for t in topics if t.name not in gate]:
            sub = self._subscribe(t)
            if t.name in self._wait_for:
                self._waiting_subs.append(sub)
        self.poll_gate()

    def poll_gate(self) -> bool:
        """Subscribe the gated topics once every awaited topic has a publisher; True when open."""
        if not self._gated:
            return True
        if not all(s.get_publisher_count() > 0 for s in self._waiting_subs):
            self._matched_since = None
            return False
        now = time.monotonic()
        if self._matched_since is None:
            self._matched_since = now
        if now - self._matched_since >= self.settle:
            for t in self._gated:
                self._subscribe(t)
            self._gated = []
        return not self._gated

    def _subscribe(self, t: TopicSpec):
        # lazy (heavy): ROS
        from rclpy.event_handler import SubscriptionEventCallbacks
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.serialization import deserialize_message

        cls = msg_class(t.msgtype)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=t.depth,
            reliability=ReliabilityPolicy.BEST_EFFORT if t.best_effort else ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if t.transient_local else DurabilityPolicy.VOLATILE)
        handler = self.handlers.get(t.name)

        watched = handler is not None and t.publisher is not None

        last_seq = self.last_seq
        first_seq = self.first_seq
        dropped = self.dropped
        offered = self._offered
        unsure = self.drops_unknown
        holder: dict = {}
        count_drops = t.name not in NO_DROP_COUNT

        def callback(data, info, topic=t.name, cls=cls, handler=handler):
            now = time.time_ns()
            if not self.bag.closed:
                if topic not in offered:  # the first message: the connection gets its publishers' QoS
                    offered.add(topic)
                    self.bag.offer(topic, publishers_qos(self.node.get_publishers_info_by_topic(topic)))
                self.bag.write(topic, now, data)
            # messages the recorder missed: gaps in the publisher's sequence numbers (the rmw's
            # message info), counted while the topic has at most one publisher (numbers are per
            # publisher; the count starts again whenever the set of publishers changed)
            seq = info["publication_sequence_number"]
            if count_drops and seq is not None and topic not in unsure:
                if holder["sub"].get_publisher_count() > 1:
                    # numbers of several publishers interleave: no estimate for this topic from now on
                    # (none left: the last publisher stopped and its queued messages are taken now)
                    unsure.add(topic)
                else:
                    first_seq.setdefault(topic, seq)
                    gap = _follow(last_seq.setdefault(topic, []), seq)
                    if gap:
                        dropped[topic] = dropped.get(topic, 0) + gap
            self.first_ns.setdefault(topic, now)
            self.last_ns[topic] = now
            if handler is not None:
                stream = self.streams.get(topic)
                if stream is not None:
                    why = stream.check(seq, info["source_timestamp"])
                    if why:
                        self._drop(topic, "publishers", why)
                        if not self.bag.closed:
                            self.bag.foreign.append((topic, now, why))
                        return
                try:
                    accepted = handler(deserialize_message(data, cls))
                except Exception as exc:  # noqa: BLE001 - a hostile message never ends the run
                    self._drop(topic, "undecodable or rejected", f"{type(exc).__name__}: {exc}")
                    return
                if accepted and stream is not None:
                    stream.commit(seq)

        events = None
        if watched:  # every publisher (un)match re-reads the topic's publishers at once (PublisherWatch)
            events = SubscriptionEventCallbacks(matched=lambda _info, topic=t.name: self._matched(topic))
        sub = self.node.create_subscription(cls, t.name, callback, qos, raw=True, event_callbacks=events)
        holder["sub"] = sub
        if watched:
            self.watch.watch(t.name, sub, t.publisher)
            self.streams[t.name] = PublisherStream(self.watch, t.name, t.publisher)
        self._subs.append(sub)
        return sub

    def _matched(self, topic: str) -> None:
        """A publisher of ``topic`` matched or left: its publishers are read now, so a second one is
        known (PublisherWatch.foreign_ns) even if it came and went between two messages."""
        if topic in self.watch.rules:
            self.watch.refresh(topic)

    def _drop(self, topic: str, why: str, detail: str) -> None:
        """Count a message not handed to its handler, and log it (:meth:`log_problem`)."""
        key = f"{topic} {why}"
        n = self.rejected.get(key, 0) + 1
        self.rejected[key] = n
        self.log_problem(key, n, detail)

    def log_problem(self, key: str, n: int, detail: str) -> None:
        """Log the ``n``-th message of ``key`` ("<topic> <why>") not used, with what was wrong: at the
        first and then at most every 5 s per key (also for the handlers' own rejections)."""
        now = time.monotonic()
        if n == 1 or now - self._logged.get(key, 0.0) >= 5.0:
            self._logged[key] = now
            self.problems[key] = detail
            topic, why = key.split(" ", 1)
            self.node.get_logger().error(f"{topic}: message not used ({why}: {detail}); {n} so far")

    def destroy(self) -> None:
        for s in self._subs:
            self.node.destroy_subscription(s)
        self._subs = []
