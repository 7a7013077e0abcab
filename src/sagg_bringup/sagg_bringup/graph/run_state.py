"""What a graph run's orchestrator learns from the /sagg topics, each message checked (docs/safety.md)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from sagg_common.diagnostics import goal_problem, report_problem, sample_problem
from sagg_common.report_kinds import KIND_GOAL, KIND_NAMES
from sagg_goal_generator.core import MODE_NAMES
from sagg_low_level.holds import PAUSED_BY_SERVICE


HELD_WIDTH = 72  # characters of the hold reason on the progress line


@dataclass
class RunState:
    """What the orchestrator learns from the topics."""

    samples: int = 0
    sample_t0: float | None = None
    sample_t1: float | None = None
    status: dict | None = None
    goals: dict[int, dict] = field(default_factory=dict)
    goal_competence: dict[int, float] = field(default_factory=dict)
    report_ma: dict[int, int] = field(default_factory=dict)
    reports: int = 0
    report_t: float = field(default_factory=time.perf_counter)  # last /sagg/competence arrival
    last_regions: Any = None
    last_competence: float = float("nan")
    last_error: float = float("nan")
    # messages missing from sequences the recorder can check (seq/index not consecutive)
    gaps: dict[str, int] = field(default_factory=lambda: {"/sagg/sample": 0, "/sagg/competence": 0,
                                                          "/sagg/goal": 0})
    status_rate: bool = True  # keep /sagg/status's micro_actions_per_second in `status`
    # messages from the expected publisher that were rejected, by "<topic> <problem>" (docs/safety.md)
    rejected: dict[str, int] = field(default_factory=dict)
    task_lower: Any = None  # Y, for checking goals (None: not checked)
    task_upper: Any = None
    window: int = 10000     # a goal or report seq further than this beyond the last is rejected
    # called with ("<topic> <kind>", count so far, what was wrong) at every rejection (the log)
    on_reject: Callable[[str, int, str], None] | None = None

    def reject(self, topic: str, kind: str, detail: str = "") -> None:
        """Count a message not used (``rejected``) and pass it on to ``on_reject``."""
        key = f"{topic} {kind}"
        n = self.rejected[key] = self.rejected.get(key, 0) + 1
        if self.on_reject is not None:
            self.on_reject(key, n, detail or kind)

    def accept_sample(self, m, problem: Callable[[Any, int], str], republished_ok: bool = True) -> bool | None:
        """/sagg/sample, one check for every recorder (``sagg run``'s graph, ``--driver external``,
        the synergy graph): ``problem(m, expected)`` names what is wrong ('' if nothing: the index
        ``expected`` and a plausible content, e.g. :func:`sagg_common.diagnostics.sample_problem`);
        a bad sample is dropped and counted, so a forged one never takes the real one's index. A
        sample below the next index is a re-publication by a resumed learner (same values) and is
        ignored when ``republished_ok``, if its content is plausible (checked at its own index; an
        implausible one is counted as the bad input it is). True = used (the caller stores it; the
        topic's publisher stream moves on), None = not used. Stamps the sample rate's first and
        last arrival."""
        index = int(m.index)
        if republished_ok and index < self.samples:
            why = problem(m, index)
            if why:
                self.reject("/sagg/sample", "content rejected (an earlier index)", f"index {index}: {why}")
            return None
        why = problem(m, self.samples)
        if why:
            self.reject("/sagg/sample", "index or content rejected", why)
            return None
        now = time.perf_counter()
        if self.sample_t0 is None:
            self.sample_t0 = now
        self.sample_t1 = now
        self.samples += 1
        return True

    def start_samples_at(self, index: int) -> None:
        """The next sample expected is ``index``: a recorder that joined a running graph, or a new
        learner process (0 when fresh, its first re-published sample when resumed), follows the
        stream from there (:meth:`accept_sample` checks the rest as usual)."""
        self.samples = int(index)

    def arm_sample_check(self, learner_params: dict, task_dim: int) -> Callable[[Any], str]:
        """The ``problem`` of :meth:`accept_sample` for an evolving-context arm's /sagg/sample: the
        next index and a plausible content (:func:`sagg_common.diagnostics.sample_problem` with the
        learner's joint limits and plausibility tolerance)."""
        lp = learner_params
        lo, hi, tol = lp["joint_limits.lower"], lp["joint_limits.upper"], lp["plausibility.joint_tolerance"]
        return lambda m, expected: sample_problem(int(m.index), expected, m.alpha, m.delta_alpha, m.delta_y,
                                                  lo, hi, task_dim, tol)

    def on_goal(self, m) -> None:
        """/sagg/goal (keyed by seq)."""
        if int(m.seq) in self.goals:
            return  # published again (a repeated goal request after a generator restart)
        if not 0 < int(m.seq) <= len(self.goals) + self.window:
            self.reject("/sagg/goal", "seq out of window",
                        f"seq {int(m.seq)}; allowed: 1..{len(self.goals) + self.window}")
            return
        why = goal_problem(m.position, self.task_lower, self.task_upper)[1] if self.task_lower is not None else ""
        if why:
            self.reject("/sagg/goal", "position not finite or outside Y", f"position {why}")
            return
        if int(m.seq) != len(self.goals) + 1:
            self.gaps["/sagg/goal"] += 1
        self.goals[int(m.seq)] = {"seq": int(m.seq), "position": list(m.position), "mode": int(m.mode),
                                  "mode_name": MODE_NAMES.get(int(m.mode), str(m.mode)),
                                  "after_report": int(m.after_report)}
        return True

    def on_report(self, m) -> None:
        """/sagg/competence: the micro-actions at each report, the competence of each goal."""
        self.report_t = time.perf_counter()  # the stream moves (a resumed learner's re-publications too)
        if int(m.seq) <= self.reports:
            return  # republished by a resumed learner
        if int(m.seq) > self.reports + self.window:
            self.reject("/sagg/competence", "seq out of window",
                        f"seq {int(m.seq)}; allowed: up to {self.reports + self.window}")
            return
        target = m.target if len(m.target) else m.reached
        dim = len(self.task_lower) if self.task_lower is not None else len(m.reached)
        why = report_problem(int(m.kind), target, float(m.competence), dim, KIND_NAMES)
        if why:
            self.reject("/sagg/competence", "invalid content", why)
            return
        if int(m.seq) != self.reports + 1:
            self.gaps["/sagg/competence"] += 1
        self.reports += 1
        self.report_ma[int(m.seq)] = int(m.micro_actions)
        if m.kind == KIND_GOAL:
            self.goal_competence[int(m.goal_seq)] = float(m.competence)
            self.last_competence = float(m.competence)
        return True

    def on_regions(self, m) -> bool:
        self.last_regions = m
        return True

    def on_status(self, m) -> bool:
        self.status = _status_dict(m, self.status_rate)
        return True

    def paused_by_user(self) -> bool:
        """Whether the learner's last status says the user paused it (``/sagg/pause``): a pause is
        no stall, however long, whatever else holds meanwhile (a recorder catching up, a driver
        restarted during the pause); the stall clock starts again at its release, and a hold still
        set then ends the run after the stall timeout."""
        s = self.status
        return bool(s and s.get("paused") and PAUSED_BY_SERVICE in s.get("pause_reason", "").split("; "))

    def unrecorded(self) -> dict[str, int]:
        """What the learner's last /sagg/status counts as published and the recorder has not taken:
        {"/sagg/sample": n, "/sagg/competence": n}, topics with n > 0 only."""
        if self.status is None:
            return {}
        missing = {"/sagg/sample": self.status["samples"] - self.samples,
                   "/sagg/competence": self.status.get("reports", 0) - self.reports}
        return {t: n for t, n in missing.items() if n > 0}

    def all_recorded(self, now: float, patience: float) -> bool:
        """Whether the recorder has taken every sample and competence report the learner's last
        status counts, so the nodes may stop. Reports are not held back by the learner (samples
        are, by the recorder's acknowledgements): a recorder that fell behind on /sagg/competence,
        e.g. behind a resumed learner's re-published history on a loaded machine, takes them at
        the reliable transport's repair rate, and they would be lost with the learner's process.
        They are waited for while they keep coming; after ``patience`` s without one the run
        ends and the rest are counted as dropped (:meth:`unrecorded`)."""
        if self.status is None or self.samples < self.status["samples"]:
            return False
        return self.reports >= self.status.get("reports", 0) or now - self.report_t >= patience

    def progress(self) -> dict:
        """The progress bar's fields; ``held``: why the learner holds, shortened (the full text is
        in /sagg/status, /diagnostics and the learner's log)."""
        out = {"goals": len(self.goals),
               "regions": len(self.last_regions.regions) if self.last_regions is not None else 1,
               "competence": self.last_competence, "error": self.last_error}
        if self.status is not None and self.status.get("refused"):
            out["refused"] = self.status["refused"]
        if self.status is not None and self.status.get("prior"):
            out["prior"] = "{superseded}/{samples} superseded".format(**self.status["prior"])
        reason = self.hold_reason()
        if reason:
            out["held"] = reason if len(reason) <= HELD_WIDTH else reason[:HELD_WIDTH - 1] + "…"
        return out

    def hold_reason(self) -> str:
        """Why the learner does not act now, from its last /sagg/status ('' while it acts)."""
        s = self.status
        if s is None or not s.get("paused") or s.get("pause_reason", "").startswith("max_micro_actions"):
            return ""  # (acting, or done: not a hold)
        return s.get("pause_reason", "")

    def stall_text(self, seconds: float, unit: str) -> str:
        """The error of a run that got no new sample for ``seconds`` s: with what the learner says."""
        why = self.hold_reason()
        return (f"no new sample for {seconds:.0f} s (at {self.samples} {unit}); the learner "
                + (f"holds: {why}" if why else "does not say it holds (a node stalled or died?)"))

    def goal_list(self) -> list[dict]:
        """The goals in seq order, with their final competence and the micro-actions done when
        they were chosen (the summary's ``goals``)."""
        goals = []
        for seq in sorted(self.goals):
            g = dict(self.goals[seq])
            g["competence"] = self.goal_competence.get(seq)
            g["micro_actions"] = self.report_ma.get(g["after_report"], 0)
            goals.append(g)
        return goals

    def region_list(self) -> list[dict]:
        """The leaves of the last /sagg/regions (the summary's ``regions``)."""
        if self.last_regions is None:
            return []
        return [{"id": int(r.id), "lower": list(r.lower), "upper": list(r.upper),
                 "interest": float(r.interest), "count": int(r.count),
                 "mean_competence": float(r.mean_competence)} for r in self.last_regions.regions]


def finite_sample_problem(m, expected: int) -> str:
    """A ``problem`` for :meth:`RunState.accept_sample` that needs no parameters: the next index and
    finite values only (docs/safety.md), for the synergy set-ups' samples and for ``sagg record``, which
    may not know the learner's joint limits."""
    if int(m.index) != expected:
        return f"index {int(m.index)}; allowed: {expected} (the next sample)"
    ok = all(np.isfinite(np.array(v, float)).all() for v in (m.alpha, m.delta_alpha, m.delta_y))
    return "" if ok else "NaN/inf value; allowed: finite values"


def _status_dict(m, rate: bool = True) -> dict:
    out = {"strategy": m.strategy, "micro_actions": int(m.micro_actions), "goals": int(m.goals),
           "samples": int(m.samples), "reports": int(m.reports), "last_competence": float(m.last_competence)}
    if rate:
        out["micro_actions_per_second"] = float(m.micro_actions_per_second)
    out.update(paused=bool(m.paused), pause_reason=m.pause_reason)
    if m.refused:
        out["refused"] = m.refused
    if m.prior_samples:
        out["prior"] = {"samples": int(m.prior_samples), "superseded": int(m.prior_superseded)}
    return out
