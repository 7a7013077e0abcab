"""The recorders a learner waits for (backpressure, ``recorder_max_lag``), ROS-free.

A recorder (``sagg run``'s, ``sagg record``) acknowledges on ``/sagg/recorded`` (std_msgs/UInt64)
how many samples it has recorded from index 0. Several may record at once; each is told apart by
its publisher's sequence numbers (:class:`~sagg_common.sources.SourceChains`: one chain per
publisher). The learner waits for the slowest recorder that is *alive*: one that acknowledged,
and moved its count, within ``timeout`` seconds. So a recorder that stopped or died, or a stray
publisher repeating one number, never stalls learning, and a fast recorder never hides a slow
one (the largest acknowledgement used to count).
"""
from __future__ import annotations

from sagg_common.sources import SourceChains


class RecorderAcks:
    """Acknowledgements per recorder; :meth:`slowest` is what the learner waits on."""

    def __init__(self, timeout: float):
        self.timeout = float(timeout)
        # (grace only decides "live" here; chains are never ambiguous for this use)
        self.chains = SourceChains(grace=self.timeout)
        self.recorders_seen = 0

    def ack(self, seq: int | None, count: int, now: float) -> None:
        """An acknowledgement ``count`` from the publisher numbering it ``seq``, received at ``now``
        (monotonic s). ``seq`` None (an rmw without numbers): all acknowledgements are one recorder's."""
        chains = self.chains
        if seq is None:
            i = 0 if chains.last else chains.assign(1, now)[0]
            chains.rx[i] = now
        else:
            i, _, new = chains.assign(seq, now)
            self.recorders_seen += new
        entry = chains.data[i]
        if entry is None or count > entry[0]:
            # (largest count of this recorder, when it last moved, whether its going stale was said)
            chains.data[i] = (count, now, False)

    def _alive(self, d, t: float, now: float) -> bool:
        return now - t <= self.timeout and now - d[1] <= self.timeout

    def slowest(self, now: float) -> int | None:
        """The smallest count among the recorders alive at ``now`` (None: none is alive)."""
        counts = [d[0] for d, t in zip(self.chains.data, self.chains.rx) if d is not None and self._alive(d, t, now)]
        return min(counts) if counts else None

    def newly_stale(self, now: float) -> list[int]:
        """The counts of the recorders no longer waited for since the last call (each said once,
        until it moves its count again)."""
        out = []
        for i, (d, t) in enumerate(zip(self.chains.data, self.chains.rx)):
            if d is not None and not d[2] and not self._alive(d, t, now):
                self.chains.data[i] = (d[0], d[1], True)
                out.append(d[0])
        return out

    def largest(self) -> int:
        """The largest count any recorder acknowledged (for /diagnostics)."""
        return max((d[0] for d in self.chains.data if d is not None), default=0)
