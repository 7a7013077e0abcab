"""One expected publisher per input topic (docs/safety.md), with rclpy's public graph API.

rclpy (Jazzy) gives a subscription callback's message info without the publisher's GID, so a
message cannot be attributed to its publisher; what can be checked is who publishes on the topic:
``Node.get_publishers_info_by_topic`` (node name, namespace, endpoint GID, QoS). A
:class:`PublisherWatch` keeps, per watched topic, the rule "at most one publisher, and (if given)
from the node named so", re-reads the publishers only when the subscription's publisher count
changes (``Subscription.get_publisher_count``, one cheap call per message), and names the
publishers of a topic that breaks the rule (node name and GID) for the log, ``/diagnostics`` and
the hold reason. While a topic breaks it, its messages are rejected: they may come from either
publisher.
"""
from __future__ import annotations

import time

from .sources import SourceChains


# the graph cache's name for an endpoint whose node it has not learnt yet (for a moment after discovery)
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"


def describe(info) -> str:
    """``node /ns/name (gid 0123abcd…)`` for a ``TopicEndpointInfo``."""
    ns = info.node_namespace.rstrip("/")
    gid = bytes(info.endpoint_gid).hex()
    return f"node {ns}/{info.node_name} (gid {gid})"


def publisher_problem(infos, expected_node: str | None) -> str:
    """What is wrong with the publishers ``infos`` of one topic ('' if nothing): more than one, or
    one from another node than ``expected_node`` (None: any node)."""
    if len(infos) > 1:
        return f"{len(infos)} publishers ({'; '.join(describe(i) for i in infos)}); allowed: one"
    if infos and expected_node is not None and infos[0].node_name not in (expected_node, UNKNOWN_NODE):
        return f"publisher {describe(infos[0])}; allowed: node {expected_node} only"
    return ""


class PublisherWatch:
    """The publishers of some topics subscribed by ``node``: :meth:`problem` per message."""

    def __init__(self, node):
        self.node = node
        self.rules: dict[str, tuple] = {}      # topic -> (publisher count function, expected node or None)
        self._count: dict[str, int] = {}       # publisher count when the problem was last computed
        self.problems: dict[str, str] = {}     # topic -> current problem ('' = fine)
        # topic -> when (time.time_ns) another publisher was last known on it: while it was, or when
        # it was seen gone (0: never); messages sent before then may be that publisher's
        self.foreign_ns: dict[str, int] = {}

    def watch(self, topic: str, subscription=None, expected_node: str | None = None) -> None:
        """Watch ``topic``; ``subscription``: this node's subscription to it (its publisher count is
        the cheapest), else ``Node.count_publishers`` is used (e.g. a topic the node publishes)."""
        count = (subscription.get_publisher_count if subscription is not None
                 else (lambda: self.node.count_publishers(topic)))
        self.rules[topic] = (count, expected_node)
        self._count[topic] = -1
        self.problems[topic] = ""
        self.foreign_ns[topic] = 0

    def problem(self, topic: str) -> str:
        """The topic's current publisher problem ('' if none); re-read only on a count change."""
        count, expected = self.rules[topic]
        n = count()
        if n != self._count[topic]:
            infos = self.node.get_publishers_info_by_topic(topic)
            # a publisher whose node is not known yet: read again at the next message
            self._count[topic] = -1 if any(i.node_name == UNKNOWN_NODE for i in infos) else n
            was = self.problems[topic]
            self.problems[topic] = publisher_problem(infos, expected)
            if was or self.problems[topic]:
                self.foreign_ns[topic] = time.time_ns()
        return self.problems[topic]

    def refresh(self, topic: str) -> str:
        """Re-read the topic's publishers now (a publisher may have been replaced at equal count)."""
        self._count[topic] = -1
        return self.problem(topic)

    def all_problems(self) -> dict[str, str]:
        """Every watched topic with a problem, re-read now (for a timer: names may change at equal count)."""
        return {t: p for t in self.rules if (p := self.refresh(t))}


class PublisherStream:
    """Messages of a topic accepted only from its expected publisher's stream (docs/safety.md).

    rclpy gives no publisher GID per message, but it gives the publisher's sequence number
    (``publication_sequence_number`` of the message info; +1 per message of one writer). The
    stream of the expected publisher is followed by that number: a message continues it when its
    number is the next one; a gap is accepted only while the expected node is the topic's only
    publisher and from a message sent after any other one was last seen (then messages were
    missed, not forged); a number at or below the last one comes from
    another writer (dropped, counted) unless the expected node's publisher was replaced (a restart:
    the stream starts again). A message is *committed* (its number becomes the last one) by the
    caller once its content is accepted too, so a rejected message never moves the stream.
    An rmw without sequence numbers (``None``) leaves the content checks alone.

    The numbers of the rejected messages are followed too, as the other publishers' streams
    (:attr:`others`, chains as :class:`~sagg_common.sources.SourceChains` follows them): a replay
    (``ros2 bag play``) numbers its messages from 1, so while the
    expected publisher is silent (a learner holding for the replay's joint states) the replay's
    numbers climb to the expected stream's last one, and its next message would continue the
    expected stream exactly. A message whose number continues both is refused (it may be either);
    afterwards the replay's numbers are above the expected stream's and never continue it, and the
    expected publisher's own next message continues its stream again. (If the expected publisher
    then publishes faster than the other and catches up with it, its messages stay refused, as
    gaps, until the other leaves the topic.)
    """

    OTHERS = 8  # the other publishers' streams followed (the one heard from longest ago is forgotten)

    def __init__(self, watch: PublisherWatch, topic: str, expected_node: str):
        self.watch, self.topic, self.expected = watch, topic, expected_node
        self.last = 0
        self.gids: tuple | None = None   # the expected node's publisher GIDs when the stream (re)started
        self.gaps = 0                    # messages missed by this subscriber (numbers skipped)
        self.restarts = 0
        self.others = self._new_others()  # the other publishers' streams (the rejected messages' numbers)

    def _expected_gids(self) -> tuple | None:
        infos = self.watch.node.get_publishers_info_by_topic(self.topic)
        if len(infos) != 1 or infos[0].node_name != self.expected:
            return None
        return (bytes(infos[0].endpoint_gid),)

    def check(self, seq, source_ns: int | None = None) -> str:
        """'' if a message numbered ``seq`` (sent at ``source_ns``, the message info's
        ``source_timestamp``) may continue the stream, else why not. A gap is accepted only from a
        message sent after any other publisher was last known on the topic: a message still queued
        from a publisher that has left since (the topic looks fine again) has a later number than
        ours, and taking it would move the stream past every real message (seen in the soak: a
        forger's number 27,312 after our 4,814 stopped every real sample)."""
        why = self._why(seq, source_ns)
        if why:
            self.others.assign(seq, time.monotonic())
        return why

    def _why(self, seq, source_ns: int | None) -> str:
        if seq is None:
            return ""
        if seq == self.last + 1:
            if self.last and self.last in self.others.last:
                return (f"publisher sequence number {seq} continues the expected publisher's stream and "
                        f"another's (both stood at {self.last}): which one sent it cannot be told")
            return ""
        if seq > self.last:
            if self.watch.problem(self.topic):
                return (f"publisher sequence number {seq} after {self.last} while the topic has "
                        f"{self.watch.problems[self.topic]}")
            seen = self.watch.foreign_ns.get(self.topic, 0)
            if source_ns is not None and source_ns <= seen:
                return (f"publisher sequence number {seq} after {self.last}, sent (source time {source_ns} ns) "
                        f"before another publisher on the topic was last seen ({seen} ns)")
            return ""
        gids = self._expected_gids()
        if gids is not None and gids != self.gids and self.gids is not None:
            return ""  # the expected node's publisher was replaced: its stream starts again
        return (f"publisher sequence number {seq}, not after {self.last}: another publisher's message "
                f"(topic publishers: {self.watch.refresh(self.topic) or 'as expected'})")

    @classmethod
    def _new_others(cls) -> SourceChains:
        # only its chains are used (assign: the one a number continues, or a new one), not its verdicts
        return SourceChains(grace=1.0, keep=cls.OTHERS)

    def commit(self, seq) -> None:
        if seq is None:
            return
        if seq <= self.last:  # a restarted publisher: its stream starts again, the others' are forgotten
            self.restarts += 1
            self.others = self._new_others()
            self.gids = self._expected_gids()
        elif seq > self.last + 1 and self.last:
            self.gaps += seq - self.last - 1
        if self.gids is None:
            self.gids = self._expected_gids()
        self.last = seq
