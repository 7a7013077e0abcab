"""``sagg record [--out DIR] [--params FILE]``: the recorder alone, for graphs started with
``ros2 run`` / ``ros2 launch`` (or any driver), into an mcap rosbag2 bag.

The topic set is ``sagg run``'s (:func:`recorded_topics`: the ``/sagg`` topics, ``/joint_states``,
the commands and the task-space topic named by the parameter file, ``/clock``, ``/sagg/markers``).
A topic is subscribed when its first publisher appears, with the publishers' QoS (reliable unless
one of them is best effort; transient_local when all of them are, so the latched
``/sagg/regions``, ``/sagg/markers`` and the learner's ``/sagg/competence`` history arrive even when
the recorder starts late), and its connection is added to the bag with that QoS. Raw CDR is written
as received. Ctrl-C (SIGINT) or SIGTERM stops it: subscriptions destroyed, bag closed (mcap footer and
``metadata.yaml``), counts printed; exit code 0.
"""
from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

from sagg_common.params import ConfigError

from .markers import MarkerView, MARKER_TOPIC
from .recorder import BagWriter, TopicSpec, _msg_class
from .topics import graph_topics
from .recorder import publishers_qos as offered_qos


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
    return TopicSpec(spec.name, spec.msgtype, spec.depth, latched, best_effort)


class LiveRecorder:
    """Subscribes each topic of ``topics`` once it has a publisher of the expected type (checked by
    :meth:`poll`), with the publishers' QoS, writing raw CDR into ``bag``; ``handlers[topic](msg)``
    gets the deserialized message too."""

    def __init__(self, node, bag: BagWriter, topics: list[TopicSpec], handlers: dict | None = None):
        self.node, self.bag, self.handlers = node, bag, handlers or {}
        self.waiting = {t.name: t for t in topics}
        self.qos: dict[str, TopicSpec] = {}
        self.rejected: dict[str, int] = {}  # topic -> messages the handler could not use (recorded all the same)
        self._subs = []

    def poll(self) -> None:
        for name, spec in list(self.waiting.items()):
            infos = [i for i in self.node.get_publishers_info_by_topic(name) if i.topic_type == spec.msgtype]
            if not infos:
                continue
            del self.waiting[name]
            self._subscribe(publishers_qos(infos, spec), infos)

    def _subscribe(self, t: TopicSpec, infos=()) -> None:
        # lazy (heavy): ROS
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.serialization import deserialize_message
        cls = _msg_class(t.msgtype)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=t.depth,
                         reliability=ReliabilityPolicy.BEST_EFFORT if t.best_effort else ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if t.transient_local else DurabilityPolicy.VOLATILE)
        self.bag.add_topic(t)
        # the bag's offered_qos_profiles: the publishers' own, as `ros2 bag record` writes them
        self.bag.offer(t.name, offered_qos(infos))
        self.qos[t.name] = t
        handler = self.handlers.get(t.name)

        def callback(data, topic=t.name):
            if not self.bag.closed:
                self.bag.write(topic, time.time_ns(), data)
            if handler is not None:
                try:
                    handler(deserialize_message(data, cls))
                except Exception as exc:  # noqa: BLE001 - a hostile message never ends the recording
                    n = self.rejected[topic] = self.rejected.get(topic, 0) + 1
                    if n == 1 or n % 1000 == 0:
                        self.node.get_logger().error(f"{topic}: message not used by the live view "
                                                     f"({type(exc).__name__}: {exc}); {n} so far")

        self._subs.append(self.node.create_subscription(cls, t.name, callback, qos, raw=True))

    def destroy(self) -> None:
        for s in self._subs:
            self.node.destroy_subscription(s)
        self._subs = []


def record(out: str | Path, params_file: str | Path | None = None, domain_id: int | None = None,
           duration: float | None = None, progress: bool = True, markers: bool = True) -> dict:
    """Record until Ctrl-C / SIGTERM (or ``duration`` s); returns ``{"path", "topics", "interrupted"}``.
    ``markers``: also publish the live view on /sagg/markers (:mod:`.markers`) from what is recorded."""
    # lazy (heavy): ROS
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
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
    node = rclpy.create_node("sagg_record", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    out.parent.mkdir(parents=True, exist_ok=True)
    bag = BagWriter(out, [])
    view = None
    handlers = {}
    if markers:
        view = MarkerView(node, topics)
        handlers = view.handlers()
    rec = LiveRecorder(node, bag, topics, handlers)
    t0 = last = time.monotonic()
    try:
        while not stop and (duration is None or time.monotonic() - t0 < duration):
            rec.poll()
            executor.spin_once(timeout_sec=0.05)
            for _ in range(1000):  # drain what is queued
                before = bag.written
                executor.spin_once(timeout_sec=0)
                if bag.written == before:
                    break
            if view is not None:
                view.maybe_publish()
            now = time.monotonic()
            if progress and now - last >= 2.0:
                last = now
                print(f"\rrecording {out}: {bag.written:,} messages on {len(rec.qos)} topics "
                      f"({len(rec.waiting)} without publisher yet)", end="", file=sys.stderr, flush=True)
    finally:
        rec.destroy()
        bag.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        for s, h in old.items():
            signal.signal(s, h)
    topics_out = bag.topics()
    if progress:
        print(f"\nbag closed: {out} ({bag.written:,} messages: "
              + ", ".join(f"{t} {v['count']}" for t, v in sorted(topics_out.items())) + ")", file=sys.stderr)
    return {"path": str(out), "topics": topics_out, "interrupted": bool(stop),
            "qos": {t: {"transient_local": s.transient_local, "best_effort": s.best_effort} for t, s in rec.qos.items()}}


def default_out() -> Path:
    return Path("runs") / f"record-{time.strftime('%Y%m%d-%H%M%S')}-{os.getpid()}"
