"""Rejected-input bookkeeping shared by the nodes, and its ``diagnostic_msgs`` form.

Every node checks what it receives (NaN/inf, wrong array lengths, unknown or missing joint names,
goals outside Y, duplicated or out-of-order reports, undecodable bytes). A bad input is dropped
before it can touch the node's state, logged with a line that names the problem, and counted here;
the counts go out on ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second.

:class:`InputGuard` is plain Python; :func:`diagnostic_array` builds the ROS message (imported
lazily, so the cores never import ROS).
"""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np


def all_finite(a: np.ndarray) -> bool:
    """True iff every entry of the 1-D float array ``a`` is finite, cheaply: ``a·a`` is one
    reduction and is NaN/inf iff some entry is non-finite (or |a| > ~1e154, where the exact check
    decides). For the hot paths (every command and observation, every simulator call)."""
    return bool(a.dot(a) < math.inf) or bool(np.isfinite(a).all())

# DiagnosticStatus levels (diagnostic_msgs/DiagnosticStatus: OK=0, WARN=1, ERROR=2, STALE=3)
OK, WARN, ERROR, STALE = 0, 1, 2, 3


class InputGuard:
    """Counts rejected inputs per kind (e.g. ``joint_states.non_finite``) and logs them.

    The first rejection of a kind is logged at once; later ones of the same kind at most every
    ``throttle`` seconds, with the count so far, so a flood of bad messages cannot flood the log.
    """

    def __init__(self, log: Callable[[str], None], throttle: float = 5.0,
                 clock: Callable[[], float] = time.monotonic):
        self.log = log
        self.throttle = throttle
        self.clock = clock
        self.counts: dict[str, int] = {}
        self.last_message: dict[str, str] = {}
        self._last_logged: dict[str, float] = {}
        self.total = 0
        self._total_at_last_status = 0

    def reject(self, kind: str, message: str) -> None:
        """Record one rejected input of ``kind``; ``message`` names the problem and what is allowed."""
        n = self.counts.get(kind, 0) + 1
        self.counts[kind] = n
        self.total += 1
        self.last_message[kind] = message
        now = self.clock()
        last = self._last_logged.get(kind)
        if last is None or now - last >= self.throttle:
            self._last_logged[kind] = now
            self.log(f"rejected input [{kind}] {message}" + (f" ({n} so far)" if n > 1 else ""))

    def new_since_last_status(self) -> int:
        """Rejections since the previous call (the status level is WARN while there are new ones)."""
        n = self.total - self._total_at_last_status
        self._total_at_last_status = self.total
        return n


def goal_problem(position, lower, upper) -> tuple[np.ndarray, str]:
    """A goal received by a learner as a float array, and what is wrong with it ('' if nothing):
    it must have one finite value per task-space dimension, within [lower, upper]."""
    pos = np.array(position, dtype=np.float64)
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    if pos.shape != lo.shape or not np.all(np.isfinite(pos)) or np.any(pos < lo) or np.any(pos > hi):
        return pos, (f"at {pos.tolist()}: allowed: {len(lo)} finite values within task_space "
                     f"[{lo.tolist()}, {hi.tolist()}]")
    return pos, ""


def diagnostic_array(stamp, node_name: str, guard: InputGuard, state: dict[str, str] | None = None,
                     fault: str = ""):
    """A ``diagnostic_msgs/DiagnosticArray`` with one status for ``node_name``: level ERROR if
    ``fault`` (e.g. a safety pause) else WARN if inputs were rejected since the last status, else
    OK; values: every rejection counter (``rejected.<kind>``) and the ``state`` entries."""
    # lazy (heavy): ROS
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    new = guard.new_since_last_status()
    st = DiagnosticStatus()
    st.name = f"{node_name}: inputs and safety"
    st.hardware_id = node_name
    if fault:
        st.level, st.message = bytes([ERROR]), fault
    elif new:
        st.level = bytes([WARN])
        st.message = f"{new} input(s) rejected in the last period ({guard.total} in total)"
    else:
        st.level = bytes([OK])
        st.message = f"ok ({guard.total} input(s) rejected in total)"
    values = [KeyValue(key="rejected.total", value=str(guard.total))]
    values += [KeyValue(key=f"rejected.{k}", value=str(v)) for k, v in sorted(guard.counts.items())]
    values += [KeyValue(key=k, value=str(v)) for k, v in (state or {}).items()]
    st.values = values
    msg = DiagnosticArray()
    msg.header.stamp = stamp
    msg.status = [st]
    return msg


def sample_problem(index: int, expected: int, alpha, delta_alpha, delta_y, lower, upper, m: int,
                   tolerance: float = 0.1) -> str:
    """What is wrong with a /sagg/sample received after ``expected`` samples ('' if nothing): its
    index must be ``expected`` (the next one), α one finite value per joint within the joint limits
    ± ``tolerance`` (the learner's plausibility.joint_tolerance), Δα one finite value per joint,
    Δy ``m`` finite values. A sample with an older index is a re-publication, not a problem
    (the caller drops it)."""
    if index != expected:
        return f"index {index}; allowed: {expected} (the next sample)"
    lo, hi = np.asarray(lower, dtype=float), np.asarray(upper, dtype=float)
    a, da, dy = (np.asarray(x, dtype=float) for x in (alpha, delta_alpha, delta_y))
    if a.shape != lo.shape or da.shape != lo.shape or dy.shape != (m,):
        return (f"{a.size} alpha, {da.size} delta_alpha, {dy.size} delta_y values; allowed: {lo.size}, "
                f"{lo.size}, {m}")
    if not (np.isfinite(a).all() and np.isfinite(da).all() and np.isfinite(dy).all()):
        return "NaN/inf value; allowed: finite values"
    if (a < lo - tolerance).any() or (a > hi + tolerance).any():
        return f"alpha {a.tolist()}; allowed: within the joint limits ± {tolerance}"
    return ""


def report_problem(kind: int, target, competence: float, dim: int, kinds) -> str:
    """What is wrong with a competence report's content ('' if nothing): ``kind`` one of
    ``kinds``, ``target`` (the target, or the reached point when it has none) ``dim`` finite
    values, ``competence`` finite and <= 0."""
    t = np.asarray(target, dtype=float)
    if kind not in kinds:
        return f"kind {kind}; allowed: {sorted(kinds)}"
    if t.shape != (dim,):
        return f"{t.size} target/reached coordinates; allowed: {dim} (the task space)"
    if not np.all(np.isfinite(t)):
        return f"NaN/inf position {t.tolist()}; allowed: finite values"
    if not math.isfinite(competence) or competence > 0.0:
        return f"competence {competence}; allowed: a finite value <= 0"
    return ""
