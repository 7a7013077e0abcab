"""The plausibility envelope of a measurement stream (docs/safety.md), ROS-free.

A node that receives measurements (joint states, task points) keeps, per stream, a
:class:`StampTracker`: the newest accepted stamp, when it arrived, and how many messages in a row
went back in time. A stamp is

- **accepted** when it is not older than the newest one, and not further ahead of it than the
  time that passed on the receiver's clock since the newest one arrived plus ``future_tolerance``
  (a stamp "in the future" of the stream: a forged or broken message; accepting it would make
  every real message after it look older: the stream would wedge). The first stamp of a stream has
  no reference and is accepted;
- **rejected as out of order** when it is older than the newest one: kept the newest;
- **a clock jump back** when ``resync_after`` messages in a row were older than the newest one
  (a driver or sim-time restart, or the real stream after a forged future stamp got through
  before): the stream is re-synchronised on this stamp and the message accepted.

Why relative to the stream and not to the node's clock: a lockstep bridge stamps with simulation
time, unrelated to the learner's clock; the stream's own stamps plus the receive clock are the
one reference every driver offers. (Sim time may run faster than the wall clock in lockstep: one
settled micro-action or return to rest is at most ``max_settle_steps·timestep`` = 10 s of sim time
with the default arm, so ``future_tolerance``'s default is above that.)

:class:`RejectRun` counts implausible readings in a row for the "hold after a run of rejections"
rule. Both are plain Python, cheap enough for the per-message path.
"""
from __future__ import annotations

ACCEPT, OUT_OF_ORDER, FUTURE, RESYNC = 0, 1, 2, 3


class StampTracker:
    """Newest stamp of one stream (ns) and the future / jump-back rules above."""

    __slots__ = ("future_ns", "resync_after", "newest", "newest_rx", "back_run", "resyncs", "previous")

    def __init__(self, future_tolerance: float, resync_after: int):
        self.future_ns = int(round(future_tolerance * 1e9))
        self.resync_after = int(resync_after)
        self.newest = -1          # newest accepted stamp (ns); -1 = none yet
        self.newest_rx = 0        # receive time (ns, monotonic) of the newest accepted stamp
        self.back_run = 0         # messages in a row older than the newest
        self.resyncs = 0          # clock jumps back detected
        self.previous = -1        # the newest stamp before the last re-synchronisation

    def check(self, stamp: int, rx_ns: int) -> int:
        """The verdict for a message stamped ``stamp`` received at ``rx_ns`` (monotonic ns); an
        ACCEPT or RESYNC verdict has moved the newest stamp to ``stamp``."""
        newest = self.newest
        if stamp >= newest:
            if newest >= 0 and stamp - newest > (rx_ns - self.newest_rx) + self.future_ns:
                return FUTURE
            self.back_run = 0
            if stamp != newest:  # (a re-published state keeps its stamp and its receive time)
                self.newest, self.newest_rx = stamp, rx_ns
            return ACCEPT
        self.back_run += 1
        if self.back_run < self.resync_after:
            return OUT_OF_ORDER
        self.previous = newest
        self.newest, self.newest_rx, self.back_run = stamp, rx_ns, 0
        self.resyncs += 1
        return RESYNC

    def allowed_until(self, rx_ns: int) -> int:
        """The latest stamp accepted at ``rx_ns`` (for log lines)."""
        return self.newest + (rx_ns - self.newest_rx) + self.future_ns

    def describe(self, verdict: int, topic: str, stamp: int, rx_ns: int) -> tuple[str, str]:
        """(field, message) of a verdict other than ACCEPT for a message of ``topic`` stamped
        ``stamp`` received at ``rx_ns``, as :meth:`check` left the tracker: field ``out_of_order``,
        ``future_stamp`` or ``clock_jump_back`` (a reader prefixes its stream's name)."""
        if verdict == OUT_OF_ORDER:
            return "out_of_order", (f"{topic}: header.stamp {stamp} ns is older than the newest one ({self.newest} "
                                    f"ns); kept the newest (after {self.resync_after} in a row: a clock jump back)")
        if verdict == FUTURE:
            return "future_stamp", (f"{topic}: header.stamp {stamp} ns is in the future of the stream; allowed: <= "
                                    f"{self.allowed_until(rx_ns)} ns (newest stamp + time since it arrived + "
                                    "plausibility.future_tolerance); the newest stamp stays")
        return "clock_jump_back", (f"{topic}: clock jumped back from {self.previous} ns to {stamp} ns "
                                   f"({self.resync_after} messages in a row older than the newest; driver or "
                                   "sim-time restart?): re-synchronised on the new stamps")


class RejectRun:
    """Implausible readings in a row of one stream; ``hit`` is True once ``limit`` are reached."""

    __slots__ = ("limit", "run")

    def __init__(self, limit: int):
        self.limit = int(limit)
        self.run = 0

    def reject(self) -> bool:
        self.run += 1
        return self.run >= self.limit

    def ok(self) -> bool:
        """A valid reading: the run ends; True if it had reached the limit (a hold to release)."""
        was = self.run >= self.limit
        self.run = 0
        return was
