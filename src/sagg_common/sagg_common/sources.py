"""Which publisher a message came from, told apart by the publishers' sequence numbers (docs/safety.md).

rclpy (Jazzy) hands a subscription the message info (source timestamp, publication sequence
number) but not the publisher's GID, so a message cannot be named by its publisher. What can be
told apart are the *sources*: a DDS writer numbers its messages 1, 2, 3, ..., so the messages of a
topic form one increasing chain of numbers per publisher. :class:`SourceChains` follows these
chains for one stream (a topic, or the part of a topic a node uses: the learner's joints on
``/joint_states``, where a gripper driver publishing only its own joints is not part of the
stream) and decides, per message:

- **accept**: its chain is the only *live* one (a message within ``grace`` s) and the message
  continues it exactly (its number is the chain's last + 1), or starts the stream's first chain
  (nothing to continue yet; a publisher restarted after its old chain went quiet for ``grace``);
- **gap**: its chain is the only live one but numbers were skipped (messages this subscriber did
  not get, e.g. a full queue; or the first message of another publisher whose numbers are above
  ours). Not taken, not an error: the next message of the chain continues it exactly. A single
  message of a second publisher can therefore never pass as ours unless its number is exactly our
  next one;
- **ambiguous**: more than one chain is live. Every message of the stream is refused while this
  lasts and for ``grace`` s after the last message of the second live chain: which one is real
  cannot be told, and holding is the safe answer (a measured posture from the wrong publisher
  would be the base of a command). It ends by itself.

Messages of the topic that the caller does not take for a reason of its own (another driver's
joints on ``/joint_states``; a value it rejects) are passed to :meth:`skip`: their numbers are no
gap in the chain they belong to (a driver publishing its arm's and its gripper's joints in
separate messages through one publisher stays one exact chain). A skipped number changes no chain
and never makes a message accepted that would not continue its chain once the skipped numbers are
filled in.

A number is assigned to the chain whose last number is the largest below it (the one it can
continue); a number at or below every chain's last starts a new chain (another publisher, or a
restart). Two publishers whose counters are close may swap chains now and then; both chains stay
live, so the stream stays ambiguous, which is all that matters. An rmw without numbers (``None``)
accepts every message (nothing can be told apart).

Plain Python, O(chains) per message (at most ``keep`` chains are kept).
"""
from __future__ import annotations

import collections
import inspect

ACCEPT, GAP, AMBIGUOUS = 0, 1, 2
VERDICT_NAMES = {ACCEPT: "accept", GAP: "gap", AMBIGUOUS: "ambiguous"}
# the message info of a message whose publisher is unknown (a callback called directly): accepted
NO_INFO = {"publication_sequence_number": None, "source_timestamp": None}


class SourceChains:
    """The publisher chains of one stream and the verdict for each message (module docstring)."""

    __slots__ = ("grace", "keep", "last", "rx", "data", "started", "ambiguous_until", "episodes", "gaps",
                 "skipped", "current")
    SKIPPED = 64  # the numbers of the last messages not taken that are remembered (a gap of more is a gap)

    def __init__(self, grace: float, keep: int = 8):
        if not grace > 0:
            raise ValueError(f"grace: got {grace!r}; allowed: a number > 0 (seconds)")
        self.grace = float(grace)
        self.keep = int(keep)
        self.last: list[int] = []    # per chain: its last number
        self.rx: list[float] = []    # per chain: when its last message arrived
        self.data: list = []         # per chain: the caller's (e.g. a recorder's acknowledged count)
        self.started = False         # a chain was ever accepted (the stream's first one is taken as is)
        self.ambiguous_until = -1.0  # the stream is ambiguous until then (receive clock)
        self.episodes = 0            # how often the stream became ambiguous
        self.gaps = 0                # messages not taken for a gap
        self.skipped: collections.deque[int] = collections.deque(maxlen=self.SKIPPED)  # (skip)
        self.current = -1            # the chain of the last message classified (-1: none, or no numbers)

    def assign(self, seq: int, now: float) -> tuple[int, bool, bool]:
        """The chain of a message numbered ``seq`` received at ``now`` (updated), whether the message
        continues it exactly, and whether it starts a new chain. Of the chains it can continue, the
        one whose last number is the largest below ``seq``; of equal ones, the one heard from last
        (a live chain whose numbers pass those of a silent one keeps its messages)."""
        last, rx = self.last, self.rx
        best = -1
        for i, t in enumerate(last):
            if t < seq and (best < 0 or t > last[best] or (t == last[best] and rx[i] > rx[best])):
                best = i
        if best >= 0:
            exact = seq == last[best] + 1 or self._skipped_between(last[best], seq)
            last[best], rx[best] = seq, now
            return best, exact, False
        if len(last) >= self.keep:  # a new chain: forget the one heard from longest ago
            oldest = rx.index(min(rx))
            del last[oldest], rx[oldest], self.data[oldest]
        last.append(seq)
        rx.append(now)
        self.data.append(None)
        return len(last) - 1, False, True

    def skip(self, seq: int | None) -> None:
        """A message numbered ``seq`` that the caller does not take for a reason of its own (not
        part of the stream, or a rejected value): its number is no gap (module docstring)."""
        if seq is not None:
            self.skipped.append(seq)

    def _skipped_between(self, last: int, seq: int) -> bool:
        """Whether every number strictly between ``last`` and ``seq`` was skipped."""
        missing = seq - last - 1
        if not 0 < missing <= len(self.skipped):
            return False
        skipped = set(self.skipped)
        return all(n in skipped for n in range(last + 1, seq))

    def classify(self, seq: int | None, now: float) -> int:
        """The verdict for a message numbered ``seq`` received at ``now`` (any monotonic clock, s)."""
        if seq is None:
            self.current = -1
            return ACCEPT
        self.current, exact, new = self.assign(seq, now)
        if new and not self.started:
            exact = True  # the stream's first chain: nothing to continue yet
        grace = self.grace
        live = sorted(t for t in self.rx if now - t <= grace)
        if len(live) > 1:
            if now > self.ambiguous_until:
                self.episodes += 1
            # until every chain but one has been quiet for grace
            self.ambiguous_until = max(self.ambiguous_until, live[-2] + grace)
            return AMBIGUOUS
        if now <= self.ambiguous_until:
            return AMBIGUOUS  # (the other chain spoke less than grace ago)
        if not exact:
            self.gaps += 1
            return GAP
        self.started = True
        return ACCEPT

    def tag(self, value) -> None:
        """Attach ``value`` to the chain of the last message classified (e.g. "found to be another
        run's"): it stays with the chain while the chain lives. Without numbers: nothing."""
        if self.current >= 0:
            self.data[self.current] = value

    def tagged(self):
        """The value attached to the chain of the last message classified (None: none)."""
        return self.data[self.current] if self.current >= 0 else None

    def ambiguous(self, now: float) -> bool:
        """Whether the stream is (still) ambiguous at ``now`` (for a timer: the hold ends by itself)."""
        return now <= self.ambiguous_until

    def live(self, now: float) -> int:
        """Chains heard from within ``grace`` s."""
        return sum(1 for t in self.rx if now - t <= self.grace)


class _WithInfo:
    """A subscription callback taking ``(message, message info)`` whichever executor runs it."""

    # A two-argument signature makes rclpy deliver the message info (Subscription.callback);
    # Jazzy's EventsExecutor then calls the callback with ONE argument, the (message, info) tuple,
    # where the other executors call it with two: both forms are accepted.
    __signature__ = inspect.Signature([
        inspect.Parameter("msg", inspect.Parameter.POSITIONAL_ONLY),
        inspect.Parameter("info", inspect.Parameter.POSITIONAL_ONLY)])
    __slots__ = ("handler",)

    def __init__(self, handler):
        self.handler = handler

    def __call__(self, *args):
        if len(args) == 1:
            args = args[0]
        return self.handler(args[0], args[1])


def with_message_info(handler):
    """``handler(msg, info)`` as a subscription callback for any rclpy executor; ``info`` is rclpy's
    message-info dict (``publication_sequence_number``, ``source_timestamp``, ...)."""
    return _WithInfo(handler)
