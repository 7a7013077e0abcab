"""CDR primitives and the codecs of the standard ROS messages on the nodes' hot path (no rclpy import).

Why: converting a message between its Python object and C (rclpy's publish and take) costs about as
much as the transport itself. The nodes therefore publish bytes they encode here and subscribe with
``raw=True``, decoding only what they need with numpy. Float64 values are copied byte for byte, so
nothing changes numerically.

Format: ROS 2's default serialization, plain CDR little endian (XCDR1): a 4-byte encapsulation
header ``00 01 00 00``, then the fields in order, each primitive aligned to its size (at most 8)
relative to the start of the payload; strings as uint32 length (with the terminating NUL) +
bytes + NUL; sequences as uint32 count + elements. Padding bytes are written as zeros and ignored
when reading; trailing bytes are ignored. ``test_nodes_cdr`` checks every codec against rclpy.

Here: the :class:`Writer`/:class:`Reader` primitives and templates for the hardware contract's
standard messages (Float64MultiArray, JointState, PointStamped: fixed by ROS, never edited by us).
The sagg_msgs codecs are built from the .msg files by :mod:`sagg_common.msg_codecs`.
"""
from __future__ import annotations

import struct

import numpy as np

ENCAP = b"\x00\x01\x00\x00"
_U32 = struct.Struct("<I")
_I32U32 = struct.Struct("<iI")
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

    def u32(self, v: int) -> None:
        self.align(4)
        self.b += _U32.pack(v)

    def stamp(self, ns: int) -> None:
        self.align(4)
        self.b += _I32U32.pack(*split_ns(ns))

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
def encode_joint_state(stamp_ns: int, frame_id: str, names, position, velocity=(), effort=()) -> bytes:
    """Any sensor_msgs/JointState, arrays of any length (the hostile-input fuzzer's and the tests'
    writer; the bridge's hot path uses :class:`JointStateEncoder`)."""
    w = Writer()
    w.header(stamp_ns, frame_id)
    w.strings(list(names))
    w.f64_seq(position)
    w.f64_seq(velocity)
    w.f64_seq(effort)
    return w.tobytes()


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
    the same object while a publisher's name list does not change (cheap re-mapping check).
    Fast path: when the frame_id and name list bytes equal those of one of the last few distinct
    lists seen (several drivers may publish their own joints on /joint_states, interleaved), their
    parsing is skipped (one bytes comparison each)."""

    KEEP = 4  # distinct (frame_id, names) lists remembered

    def __init__(self):
        # (bytes of frame_id + names (payload offsets 8..end), end, names), most recent first
        self._seen: list[tuple[bytes, int, tuple[str, ...]]] = []
        self.names: tuple[str, ...] = ()

    def decode(self, data: bytes) -> tuple[int, tuple[str, ...], np.ndarray, np.ndarray]:
        r = Reader(data)
        stamp = r.stamp()
        seen = self._seen
        for i, (blob, end, names) in enumerate(seen):
            if data[12:4 + end] == blob:
                if i:
                    seen.insert(0, seen.pop(i))
                break
        else:
            r.skip_string()  # frame_id
            start = r.o
            count = r.u32()
            for _ in range(count):
                r.skip_string()
            end = r.o
            r2 = Reader(data)
            r2.o = start
            names = tuple(r2.string() for _ in range(r2.u32()))
            seen.insert(0, (bytes(data[12:4 + end]), end, names))
            del seen[self.KEEP:]
        self.names = names
        r.o = end
        position = r.f64_seq()
        velocity = r.f64_seq()
        return stamp, names, position, velocity


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
