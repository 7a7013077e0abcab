"""CDR codecs of the sagg_msgs messages, built at import time from the .msg files (no rclpy import).

A message is edited in one place, its .msg file: this module reads the field list of every
``sagg_msgs/msg/*.msg`` (the installed share folder, as the ROS type support was built from it) and
builds an encoder and a decoder that follow it field by field with the primitives of
:mod:`sagg_common.cdr` (same byte layout as rclpy's serializer, float64 copied byte for byte),
written out as one function per message and direction at import time (one call per field, no loop:
the cost of the hand-written codecs they replace).

- ``CODECS[name].encode(stamp_ns, <fields in .msg order>, frame_id="")`` -> CDR bytes. A
  ``std_msgs/Header`` field takes the stamp in nanoseconds (its frame_id is the keyword); a float
  sequence takes any array-like; a field that is a sequence of one of our messages (``Region[]``)
  takes a tuple of per-field columns (k values; for a sequence field a (k, m) array, or k
  sequences of any lengths), laid out with one numpy structured array instead of k message
  objects. The encoder's signature is the field list, so a field added to a .msg fails loudly at
  every caller that does not pass it.
- ``CODECS[name].decode(raw)`` -> a named tuple of the fields in .msg order, the Header as
  ``stamp`` (ns; the frame_id is skipped: no reader needs it); float64 sequences are read-only
  arrays viewing the received bytes (see :meth:`sagg_common.cdr.Reader.f64_seq`).

Supported field types (what sagg_msgs uses; anything else raises NotImplementedError at import):
the numeric primitives and bool, string, std_msgs/Header, unbounded sequences of numeric
primitives, our own messages and unbounded sequences of them. Constants and comments are skipped.
``test_nodes_cdr`` checks every codec against rclpy's serializer and against a .msg edited in a
temporary copy; ``python -m sagg_lab.cdr_bench`` measures them against the hand-written
codecs they replaced.
"""
from __future__ import annotations

import os
import struct
import sys
from collections import namedtuple
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .cdr import ENCAP, Reader, Writer

#: The sagg_msgs messages (file stems of src/sagg_msgs/msg).
MESSAGES = ("Goal", "CompetenceReport", "Region", "RegionTree", "Sample", "LearnerStatus", "Evaluation")

# primitive type -> (struct format, numpy dtype)
PRIMITIVES = {
    "bool": ("?", "?"), "byte": ("B", "u1"), "char": ("B", "u1"), "uint8": ("B", "u1"), "int8": ("b", "i1"),
    "uint16": ("H", "<u2"), "int16": ("h", "<i2"), "uint32": ("I", "<u4"), "int32": ("i", "<i4"),
    "uint64": ("Q", "<u8"), "int64": ("q", "<i8"), "float32": ("f", "<f4"), "float64": ("d", "<f8"),
}
HEADER = "std_msgs/Header"


def find_msg_dir() -> Path:
    """The sagg_msgs ``msg`` folder: the installed share dir (venv prefix, AMENT_PREFIX_PATH) first,
    then the source tree (src/sagg_msgs/msg)."""
    candidates = [Path(sys.prefix) / "share" / "sagg_msgs" / "msg"]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix) / "share" / "sagg_msgs" / "msg")
    candidates.append(Path(__file__).resolve().parents[2] / "sagg_msgs" / "msg")
    for c in candidates:
        if all((c / f"{name}.msg").is_file() for name in MESSAGES):
            return c
    raise FileNotFoundError("sagg_msgs .msg files not found in: " + ", ".join(str(c) for c in candidates))


def parse_msg(text: str) -> list[tuple[str, str]]:
    """The (type, name) fields of a .msg text, in order; constants (``TYPE NAME=value``) and
    comments are skipped. Types as written (``float64[]``, ``std_msgs/Header``, ``Region[]``)."""
    fields = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) < 2:
            raise ValueError(f"not a field: {line!r}")
        if "=" in line:
            continue  # a constant
        if len(parts) > 2:
            raise NotImplementedError(f"field default values are not supported: {line!r}")
        fields.append((parts[0], parts[1]))
    return fields


def _prim_put(fmt: str) -> Callable[[Writer, Any], None]:
    st = struct.Struct("<" + fmt)
    size = st.size

    def put(w: Writer, v) -> None:
        b = w.b
        pad = -len(b) % size
        if pad:
            b += bytes(pad)
        b += st.pack(v)
    return put


def _prim_get(fmt: str) -> Callable[[Reader], Any]:
    st = struct.Struct("<" + fmt)
    size = st.size

    def get(r: Reader):
        r.o += -r.o % size
        (v,) = st.unpack_from(r.d, r.o)
        r.o += size
        return v
    return get


def _seq_put(dtype: str) -> Callable[[Writer, Any], None]:
    if dtype == "<f8":
        return Writer.f64_seq
    dt = np.dtype(dtype)

    def put(w: Writer, values) -> None:
        a = np.ascontiguousarray(values, dtype=dt)
        w.u32(a.size)
        if a.size:
            w.align(dt.itemsize)
            w.b += a.tobytes()
    return put


def _seq_get(dtype: str) -> Callable[[Reader], np.ndarray]:
    if dtype == "<f8":
        return Reader.f64_seq
    dt = np.dtype(dtype)

    def get(r: Reader) -> np.ndarray:
        n = r.u32()
        if n == 0:
            return np.empty(0, dtype=dt)
        r.align(dt.itemsize)
        if len(r.d) < r.o + dt.itemsize * n:
            raise ValueError("truncated sequence")
        a = np.frombuffer(r.raw, dtype=dt, count=n, offset=4 + r.o)
        r.o += dt.itemsize * n
        return a
    return get


def _header_get(r: Reader) -> int:
    stamp = r.stamp()
    r.skip_string()
    return stamp


class MsgCodec:
    """Encoder and decoder of one message, built from its field list (see the module docstring)."""

    def __init__(self, name: str, fields: list[tuple[str, str]], codecs: dict[str, "MsgCodec"]):
        self.name = name
        self.fields = tuple(fields)
        self.has_header = any(t == HEADER for t, _ in fields)
        self.puts: list[Callable] = []
        self.gets: list[Callable] = []
        self.columns: list[tuple[str, str]] = []  # (kind, dtype) per field: how it sits in a column layout
        for typ, fname in fields:
            self._add(typ, fname, codecs)
        self.Decoded = namedtuple(name, ["stamp" if t == HEADER else n for t, n in fields])
        self._make = self.Decoded._make
        self._arity = len(fields)
        self.encode, self.decode = self._compile()

    def _add(self, typ: str, fname: str, codecs: dict[str, "MsgCodec"]) -> None:
        where = f"{self.name}.{fname} ({typ})"
        if typ == HEADER:
            self.puts.append(None)  # the header: stamp argument + frame_id keyword (see encode)
            self.gets.append(_header_get)
            self.columns.append(("header", ""))
        elif typ in PRIMITIVES:
            self.puts.append(_prim_put(PRIMITIVES[typ][0]))
            self.gets.append(_prim_get(PRIMITIVES[typ][0]))
            self.columns.append(("prim", PRIMITIVES[typ][1]))
        elif typ == "string":
            self.puts.append(Writer.string)
            self.gets.append(Reader.string)
            self.columns.append(("string", ""))
        elif typ.endswith("[]") and typ[:-2] in PRIMITIVES:
            self.puts.append(_seq_put(PRIMITIVES[typ[:-2]][1]))
            self.gets.append(_seq_get(PRIMITIVES[typ[:-2]][1]))
            self.columns.append(("seq", PRIMITIVES[typ[:-2]][1]))
        elif typ.endswith("[]") and typ[:-2] in codecs:
            sub = codecs[typ[:-2]]
            self.puts.append(_MsgSeqPut(sub))
            self.gets.append(_msg_seq_get(sub))
            self.columns.append(("msgseq", ""))
        elif typ in codecs:
            sub = codecs[typ]
            self.puts.append(sub.write_fields)
            self.gets.append(sub.read_fields)
            self.columns.append(("msg", ""))
        else:
            raise NotImplementedError(f"{where}: type not supported by sagg_common.msg_codecs")

    # ------------------------------------------------------------------ field-level (nesting)
    def write_fields(self, w: Writer, values, frame_id: str = "") -> None:
        if len(values) != self._arity:
            raise TypeError(f"{self.name}: {len(values)} values for the fields "
                            f"{', '.join(n for _, n in self.fields)}")
        for put, v in zip(self.puts, values):
            if put is None:
                w.header(v, frame_id)
            else:
                put(w, v)

    def read_fields(self, r: Reader):
        return self._make([get(r) for get in self.gets])

    # ------------------------------------------------------------------------- messages
    def _compile(self):
        """``encode`` and ``decode`` as functions written for this field list (as dataclasses and
        rosbags do): one call per field and no loop, so they cost what hand-written codecs cost,
        and ``encode`` has the real signature (a missing field is a TypeError naming it)."""
        names = ["stamp_ns" if t == HEADER else n for t, n in self.fields]
        if any(not n.isidentifier() or n.startswith("_") or n == "frame_id" for n in names):
            raise NotImplementedError(f"{self.name}: field names {names} not usable as arguments")
        ns: dict[str, Any] = {"_Writer": Writer, "_Reader": Reader, "_ENCAP": ENCAP, "_Decoded": self.Decoded}
        enc = ["    _w = _Writer()"]
        for i, (arg, put) in enumerate(zip(names, self.puts)):
            if put is None:
                enc.append(f"    _w.header({arg}, frame_id)")
            else:
                ns[f"_put{i}"] = put
                enc.append(f"    _put{i}(_w, {arg})")
        enc.append("    return _ENCAP + bytes(_w.b)")
        kw = ", *, frame_id=''" if self.has_header else ""
        for i, get in enumerate(self.gets):
            ns[f"_get{i}"] = get
        src = (f"def encode({', '.join(names)}{kw}):\n" + "\n".join(enc) + "\n\n"
               f"def decode(data):\n    _r = _Reader(data)\n"
               f"    return _Decoded({', '.join(f'_get{i}(_r)' for i in range(len(names)))})\n")
        exec(compile(src, f"<sagg_common.msg_codecs: {self.name}>", "exec"), ns)
        return ns["encode"], ns["decode"]


class _MsgSeqPut:
    """Writes a sequence of one of our messages from per-field columns: with one numpy structured
    array when every element has the same layout (it does when the element's size is a multiple of
    its largest alignment, e.g. Region: 40 + 16·m bytes), else element by element."""

    def __init__(self, sub: MsgCodec):
        if any(kind not in ("prim", "seq") for kind, _ in sub.columns):
            raise NotImplementedError(f"sequence of {sub.name}: only primitive and primitive-sequence fields")
        self.sub = sub
        self._dtypes: dict[tuple, np.dtype | None] = {}

    def _layout(self, start: int, lengths: tuple[int, ...]) -> np.dtype | None:
        """Structured dtype of one element starting at payload offset ``start`` (mod 8), or None
        when consecutive elements would not share it."""
        names, formats, offsets = [], [], []
        o = start
        for i, ((kind, dt), n) in enumerate(zip(self.sub.columns, lengths)):
            size = np.dtype(dt).itemsize
            if kind == "prim":
                o += -o % size
                names.append(f"f{i}"), formats.append(dt), offsets.append(o - start)
                o += size
            else:
                o += -o % 4
                names.append(f"n{i}"), formats.append("<u4"), offsets.append(o - start)
                o += 4
                if n:
                    o += -o % size
                    names.append(f"f{i}"), formats.append((dt, (n,))), offsets.append(o - start)
                    o += size * n
        if (o - start) % 8:
            return None
        return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": o - start})

    def __call__(self, w: Writer, columns) -> None:
        sub = self.sub
        if len(columns) != len(sub.columns):
            raise TypeError(f"{sub.name}[]: {len(columns)} columns for the fields "
                            f"{', '.join(n for _, n in sub.fields)}")
        k = len(columns[0])
        w.u32(k)
        if not k:
            return
        for c, (_, fname) in zip(columns, sub.fields):
            if len(c) != k:
                raise ValueError(f"{sub.name}[].{fname}: {len(c)} values, {k} elements")
        cols, lengths = [], []
        for c, (kind, dt) in zip(columns, sub.columns):
            try:
                a = np.asarray(c, dtype=dt)
            except ValueError:  # sequences of unequal lengths
                a = None
            if a is None or a.ndim != (2 if kind == "seq" else 1):
                dtype = None
                break
            cols.append(a)
            lengths.append(a.shape[1] if kind == "seq" else 0)
        else:
            key = (len(w.b) % 8, tuple(lengths))
            if key not in self._dtypes:
                self._dtypes[key] = self._layout(*key)
            dtype = self._dtypes[key]
        if dtype is None:
            for i in range(k):
                sub.write_fields(w, [c[i] for c in columns])
            return
        arr = np.zeros(k, dtype=dtype)
        for i, (c, (kind, _)) in enumerate(zip(cols, sub.columns)):
            if kind == "seq":
                arr[f"n{i}"] = lengths[i]
                if lengths[i]:
                    arr[f"f{i}"] = c
            else:
                arr[f"f{i}"] = c
        w.b += arr.tobytes()


def _msg_seq_get(sub: MsgCodec) -> Callable[[Reader], list]:
    def get(r: Reader) -> list:
        return [sub.read_fields(r) for _ in range(r.u32())]
    return get


def build_codecs(msg_dir: Path | None = None, names=MESSAGES) -> dict[str, MsgCodec]:
    """One codec per message of ``msg_dir`` (default :func:`find_msg_dir`); nested messages are
    built first, whatever the order of ``names``."""
    msg_dir = Path(msg_dir) if msg_dir is not None else find_msg_dir()
    fields = {n: parse_msg((msg_dir / f"{n}.msg").read_text()) for n in names}
    codecs: dict[str, MsgCodec] = {}

    def build(n: str, seen: tuple = ()) -> None:
        if n in codecs:
            return
        if n in seen:
            raise ValueError(f"recursive message {n}")
        for typ, _ in fields[n]:
            base = typ[:-2] if typ.endswith("[]") else typ
            if base in fields:
                build(base, seen + (n,))
        codecs[n] = MsgCodec(n, fields[n], codecs)

    for n in names:
        build(n)
    return codecs


CODECS = build_codecs()

# The hot-path entry points (the nodes', the recorder's and relearn's).
encode_sample = CODECS["Sample"].encode
decode_sample = CODECS["Sample"].decode
encode_report = CODECS["CompetenceReport"].encode
decode_report = CODECS["CompetenceReport"].decode
encode_region_tree = CODECS["RegionTree"].encode
