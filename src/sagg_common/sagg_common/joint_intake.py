"""The one reader of ``/joint_states`` (sensor_msgs/JointState as raw CDR), for every node and tool
that takes an arm's measured posture: the evolving-context learner, the fixed-context position
link, the external run's driver monitor and ``sagg check-driver``. One rule set, in this order:

1. **decode** (``joint_states.undecodable``) and check the lengths: one position per name, and no
   velocity or one per name (``joint_states.length``);
2. **select** the reader's joints by name (any order; a message may carry other joints too). A
   message naming none of them is another driver's (a gripper's): *ignored*, counted per name
   list in :attr:`JointStateIntake.other_joints`, never an error. A message naming a joint twice,
   or only some of ours, is rejected (``joint_states.names``);
3. **check** the values: finite (``joint_states.non_finite``), inside the joint limits widened by
   ``tolerance`` (``joint_states.out_of_limits``), every |velocity| at most ``max_velocity``
   (``joint_states.velocity``); each rejection names the field, the value and the allowed range;
4. **attribute** it to a source (:class:`~sagg_common.sources.SourceChains`: the messages carrying
   our joints must come from one publisher; ``check_sources``): a gap is not taken (not an
   error), a second live source makes the stream *ambiguous*. A message not taken for its content
   (1-3) is no gap in its publisher's chain;
5. **stamp** (:class:`~sagg_common.envelope.StampTracker`): older than the newest
   (``joint_states.out_of_order``), in the future of the stream (``joint_states.future_stamp``), or
   a clock jump back after ``resync_after`` older ones in a row (taken; the stream re-synchronised).

Then it is the newest reading: :attr:`position`, :attr:`velocity` (None when the message has
none), :attr:`stamp` (ns) and :attr:`settled` (every |velocity| below ``settle_velocity``; a
reading without velocities counts as settled). What a reader does with a verdict (log, count on
/diagnostics, hold) is its own; the verdict carries the words. ROS-free: plain numpy.
"""
from __future__ import annotations

import math
import struct
import time
from typing import Sequence

import numpy as np

from .cdr import JointStateDecoder
from .envelope import ACCEPT, FUTURE, OUT_OF_ORDER, StampTracker
from .sources import ACCEPT as SOURCE_ACCEPT, AMBIGUOUS as SOURCE_AMBIGUOUS, SourceChains

# verdict codes (Verdict.code)
TAKEN = "taken"            # the newest reading (a clock jump back too: then ``message`` says so)
OTHER = "other"            # another driver's joints: ignored
REJECTED = "rejected"      # its content: ``kind`` and ``message`` name the field, value and range
GAP = "gap"                # its publisher's chain skipped numbers: not taken, not an error
AMBIGUOUS = "ambiguous"    # a second source sends our joints: not taken
OUT_OF_ORDER_STAMP = "out_of_order"  # older than the newest stamp: not taken
FUTURE_STAMP = "future_stamp"        # in the future of the stream: not taken
TOPIC = "/joint_states"
NAME_MAPS = 32  # name lists whose mapping is kept (a fuzzer's random names must not grow the cache)


class Verdict:
    """What the intake made of one message: ``code`` (the constants above), and for a rejection
    or a clock jump back its ``kind`` (``joint_states.<field>``) and ``message`` (for the log)."""

    __slots__ = ("code", "kind", "message")

    def __init__(self, code: str, kind: str = "", message: str = ""):
        self.code, self.kind, self.message = code, kind, message

    def __repr__(self) -> str:
        return f"Verdict({self.code!r}, {self.kind!r})"


_TAKEN, _OTHER, _GAP, _AMBIGUOUS = Verdict(TAKEN), Verdict(OTHER), Verdict(GAP), Verdict(AMBIGUOUS)


class JointStateIntake:
    """The reader of ``/joint_states`` for the joints ``joints`` (module docstring).

    Parameters
    ----------
    joints : sequence of str, length n
        The reader's joints; :attr:`position` and :attr:`velocity` are in this order.
    lower, upper : array_like, shape (n,)
        Joint limits (rad); a position outside them by more than ``tolerance`` is rejected.
    tolerance, max_velocity, settle_velocity : float
        The learner's ``plausibility.joint_tolerance``, ``plausibility.max_joint_velocity`` and
        ``settle_velocity``.
    source_grace : float
        ``plausibility.source_grace`` (s): how long a second source keeps the stream ambiguous.
    check_sources : bool
        Apply the one-source rule (``plausibility.check_sources``).
    future_tolerance : float
        ``plausibility.future_tolerance`` (s).
    resync_after : int
        ``plausibility.resync_after``: older stamps in a row that are a clock jump back.
    """

    def __init__(self, joints: Sequence[str], lower, upper, *, tolerance: float, max_velocity: float,
                 settle_velocity: float, source_grace: float, check_sources: bool, future_tolerance: float,
                 resync_after: int):
        self.joints = tuple(joints)
        self.n = len(self.joints)
        self.lower = np.asarray(lower, dtype=float) - tolerance
        self.upper = np.asarray(upper, dtype=float) + tolerance
        if self.lower.shape != (self.n,) or self.upper.shape != (self.n,):
            raise ValueError(f"joint limits: {self.lower.shape[0]} / {self.upper.shape[0]} values; "
                             f"allowed: one per joint ({self.n})")
        self.max_velocity = float(max_velocity)
        self.settle_velocity = float(settle_velocity)
        self.check_sources = bool(check_sources)
        self.sources = SourceChains(source_grace)
        self.track = StampTracker(future_tolerance, resync_after)
        self.decoder = JointStateDecoder()
        self._maps: dict[tuple, tuple] = {}  # name list -> ("ok", index) | ("other",) | ("bad", message)
        self.other_joints: dict[tuple, int] = {}  # name lists without any of our joints -> messages
        self.names: tuple[str, ...] | None = None  # the name list of the last decoded message
        self.message_stamp = -1  # the stamp (ns) of the last decoded message, taken or not
        # the newest reading (TAKEN)
        self.position: np.ndarray | None = None
        self.velocity: np.ndarray | None = None
        self.stamp = -1
        self.settled = False

    # ------------------------------------------------------------------ one message
    def take(self, data: bytes, seq: int | None = None, now: float | None = None) -> Verdict:
        """The verdict for one raw JointState (``seq``: its publication sequence number, None when
        unknown; ``now``: its receive time, ``time.monotonic()`` by default). A message not taken
        for its content is skipped in its publisher's chain (no gap)."""
        verdict = self._content(data)
        if verdict is not None:
            self.sources.skip(seq)
            return verdict
        now = time.monotonic() if now is None else now
        if self.check_sources:
            source = self.sources.classify(seq, now)
            if source != SOURCE_ACCEPT:
                return _AMBIGUOUS if source == SOURCE_AMBIGUOUS else _GAP
        st = self._stamp
        rx_ns = time.monotonic_ns()
        stamp = self.track.check(st, rx_ns)
        if stamp != ACCEPT:
            field, message = self.track.describe(stamp, TOPIC, st, rx_ns)
            if stamp in (OUT_OF_ORDER, FUTURE):
                return Verdict(OUT_OF_ORDER_STAMP if stamp == OUT_OF_ORDER else FUTURE_STAMP,
                               f"joint_states.{field}", message)
        self.position, self.velocity, self.stamp = self._alpha, self._vel, st
        v = self._vel
        sv = self.settle_velocity
        self.settled = v is None or bool(-sv < v.min() and v.max() < sv)
        if stamp != ACCEPT:  # (RESYNC: taken)
            return Verdict(TAKEN, f"joint_states.{field}", message)
        return _TAKEN

    def _content(self, data: bytes) -> Verdict | None:
        """Steps 1-3 (None: the content is fine; :attr:`_alpha`, :attr:`_vel`, :attr:`_stamp` set)."""
        try:
            st, names, pos, vel = self.decoder.decode(data)
        except (ValueError, IndexError, struct.error, UnicodeDecodeError) as exc:
            self.names, self.message_stamp = None, -1
            return Verdict(REJECTED, "joint_states.undecodable", f"{TOPIC}: undecodable message ({exc})")
        self.names, self.message_stamp = names, st
        if len(pos) != len(names) or (len(vel) and len(vel) != len(names)):
            return Verdict(REJECTED, "joint_states.length",
                           f"{TOPIC}: {len(names)} names but {len(pos)} positions and {len(vel)} velocities; "
                           "allowed: one position per name, and no or one velocity per name")
        how = self._maps.get(names)
        if how is None:
            if len(self._maps) >= NAME_MAPS:
                self._maps.clear()
            how = self._maps[names] = self._name_map(names)
        if how[0] != "ok":
            if how[0] == "other":
                self.other_joints[names] = self.other_joints.get(names, 0) + 1
                return _OTHER
            return Verdict(REJECTED, "joint_states.names", how[1])
        idx = how[1]
        alpha = pos[idx]
        v = vel[idx] if len(vel) else None
        # one vector test each (NaN fails a comparison, so non-finite values are caught too)
        if not ((alpha >= self.lower).all() and (alpha <= self.upper).all()):
            return self._value_problem(alpha, v)
        if v is not None and not (-self.max_velocity <= v.min() and v.max() <= self.max_velocity):
            return self._value_problem(alpha, v)
        self._alpha, self._vel, self._stamp = alpha, v, st
        return None

    def _name_map(self, names: tuple) -> tuple:
        """("ok", index array) for a list naming each of our joints once; ("other",) for one that
        names none of them; else ("bad", message)."""
        where = {n: i for i, n in enumerate(names)}
        ours = self.joints
        missing = [j for j in ours if j not in where]
        if len(missing) == len(ours):  # (another driver's message, however formed: not ours to judge)
            return ("other",)
        if len(where) != len(names):
            return ("bad", f"{TOPIC} names a joint twice ({', '.join(names)}); allowed: every joint of the "
                           f"'joints' parameter ({', '.join(ours)}) once")
        if missing:
            return ("bad", f"{TOPIC} lacks joint(s) {', '.join(missing)}; allowed: every joint of the 'joints' "
                           f"parameter ({', '.join(ours)}) in one message, other joints are ignored")
        return ("ok", np.array([where[j] for j in ours], dtype=np.intp))

    def _value_problem(self, alpha: np.ndarray, v: np.ndarray | None) -> Verdict:
        """The first implausible field of a reading, named (the slow path of the checks)."""
        bad = [self.joints[k] for k in range(self.n) if not math.isfinite(alpha[k])
               or (v is not None and not math.isfinite(v[k]))]
        if bad:
            return Verdict(REJECTED, "joint_states.non_finite",
                           f"{TOPIC}: NaN/inf position or velocity of {', '.join(bad)}; allowed: finite values")
        for i, name in enumerate(self.joints):
            a = float(alpha[i])
            if not self.lower[i] <= a <= self.upper[i]:
                return Verdict(REJECTED, "joint_states.out_of_limits",
                               f"{TOPIC}: position of {name} = {a!r} rad; allowed: [{self.lower[i]:.6g}, "
                               f"{self.upper[i]:.6g}] (joint limits ± plausibility.joint_tolerance)")
        i = int(np.argmax(np.abs(v)))
        return Verdict(REJECTED, "joint_states.velocity",
                       f"{TOPIC}: velocity of {self.joints[i]} = {float(v[i])!r} rad/s; allowed: "
                       f"|v| <= {self.max_velocity:g} (plausibility.max_joint_velocity)")

    # ------------------------------------------------------------------ the stream
    def ambiguous(self, now: float | None = None) -> bool:
        """Whether two sources send our joints now."""
        return self.sources.ambiguous(time.monotonic() if now is None else now)
