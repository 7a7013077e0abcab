"""Write-ahead journal and atomic checkpoint files (ROS-free), for checkpoint / resume.

A :class:`Journal` is an append-only binary file of records, each written with one ``os.write`` on
an ``O_APPEND`` descriptor *before* the state change it records is published (write-ahead). After a
SIGKILL every record whose ``write`` returned is in the file (the kernel's page cache outlives the
process); ``fsync=True`` also survives a power cut, at the cost of one disk flush per record.

Record layout (little-endian)::

    magic u32 (0x5341474A, "SAGJ") | kind u8 | count u32 | count float64 values | crc32 u32

The crc covers kind, count and the values. Payloads are float64 vectors: integers below 2**53
(indices, sequence numbers, counters) are exact in float64, and float64 data travel bit for bit.
:func:`read_journal` returns the complete records and stops at the first torn or corrupt one (a
process killed in the middle of a ``write`` leaves at most one torn record, at the end).

Checkpoint generations: a component saving generation ``g`` writes its files under names with
``g`` in them, then the JSON that points at them (:func:`write_json_atomic`, temporary file +
``os.replace``), so a crash at any moment leaves the previous complete generation in place.
"""
from __future__ import annotations

import json
import os
import re
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np

MAGIC = 0x5341474A
_HEAD = struct.Struct("<IBI")
_CRC = struct.Struct("<I")


class Journal:
    """An open journal file (appending)."""

    def __init__(self, path: str | Path, fsync: bool = False):
        self.path = Path(path)
        self.fsync = bool(fsync)
        self.fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self.records = 0

    def append(self, kind: int, values) -> None:
        """Write one record (``kind`` in [0, 255], ``values`` a float64 vector) in one write."""
        if not 0 <= int(kind) <= 255:
            raise ValueError(f"journal record kind: got {kind}; allowed: an integer in [0, 255]")
        body = np.ascontiguousarray(values, dtype="<f8").tobytes()
        head = _HEAD.pack(MAGIC, int(kind), len(body) // 8)
        crc = zlib.crc32(body, zlib.crc32(head[4:]))
        os.write(self.fd, head + body + _CRC.pack(crc))
        if self.fsync:
            os.fsync(self.fd)
        self.records += 1

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


def read_journal(path: str | Path) -> tuple[list[tuple[int, np.ndarray]], int]:
    """``(records, torn_bytes)``: every complete record as ``(kind, float64 values)``, in order,
    and the number of trailing bytes dropped (a torn or corrupt record and what follows it)."""
    try:
        data = Path(path).read_bytes()
    except FileNotFoundError:
        return [], 0
    out = []
    pos = 0
    while pos + _HEAD.size <= len(data):
        magic, kind, count = _HEAD.unpack_from(data, pos)
        end = pos + _HEAD.size + 8 * count
        if magic != MAGIC or end + _CRC.size > len(data):
            break
        body = data[pos + _HEAD.size:end]
        (crc,) = _CRC.unpack_from(data, end)
        if crc != zlib.crc32(body, zlib.crc32(data[pos + 4:pos + _HEAD.size])):
            break
        out.append((kind, np.frombuffer(body, dtype="<f8").astype(np.float64)))
        pos = end + _CRC.size
    return out, len(data) - pos


class GenerationFiles:
    """The numbered files of a checkpoint directory: ``<prefix>_<kind>_<g>.npz`` for the kinds in
    ``npz_kinds``, ``.bin`` (journals) for the others. Subclasses set ``dir``, ``prefix`` and
    ``npz_kinds``."""

    dir: Path
    prefix: str
    npz_kinds: tuple[str, ...] = ()

    def _path(self, kind: str, g: int) -> Path:
        return self.dir / f"{self.prefix}_{kind}_{g}.{'npz' if kind in self.npz_kinds else 'bin'}"

    def _generations(self, kind: str) -> list[int]:
        pat = re.compile(rf"{self.prefix}_{kind}_(\d+)\.(npz|bin)$")
        return sorted(int(m.group(1)) for p in self.dir.iterdir() if (m := pat.match(p.name)))

    def _prune(self, kind: str, below: int) -> None:
        """Delete the files of ``kind`` older than generation ``below``."""
        for k in self._generations(kind):
            if k < below:
                self._path(kind, k).unlink(missing_ok=True)


def write_json_atomic(path: str | Path, data: Any, compact: bool = False) -> None:
    """JSON to ``path`` atomically: temporary file in the same folder, fsync, ``os.replace``.
    One value per line (readable, diffable), or with ``compact`` on one line without spaces."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as fh:
        if compact:
            json.dump(data, fh, separators=(",", ":"), allow_nan=True)
        else:
            json.dump(data, fh, indent=1, allow_nan=True)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def save_npz_atomic(path: str | Path, **arrays) -> None:
    """An .npz (no pickle) written to a temporary file, fsynced, then renamed onto ``path``."""
    path = os.fspath(path)
    tmp = path + ".tmp.npz"
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def rng_state(rng: np.random.Generator) -> dict:
    """A Generator's bit-generator state as JSON-able data (``bit_generator.state``)."""
    return rng.bit_generator.state


def restore_rng(rng: np.random.Generator, state: dict) -> None:
    """Set a Generator's state from :func:`rng_state` output (same bit generator required)."""
    name = type(rng.bit_generator).__name__
    if state.get("bit_generator") != name:
        raise ValueError(f"rng state: bit generator {state.get('bit_generator')!r}; allowed: {name!r}")
    rng.bit_generator.state = state
