"""Recording the graph's topics into an mcap rosbag2 bag (no rosbag2 on PyPI: rosbags writes it).

Two parts:

- :class:`BagWriter` (ROS-free): a rosbags ``Writer`` (rosbag2 format version 9, mcap storage)
  with the sagg_msgs types registered from their ``.msg`` text, one connection per topic, and
  per-topic message counts.
- :class:`TopicRecorder`: raw (``raw=True``) rclpy subscriptions on an existing node; the CDR bytes
  are written exactly as received (DESIGN §5: they are valid CDR, unlike the output of
  ``rclpy.serialization.serialize_message``), and optional per-topic handlers get the deserialized
  message as well.

Timestamps are the receive times (ns since the epoch), as ``ros2 bag record`` does.
"""
from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

SAGG_MSGS = ("Goal", "CompetenceReport", "Region", "RegionTree", "Sample", "LearnerStatus", "Evaluation")


@dataclass(frozen=True)
class TopicSpec:
    """One recorded topic: name, ROS type (``pkg/msg/Name``), subscription depth, durability."""

    name: str
    msgtype: str
    depth: int = 10000
    transient_local: bool = False
    best_effort: bool = False  # (`sagg record` takes the publishers' reliability)


def find_msg_dir() -> Path:
    """The sagg_msgs ``msg`` folder: the installed share dir (venv prefix, AMENT_PREFIX_PATH) first,
    then the source tree (src/sagg_msgs/msg)."""
    candidates = [Path(sys.prefix) / "share" / "sagg_msgs" / "msg"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "sagg_msgs" / "msg")
    candidates.append(Path(__file__).resolve().parents[2] / "sagg_msgs" / "msg")
    for c in candidates:
        if all((c / f"{name}.msg").is_file() for name in SAGG_MSGS):
            return c
    raise FileNotFoundError("sagg_msgs .msg files not found in: " + ", ".join(str(c) for c in candidates))


def make_typestore(msg_dir: Path | None = None):
    """A rosbags typestore with the ROS 2 Jazzy types plus sagg_msgs (parsed from .msg text)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    msg_dir = msg_dir or find_msg_dir()
    types = {}
    for name in SAGG_MSGS:
        types.update(get_types_from_msg((msg_dir / f"{name}.msg").read_text(), f"sagg_msgs/msg/{name}"))
    store.register(types)
    return store


def _qos(spec: TopicSpec):
    from rosbags.interfaces import (Qos, QosDurability, QosHistory, QosLiveliness, QosReliability,
                                    QosTime)
    zero = QosTime(0, 0)  # rosbag2's "unspecified" (the rmw default)
    return Qos(QosHistory.KEEP_LAST, spec.depth, QosReliability.BEST_EFFORT if spec.best_effort else QosReliability.RELIABLE,
               QosDurability.TRANSIENT_LOCAL if spec.transient_local else QosDurability.VOLATILE,
               zero, zero, QosLiveliness.AUTOMATIC, zero, False)


class BagWriter:
    """An mcap rosbag2 bag (version 9) being written; one connection per topic."""

    def __init__(self, path: str | Path, topics: list[TopicSpec], typestore=None):
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f"bag path '{self.path}' exists already; allowed: a new path")
        self.typestore = typestore or make_typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._conn = {}
        self.counts: dict[str, int] = {}
        self.written = 0  # messages written, all topics
        self.types: dict[str, str] = {}
        try:
            for t in topics:
                self.add_topic(t)
        except Exception:
            self.abort()
            raise
        self.closed = False

    def add_topic(self, t: TopicSpec) -> None:
        """One more connection (a topic first seen after the bag was opened)."""
        self._conn[t.name] = self._writer.add_connection(
            t.name, t.msgtype, typestore=self.typestore, serialization_format="cdr",
            offered_qos_profiles=[_qos(t)])
        self.counts[t.name] = 0
        self.types[t.name] = t.msgtype

    def write(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        self._writer.write(self._conn[topic], int(timestamp_ns), data)
        self.counts[topic] += 1
        self.written += 1

    def close(self) -> None:
        """Write the mcap footer and metadata.yaml (idempotent)."""
        if not self.closed:
            self.closed = True
            self._writer.close()

    def abort(self) -> None:
        self.closed = True
        try:
            self._writer.close()
        except Exception:  # noqa: BLE001 - best effort
            pass

    def topics(self) -> dict[str, dict]:
        return {t: {"type": self.types[t], "count": self.counts[t]} for t in self.counts}


def _msg_class(msgtype: str):
    import importlib
    pkg, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{pkg}.{kind}"), name)


class TopicRecorder:
    """Raw subscriptions on ``node`` writing every message of ``topics`` into ``bag``.

    ``handlers[topic](msg)`` is called (in the executor's thread) with the deserialized message
    after it has been written, for the topics that have one.

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
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.serialization import deserialize_message

        cls = _msg_class(t.msgtype)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=t.depth,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if t.transient_local else DurabilityPolicy.VOLATILE)
        handler = self.handlers.get(t.name)

        def callback(data, topic=t.name, cls=cls, handler=handler):
            now = time.time_ns()
            if not self.bag.closed:
                self.bag.write(topic, now, data)
            self.first_ns.setdefault(topic, now)
            self.last_ns[topic] = now
            if handler is not None:
                handler(deserialize_message(data, cls))

        sub = self.node.create_subscription(cls, t.name, callback, qos, raw=True)
        self._subs.append(sub)
        return sub

    def destroy(self) -> None:
        for s in self._subs:
            self.node.destroy_subscription(s)
        self._subs = []
