"""``topic_type_hash`` on every mcap channel of a bag, as ``ros2 bag record`` (Jazzy) writes it.

rosbag2's mcap storage (Jazzy) gives each channel two metadata entries: ``offered_qos_profiles``
and ``topic_type_hash`` (the type's RIHS01 hash, REP-2016). rosbags (0.11.9, the newest release)
writes only the first: its ``McapWriter.add_connection`` builds the channel metadata from
``offered_qos_profiles`` alone, and ``Writer.add_connection`` offers no other channel metadata
(the hash goes to metadata.yaml's ``type_description_hash`` only). So, after rosbags has closed
the bag, :func:`add_type_hashes` rewrites its mcap file record by record with the ``mcap``
library's public reader and writer: the same header, schemas, messages (order, times, sequence
numbers, bytes), metadata records and chunking without compression, each channel's metadata plus
``topic_type_hash``. metadata.yaml (rosbags') is unchanged: it describes the same messages.

The same pass sets ``ros_distro`` in the mcap's own copy of the bag information (the ``rosbag2``
metadata record, ``serialized_metadata``), where rosbags writes its own name: with ``distro``,
the file says what metadata.yaml says (the recorder sets ``jazzy`` there).
"""
from __future__ import annotations

import os
from pathlib import Path

from mcap.reader import make_reader
from mcap.records import Channel, DataEnd, Footer, Header, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
import yaml


def add_type_hashes(mcap_path: str | Path, hashes: dict[str, str], distro: str | None = None) -> int:
    """Rewrite ``mcap_path`` with ``topic_type_hash = hashes[topic]`` on each channel whose topic
    is in ``hashes`` (others unchanged) and, with ``distro``, the ``rosbag2`` metadata record's
    ``ros_distro``. Returns the number of channels given a hash. The file is replaced atomically
    (written next to it, then renamed)."""
    src = Path(mcap_path)
    tmp = src.with_name(src.name + ".tmp")
    schema_ids: dict[int, int] = {}
    channel_ids: dict[int, int] = {}
    hashed = 0
    with open(src, "rb") as fin, open(tmp, "wb") as fout:
        writer = None
        for rec in StreamReader(fin).records:
            if isinstance(rec, Header):
                writer = Writer(fout, compression=CompressionType.NONE)
                writer.start(profile=rec.profile, library=rec.library)
            elif isinstance(rec, Schema):
                if rec.id not in schema_ids:  # (the summary section repeats them)
                    schema_ids[rec.id] = writer.register_schema(rec.name, rec.encoding, rec.data)
            elif isinstance(rec, Channel):
                if rec.id not in channel_ids:
                    meta = dict(rec.metadata)
                    if rec.topic in hashes:
                        meta["topic_type_hash"] = hashes[rec.topic]
                        hashed += 1
                    channel_ids[rec.id] = writer.register_channel(
                        rec.topic, rec.message_encoding, schema_ids.get(rec.schema_id, 0), meta)
            elif isinstance(rec, Message):
                writer.add_message(channel_ids[rec.channel_id], rec.log_time, rec.data, rec.publish_time,
                                   rec.sequence)
            elif isinstance(rec, Metadata):
                meta = dict(rec.metadata)
                if distro is not None and rec.name == "rosbag2" and "serialized_metadata" in meta:
                    info = yaml.safe_load(meta["serialized_metadata"])
                    info["ros_distro"] = distro
                    meta["serialized_metadata"] = yaml.safe_dump(info, sort_keys=False)
                writer.add_metadata(rec.name, meta)
            elif isinstance(rec, (DataEnd, Footer)):
                break  # the summary section is written anew
        if writer is None:
            raise ValueError(f"'{src}' is not an mcap file (no header record)")
        writer.finish()
    os.replace(tmp, src)
    return hashed


def channel_metadata(mcap_path: str | Path) -> dict[str, dict[str, str]]:
    """Each channel's metadata by topic (what ``ros2 bag info``-like tools read)."""
    with open(mcap_path, "rb") as f:
        summary = make_reader(f).get_summary()
    return {c.topic: dict(c.metadata) for c in summary.channels.values()}
