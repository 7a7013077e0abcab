"""What ``sagg record`` knows of the graph it records, without ROS: the samples it may acknowledge
(the learner's backpressure) and the messages the nodes published that are not in its bag.

- Acknowledgement: the samples accepted contiguously (:meth:`RunState.accept_sample`, the check
  every recorder of a graph run uses) from the first sample of the current learner process this
  recorder received (index 0 when it was there from the start; later when it joined a running graph
  or the learner was resumed). A sample with a lower index than the last one accepted starts a new
  learner process (a fresh one publishes from 0; a resumed one re-publishes from its last
  checkpoints; one learner publishes its samples in index order), whose stream the acknowledgement
  follows from there.
- Accounting: the nodes announce how many messages they published per topic on ``/diagnostics``
  (values ``published <topic>``; the learner's: /sagg/sample, /sagg/competence, its commands) and the
  learner its samples and reports on ``/sagg/status``. :meth:`RecordAccount.losses` compares them with
  the bag, the publishers' sequence gaps and the messages published before the recorder's
  subscription matched (which are not counted as lost: the recorder was not there yet).
"""
from __future__ import annotations

from typing import Callable

from .run_state import RunState, finite_sample_problem

PUBLISHED_KEY = "published "  # a node's /diagnostics value "published <topic>" (ros_params.run_node logs the same)
MAX_COUNT = 2 ** 63 - 1


class RecordAccount:
    """The acknowledgement and the loss count of one recording of ``topics`` (the recorded names).

    ``problem``: what is wrong with a sample (:meth:`RunState.accept_sample`'s argument; default
    the next index and finite values). ``on_reject(key, count, detail)``: called at every input
    not used (a bad announcement or sample), for the log."""

    def __init__(self, topics, problem: Callable | None = None,
                 on_reject: Callable[[str, int, str], None] | None = None):
        self.topics = frozenset(topics)
        self.st = RunState(on_reject=on_reject)
        self.problem = problem or finite_sample_problem
        self.start: int | None = None       # first index of the current learner process's stream
        self.last_index: int | None = None  # index of the last sample accepted
        self.processes = 0                  # learner processes whose stream was followed
        self.first_index: int | None = None  # index of the first sample received (> 0: the bag lacks 0..it-1)
        self.report_seq: int | None = None  # seq of the last competence report handed in
        # (node, topic) -> the last count announced; what earlier processes of that node announced
        self.announced: dict[tuple[str, str], int] = {}
        self.announced_before: dict[tuple[str, str], int] = {}

    # ------------------------------------------------------------------ handlers
    def on_sample(self, m) -> bool | None:
        """/sagg/sample: True when accepted (the acknowledgement moves on)."""
        index = int(m.index)
        if self.first_index is None:
            self.first_index = index
        if self.start is None or (self.last_index is not None and index < self.last_index):
            self.start = index
            self.processes += 1
            self.st.start_samples_at(index)
        ok = self.st.accept_sample(m, self.problem)
        if ok:
            self.last_index = index
        return ok

    def on_report(self, m) -> bool:
        """/sagg/competence: the last report's seq (the learner's status says how many it sent)."""
        self.report_seq = int(m.seq)
        return True

    def on_status(self, m) -> bool:
        return self.st.on_status(m)

    def on_diagnostics(self, msg) -> None:
        """/diagnostics: every ``published <topic>`` value of a recorded topic, per announcing node
        (``hardware_id``, else the status name). A count below the node's previous one is a new
        process of that node: the earlier one's count is kept. A value that is not an integer in
        [0, 2^63) is counted and logged (``on_reject``) and changes nothing."""
        for status in msg.status:
            node = status.hardware_id or status.name
            for kv in status.values:
                if not kv.key.startswith(PUBLISHED_KEY):
                    continue
                topic = kv.key[len(PUBLISHED_KEY):]
                if topic not in self.topics:
                    continue
                try:
                    n = int(kv.value)
                except ValueError:
                    n = -1
                if not 0 <= n <= MAX_COUNT:
                    self.st.reject("/diagnostics", "published count not a count",
                                   f"{node}: '{kv.key}' = {kv.value[:40]!r}; allowed: an integer in [0, 2^63)")
                    continue
                key = (node, topic)
                last = self.announced.get(key)
                if last is not None and n < last:
                    self.announced_before[key] = self.announced_before.get(key, 0) + last
                self.announced[key] = n

    # ------------------------------------------------------------------ results
    def acknowledged(self) -> int | None:
        """The value for /sagg/recorded (None until a sample came:
        :class:`~sagg_bringup.bags.recorder.Acknowledger`)."""
        return None if self.start is None else self.st.samples

    def published(self) -> dict[str, int]:
        """Per topic, the messages the nodes announced as published (all their processes)."""
        out: dict[str, int] = {}
        for (node, topic), n in self.announced.items():
            out[topic] = out.get(topic, 0) + n + self.announced_before.get((node, topic), 0)
        return out

    def before(self, received: dict[str, int], first_seq: dict[str, int]) -> dict[str, int]:
        """Per topic, the messages published before the recorder's subscription matched: the
        publication number of the first one received minus 1 (``first_seq``), or all those
        announced of a topic of which nothing was received."""
        out = {t: int(s) - 1 for t, s in first_seq.items() if s > 1}
        for topic, n in self.published().items():
            if not received.get(topic, 0) and n > 0:
                out[topic] = n
        return dict(sorted(out.items()))

    def losses(self, received: dict[str, int], before: dict[str, int], gaps: dict[str, int]) -> dict[str, int]:
        """Per topic (those with a loss only), the messages published while the recorder was
        subscribed that are not in the bag: at least the publishers' sequence ``gaps``, the
        announced counts beyond what was ``received`` and what was published ``before`` the
        subscription matched, and the learner's last status (samples, reports) beyond the last
        sample / report received (a tail has no gap to show)."""
        lost = {t: int(n) for t, n in gaps.items() if n > 0}
        for topic, n in self.published().items():
            if received.get(topic, 0):  # (nothing received: all published before: :meth:`before`)
                lost[topic] = max(lost.get(topic, 0), n - received[topic] - before.get(topic, 0))
        status = self.st.status
        if status is not None:
            tails = {"/sagg/sample": status["samples"] - self.st.samples if self.start is not None else 0,
                     "/sagg/competence": (status["reports"] - self.report_seq if self.report_seq is not None
                                          else 0)}
            for topic, n in tails.items():
                lost[topic] = max(lost.get(topic, 0), n)
        return {t: n for t, n in sorted(lost.items()) if n > 0}
