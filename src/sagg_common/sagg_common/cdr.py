"""Hand-written CDR codecs for the messages on the nodes' hot path (no rclpy import).

Why: converting a message between its Python object and C (rclpy's publish and take) costs about
as much as the transport itself (measured: a raw-bytes ping-pong has half the round-trip time of a
message-object one). The nodes therefore publish bytes they encode here and subscribe with
``raw=True``, decoding only what they need with numpy. Float64 values are copied byte for byte,
so nothing changes numerically.

Format: ROS 2's default serialization, plain CDR little endian (XCDR1): a 4-byte encapsulation
header ``00 01 00 00``, then the fields in order, each primitive aligned to its size (at most 8)
relative to the start of the payload; strings as uint32 length (with the terminating NUL) +
bytes + NUL; sequences as uint32 count + elements. Padding bytes are written as zeros and ignored
when reading; trailing bytes are ignored. ``test_nodes_cdr`` checks every codec against rclpy.
"""
from __future__ import annotations

import struct

import numpy as np

ENCAP = b"\x00\x01\x00\x00"
_U32 = struct.Struct("<I")
_I32U32 = struct.Struct("<iI")
_U64 = struct.Struct("<Q")
_F64 = struct.Struct("<d")
_3F64 = struct.Struct("<3d")
_NS = 1_000_000_000
_F8 = np.dtype("<f8")


def split_ns(ns: int) -> tuple[int, int]:
    """A stamp in ns -> (sec, nanosec) of builtin_interfaces/Time."""
    return ns // _NS, ns % _NS


# ------------------------------------------------------------------------------- generic
class Writer:
    """Append-only CDR writer (payload offsets count from after the encapsulation header)."""

    __slots__ = ("b",)

    def __init__(self):
        self.b = bytearray()

    def align(self, n: int) -> None:
        pad = -len(self.b) % n
        if pad:
            self.b += bytes(pad)

    def u8(self, v: int) -> None:
        self.b.append(v)

    def u32(self, v: int) -> None:
        self.align(4)
        self.b += _U32.pack(v)

    def stamp(self, ns: int) -> None:
        self.align(4)
        self.b += _I32U32.pack(*split_ns(ns))

    def u64(self, v: int) -> None:
        self.align(8)
        self.b += _U64.pack(v)

    def f64(self, v: float) -> None:
        self.align(8)
        self.b += _F64.pack(v)

    def string(self, s: str) -> None:
        data = s.encode()
        self.u32(len(data) + 1)
        self.b += data
        self.b.append(0)

    def strings(self, items) -> None:
        self.u32(len(items))
        for s in items:
            self.string(s)

    def f64_seq(self, values) -> None:
        a = np.ascontiguousarray(values, dtype="<f8")
        self.u32(a.size)
        if a.size:
            self.align(8)
            self.b += a.tobytes()

    def header(self, stamp_ns: int, frame_id: str) -> None:
        self.stamp(stamp_ns)
        self.string(frame_id)

    def tobytes(self) -> bytes:
        return ENCAP + bytes(self.b)


class Reader:
    """Sequential CDR reader over received bytes (encapsulation header skipped)."""

    __slots__ = ("raw", "d", "o")

    def __init__(self, data: bytes):
        if len(data) < 4 or data[1] != 1:
            raise ValueError("not little-endian plain CDR (encapsulation 00 01)")
        self.raw = data
        self.d = memoryview(data)[4:]
        self.o = 0

    def align(self, n: int) -> None:
        self.o += -self.o % n

    def u8(self) -> int:
        v = self.d[self.o]
        self.o += 1
        return v

    def u32(self) -> int:
        self.o += -self.o % 4
        (v,) = _U32.unpack_from(self.d, self.o)
        self.o += 4
        return v

    def stamp(self) -> int:
        self.o += -self.o % 4
        sec, nsec = _I32U32.unpack_from(self.d, self.o)
        self.o += 8
        return sec * _NS + nsec

    def u64(self) -> int:
        self.o += -self.o % 8
        (v,) = _U64.unpack_from(self.d, self.o)
        self.o += 8
        return v

    def f64(self) -> float:
        self.o += -self.o % 8
        (v,) = _F64.unpack_from(self.d, self.o)
        self.o += 8
        return v

    def string(self) -> str:
        n = self.u32()
        s = bytes(self.d[self.o:self.o + n - 1]).decode() if n else ""
        self.o += n
        return s

    def skip_string(self) -> None:
        n = self.u32()
        self.o += n

    def f64_seq(self) -> np.ndarray:
        """A float64 sequence as a READ-ONLY array viewing the received bytes (immutable, kept
        alive by the array): copy it before modifying it in place."""
        n = self.u32()
        if n == 0:
            return np.empty(0)
        self.o += -self.o % 8
        if len(self.d) < self.o + 8 * n:
            raise ValueError("truncated float64 sequence")
        a = np.frombuffer(self.raw, dtype=_F8, count=n, offset=4 + self.o)
        self.o += 8 * n
        return a


# ------------------------------------------------------------------ std_msgs/Float64MultiArray
def encode_f64_array(values: np.ndarray) -> bytes:
    """std_msgs/Float64MultiArray with an empty layout (as ros2_control's forward controllers take)."""
    a = np.ascontiguousarray(values, dtype="<f8")
    # layout.dim = [] (u32 0), layout.data_offset = 0 (u32), data count (u32), pad to 8, data
    return ENCAP + b"\0\0\0\0\0\0\0\0" + _U32.pack(a.size) + (b"\0\0\0\0" + a.tobytes() if a.size else b"")


def decode_f64_array(data: bytes) -> np.ndarray:
    r = Reader(data)
    for _ in range(r.u32()):  # layout.dim (label, size, stride)
        r.skip_string()
        r.u32()
        r.u32()
    r.u32()  # data_offset
    return r.f64_seq()


# ------------------------------------------------------------------ sensor_msgs/JointState
class JointStateEncoder:
    """Fixed joint names and frame: a template whose stamp and values are overwritten per message."""

    def __init__(self, names: list[str], frame_id: str, with_velocity: bool = True):
        self.n = len(names)
        w = Writer()
        w.header(0, frame_id)
        w.strings(names)
        w.u32(self.n)
        w.align(8)
        self.pos_off = len(w.b) + 4
        w.b += bytes(8 * self.n)
        w.u32(self.n if with_velocity else 0)
        if with_velocity and self.n:
            w.align(8)
        self.vel_off = len(w.b) + 4
        if with_velocity:
            w.b += bytes(8 * self.n)
        w.u32(0)  # effort
        self.buf = bytearray(ENCAP + bytes(w.b))
        self.with_velocity = with_velocity

    def encode(self, stamp_ns: int, position: np.ndarray, velocity: np.ndarray | None = None) -> bytes:
        b = self.buf
        _I32U32.pack_into(b, 4, *split_ns(stamp_ns))
        n8 = 8 * self.n
        b[self.pos_off:self.pos_off + n8] = np.ascontiguousarray(position, dtype="<f8").tobytes()
        if self.with_velocity:
            v = np.zeros(self.n) if velocity is None else velocity
            b[self.vel_off:self.vel_off + n8] = np.ascontiguousarray(v, dtype="<f8").tobytes()
        return bytes(b)


class JointStateDecoder:
    """Decodes stamp, names, positions and velocities; the names tuple is cached and returned as
    the same object while the publisher's name list does not change (cheap re-mapping check).
    Fast path: when the frame_id and name list bytes equal the previous message's, their parsing
    is skipped (one bytes comparison)."""

    def __init__(self):
        self._blob = b""       # bytes of frame_id + names of the last message (payload offsets 8..end)
        self._end = 0          # payload offset just after the names
        self.names: tuple[str, ...] = ()

    def decode(self, data: bytes) -> tuple[int, tuple[str, ...], np.ndarray, np.ndarray]:
        r = Reader(data)
        stamp = r.stamp()
        end = self._end
        if not (end and data[12:4 + end] == self._blob):
            r.skip_string()  # frame_id
            start = r.o
            count = r.u32()
            for _ in range(count):
                r.skip_string()
            end = r.o
            r2 = Reader(data)
            r2.o = start
            self.names = tuple(r2.string() for _ in range(r2.u32()))
            self._blob, self._end = bytes(data[12:4 + end]), end
        r.o = end
        position = r.f64_seq()
        velocity = r.f64_seq()
        return stamp, self.names, position, velocity


# ------------------------------------------------------------------ geometry_msgs/PointStamped
class PointStampedEncoder:
    def __init__(self, frame_id: str):
        w = Writer()
        w.header(0, frame_id)
        w.align(8)
        self.off = len(w.b) + 4
        w.b += bytes(24)
        self.buf = bytearray(ENCAP + bytes(w.b))

    def encode(self, stamp_ns: int, x: float, y: float, z: float = 0.0) -> bytes:
        b = self.buf
        _I32U32.pack_into(b, 4, *split_ns(stamp_ns))
        _3F64.pack_into(b, self.off, x, y, z)
        return bytes(b)


def decode_point_stamped(data: bytes) -> tuple[int, tuple[float, float, float]]:
    r = Reader(data)
    stamp = r.stamp()
    r.skip_string()
    r.align(8)
    return stamp, _3F64.unpack_from(r.d, r.o)


# ------------------------------------------------------------------ sagg_msgs/Sample
def encode_sample(stamp_ns: int, index: int, alpha, delta_alpha, delta_y, frame_id: str = "") -> bytes:
    w = Writer()
    w.header(stamp_ns, frame_id)
    w.u64(index)
    w.f64_seq(alpha)
    w.f64_seq(delta_alpha)
    w.f64_seq(delta_y)
    return w.tobytes()


def decode_sample(data: bytes) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray]:
    r = Reader(data)
    stamp = r.stamp()
    r.skip_string()
    index = r.u64()
    return stamp, index, r.f64_seq(), r.f64_seq(), r.f64_seq()


# ------------------------------------------------------------------ sagg_msgs/CompetenceReport
def encode_report(stamp_ns: int, seq: int, goal_seq: int, kind: int, target, reached, start,
                  competence: float, micro_actions: int, frame_id: str = "") -> bytes:
    w = Writer()
    w.header(stamp_ns, frame_id)
    w.u64(seq)
    w.u64(goal_seq)
    w.u8(kind)
    w.f64_seq(target)
    w.f64_seq(reached)
    w.f64_seq(start)
    w.f64(competence)
    w.u64(micro_actions)
    return w.tobytes()


class DecodedReport:
    __slots__ = ("stamp", "seq", "goal_seq", "kind", "target", "reached", "start", "competence",
                 "micro_actions")


def decode_report(data: bytes) -> DecodedReport:
    r = Reader(data)
    out = DecodedReport()
    out.stamp = r.stamp()
    r.skip_string()
    out.seq = r.u64()
    out.goal_seq = r.u64()
    out.kind = r.u8()
    out.target = r.f64_seq()
    out.reached = r.f64_seq()
    out.start = r.f64_seq()
    out.competence = r.f64()
    out.micro_actions = r.u64()
    return out


# ------------------------------------------------------------------ sagg_msgs/RegionTree
def _region_dtype(m: int) -> np.dtype:
    """Layout of one sagg_msgs/Region with m-dimensional bounds, starting 8-aligned: id u32,
    lower (u32 count, f64×m at 8), upper (u32 count at 8+8m, f64×m at 16+8m), interest f64,
    count u32, mean_competence f64. Its size 40+16m is a multiple of 8, so every region of the
    array starts 8-aligned and shares this layout."""
    return np.dtype({
        "names": ["id", "nlo", "lower", "nup", "upper", "interest", "count", "mean"],
        "formats": ["<u4", "<u4", ("<f8", (m,)), "<u4", ("<f8", (m,)), "<f8", "<u4", "<f8"],
        "offsets": [0, 4, 8, 8 + 8 * m, 16 + 8 * m, 16 + 16 * m, 24 + 16 * m, 32 + 16 * m],
        "itemsize": 40 + 16 * m,
    })


def encode_region_tree(stamp_ns: int, frame_id: str, goals: int, reports: int, splits: int,
                       ids, lowers, uppers, interests, counts, means) -> bytes:
    """sagg_msgs/RegionTree from per-region arrays (k regions, bounds of shape (k, m)); the
    regions are laid out with one numpy structured array instead of k message objects."""
    lowers = np.asarray(lowers, dtype=np.float64)
    k = len(ids)
    m = lowers.shape[1] if k else 0
    w = Writer()
    w.header(stamp_ns, frame_id)
    w.u64(goals)
    w.u64(reports)
    w.u32(splits)
    w.u32(k)
    if not k:
        return w.tobytes()
    if m == 0:
        raise ValueError("regions need at least one dimension")
    w.align(8)  # (already aligned: the u64s put the two u32s at an 8-aligned pair)
    arr = np.zeros(k, dtype=_region_dtype(m))
    arr["id"] = ids
    arr["nlo"] = m
    arr["lower"] = lowers
    arr["nup"] = m
    arr["upper"] = uppers
    arr["interest"] = interests
    arr["count"] = counts
    arr["mean"] = means
    return ENCAP + bytes(w.b) + arr.tobytes()
