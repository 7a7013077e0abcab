"""Recovering a bag whose recorder was killed (SIGKILL, the OOM killer, a power cut), as
``ros2 bag reindex`` does for rosbag2 (ROS-free).

:class:`~sagg_bringup.bags.recorder.BagWriter` writes ``metadata.yaml`` and the mcap's summary section
only when it closes. A killed recorder leaves ``<bag>/<name>.mcap`` holding the header and the
chunks written so far (rosbags writes a chunk each time 1 MiB of messages is pending; the open
chunk lives in the recorder's memory and dies with it), maybe a torn record at the end, and no
``metadata.yaml``: rosbags' Reader, hence ``sagg relearn``, ``sagg replay`` and ``sagg run
--resume``, refuses the directory.

:func:`recover_bag` reads that mcap with the ``mcap`` library's :class:`StreamReader` (records in file
order; a chunk's records come out only once the whole chunk was read and parsed, and the reader
stops at the first torn or corrupt record), and writes every complete message (topic, type, log
time, bytes: unchanged) with :class:`BagWriter` into a new bag, so the result is what a finished
``sagg run`` bag is: rosbag2 format version 9, mcap with a summary, per-topic counts, the offered
QoS recorded in each channel's metadata, ``topic_type_hash``, ``ros_distro: jazzy``.

The user's bytes are never deleted: the new bag is written into ``<bag>.recovering/`` next to the
bag, then the unfinished mcap is renamed ``<name>.mcap.unfinished`` (the original bytes, kept),
the new mcap takes its place, ``recovered.json`` (what was recovered and lost) is written, and
``metadata.yaml`` comes last: its presence says the bag is complete. A recovery killed at any point
is simply run again (it reads the ``.unfinished`` original if the rename happened); recovering a bag
that has ``metadata.yaml`` does nothing (idempotent).

What is lost, and what can be counted: the bytes after the last complete record (a torn chunk,
whose messages cannot be read by the library; its message count is written only in the message
index records after it and in the summary, neither of which exists), and the messages of the open
chunk that never reached the file (nothing in the file counts them; rosbags writes no per-channel
sequence numbers). For ``sagg run`` bags the checkpoints count those exactly: see
:mod:`.resume_check`. The recorder's ``foreign_messages.json`` (written at close) is lost as well.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Callable

from mcap.records import Channel, DataEnd, Footer, Header, Message, Schema
from mcap.stream_reader import StreamReader

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError

from .recorder import BagWriter, TopicSpec

REPORT_FILE = "recovered.json"
UNFINISHED = ".unfinished"  # suffix of the kept original mcap


def mcap_files(path: Path) -> list[Path]:
    """The mcap files of a bag directory (not the kept ``.unfinished`` original)."""
    return sorted(p for p in path.glob("*.mcap") if p.is_file())


def is_unfinished(path: str | Path) -> bool:
    """A bag directory without ``metadata.yaml`` that holds an mcap (or the ``.unfinished``
    original of an interrupted recovery): a recording whose recorder was killed."""
    path = Path(path)
    return (path.is_dir() and not (path / "metadata.yaml").is_file()
            and bool(mcap_files(path) or list(path.glob(f"*.mcap{UNFINISHED}"))))


def _source(path: Path) -> Path:
    """The mcap to recover from: the ``.unfinished`` original if an earlier recovery renamed it,
    else the directory's one mcap file."""
    kept = sorted(path.glob(f"*.mcap{UNFINISHED}"))
    if len(kept) == 1:
        return kept[0]
    found = mcap_files(path)
    if len(kept) > 1 or len(found) != 1:
        raise ConfigError(f"bag '{path}': {len(found)} mcap file(s) and {len(kept)} kept original(s) "
                          f"without metadata.yaml; allowed: one .mcap file (one rosbag2 mcap storage file)")
    return found[0]


def _qos(metadata: dict) -> list:
    """The offered QoS profiles recorded in a channel's metadata (rosbag2's
    ``offered_qos_profiles`` YAML); [] when absent or unreadable."""
    # lazy (heavy): rosbags
    from rosbags.rosbag2 import ReaderError
    from rosbags.rosbag2.metadata import parse_qos
    text = metadata.get("offered_qos_profiles")
    if not text:
        return []
    try:
        return parse_qos(text)
    except (ReaderError, KeyError, TypeError, ValueError):
        return []


def _known_type(store, name: str, schema) -> bool:
    """Whether ``name`` can be written (registered from the channel's ``ros2msg`` schema text when
    the typestore does not know it)."""
    # lazy (heavy): rosbags
    from rosbags.typesys import get_types_from_msg
    try:
        store.hash_rihs01(name)
        return True
    except KeyError:
        pass
    if schema is None or schema.encoding != "ros2msg":
        return False
    try:
        store.register(get_types_from_msg(schema.data.decode(), name))
        store.hash_rihs01(name)
        return True
    except Exception:  # noqa: BLE001 - a schema the parser rejects: its messages are skipped, counted
        return False


def _read_into(src: Path, bag: BagWriter, rep: dict) -> None:
    """Every complete message of ``src`` into ``bag``, in file order; ``rep`` gets the counts and
    where and why reading stopped."""
    size = src.stat().st_size
    schemas: dict[int, object] = {}
    topics: dict[int, str] = {}  # channel id -> topic
    refused: dict[int, str] = {}  # channel id -> why its messages are skipped
    counts: dict[str, int] = {}
    skipped: dict[str, int] = {}
    good = 0  # the end of the last complete record (bytes read that are usable)
    with open(src, "rb") as f:
        # (a record cannot be longer than the file: a torn length field is refused at once)
        records = iter(StreamReader(f, validate_crcs=True, record_size_limit=max(size, 1)).records)
        while True:
            try:
                rec = next(records)
            except StopIteration:
                rep["stopped"] = "end of the summary section (a finished mcap)"
                break
            except Exception as exc:  # noqa: BLE001 - whatever the reader cannot read is the unreadable tail
                rep["stopped"] = (f"{type(exc).__name__} reading the record at byte {good:,}"
                                  + (f" ({exc})" if str(exc) else " (the file ends inside it)") if good < size
                                  else "end of file (no summary: the recorder did not close the bag)")
                break
            good = f.tell()
            if isinstance(rec, Header):
                rep["profile"], rep["library"] = rec.profile, rec.library
            elif isinstance(rec, Schema):
                schemas.setdefault(rec.id, rec)
            elif isinstance(rec, Channel) and rec.id not in topics and rec.id not in refused:
                schema = schemas.get(rec.schema_id)
                name = schema.name if schema is not None else ""
                if (rec.message_encoding != "cdr" or not _known_type(bag.typestore, name, schema)
                        or bag.types.get(rec.topic, name) != name):
                    refused[rec.id] = (f"{rec.topic}: type {name or '?'!r}, encoding {rec.message_encoding!r}; "
                                       "allowed: cdr of a ROS 2 message type, one type per topic")
                    skipped[refused[rec.id]] = 0
                    continue
                topics[rec.id] = rec.topic
                if rec.topic not in bag.types:
                    bag.add_topic(TopicSpec(rec.topic, name))
                    qos = _qos(dict(rec.metadata))
                    bag.offer(rec.topic, qos)
                    rep["qos_recovered"][rec.topic] = bool(qos)
                    counts[rec.topic] = 0
            elif isinstance(rec, Message):
                topic = topics.get(rec.channel_id)
                if topic is None:
                    key = refused.get(rec.channel_id,
                                      f"channel {rec.channel_id}: no channel record before its messages")
                    skipped[key] = skipped.get(key, 0) + 1
                    continue
                bag.write(topic, rec.log_time, rec.data)
                counts[topic] += 1
                rep["first_ns"] = rec.log_time if rep["first_ns"] is None else min(rep["first_ns"], rec.log_time)
                rep["last_ns"] = rec.log_time if rep["last_ns"] is None else max(rep["last_ns"], rec.log_time)
            elif isinstance(rec, (DataEnd, Footer)):
                rep["stopped"] = "end of the data section (a finished mcap)"
                good = size  # (what follows is the summary: repeated, not data)
                break
    rep.update({"bytes": size, "bytes_read": good, "bytes_unreadable": size - good,
                "messages": sum(counts.values()), "topics": counts, "skipped": skipped})


def recover_bag(path: str | Path, say: Callable[[str], None] | None = None) -> dict | None:
    """Recover the unfinished bag directory ``path`` (see the module doc); returns the recovery
    report (also ``path/recovered.json``), or None when the bag has ``metadata.yaml`` already and was
    never recovered. ``say`` gets one line with the counts."""
    path = Path(path)
    if (path / "metadata.yaml").is_file():
        report = path / REPORT_FILE
        return json.loads(report.read_text()) if report.is_file() else None
    if not is_unfinished(path):
        raise ConfigError(f"bag '{path}': no metadata.yaml and no .mcap file; allowed: a rosbag2 mcap bag directory")
    src = _source(path)
    name = src.name[:-len(UNFINISHED)] if src.name.endswith(UNFINISHED) else src.name
    stem = name[:-len(".mcap")]
    work = path.parent / f"{path.name}.recovering"
    if work.exists():  # an interrupted recovery's output (derived data only): made again
        shutil.rmtree(work)
    work.mkdir()
    rep: dict = {"format": "sagg.bag_recovery/1", "bag": str(path), "file": name,
                 "original": f"{name}{UNFINISHED}", "first_ns": None, "last_ns": None,
                 "qos_recovered": {}}
    bag = BagWriter(work / stem, [])
    try:
        _read_into(src, bag, rep)
    except BaseException:
        bag.abort()
        raise
    bag.close()
    new = work / stem
    if src.name == name:  # keep the original bytes under another name (never deleted)
        os.rename(src, path / rep["original"])
    os.replace(new / name, path / name)
    write_json_atomic(path / REPORT_FILE, rep)
    os.replace(new / "metadata.yaml", path / "metadata.yaml")  # last: the bag is complete
    shutil.rmtree(work)
    if say is not None:
        say(recovery_line(rep))
    return rep


def recovery_line(rep: dict) -> str:
    """One line: what a recovery kept and what it could not read."""
    topics = ", ".join(f"{t} {n:,}" for t, n in sorted(rep["topics"].items(), key=lambda x: -x[1]))
    skipped = sum(rep["skipped"].values())
    return (f"recovered unfinished bag {rep['bag']}: {rep['messages']:,} messages ({topics or 'none'}); "
            f"{rep['bytes_unreadable']:,} of {rep['bytes']:,} bytes after the last complete record unreadable"
            + (f", {skipped:,} messages of unknown types skipped" if skipped else "")
            + f"; the original kept as {rep['original']}")


def recover_run_bags(out: str | Path, say: Callable[[str], None] | None = None) -> list[dict]:
    """Recover every unfinished bag of a run directory (``bag``, ``bag2``, ...); the reports."""
    out = Path(out)
    found = []
    k = 1
    while (bag := out / ("bag" if k == 1 else f"bag{k}")).exists():
        if is_unfinished(bag):
            found.append(recover_bag(bag, say))
        k += 1
    return found
