"""Reading the rosbag2 (mcap) bags ``sagg run`` records, with rosbags."""
from __future__ import annotations

from pathlib import Path

from sagg_common.params import ConfigError


def open_bag(path: Path):
    # lazy (heavy): rosbags
    from rosbags.rosbag2 import Reader
    if not (path / "metadata.yaml").is_file():
        raise ConfigError(f"bag '{path}': no metadata.yaml; allowed: a rosbag2 directory written by `sagg run` "
                          "(an unfinished one, whose recorder was killed, is recovered by `sagg relearn`, "
                          "`sagg replay` and `sagg run --resume`)")
    reader = Reader(path)
    reader.open()
    return reader


def bag_messages(paths: list[Path], topics: set[str] | None = None):
    """``(topic, msgtype, timestamp_ns, raw)`` of the bags, in order (bag after bag)."""
    for path in paths:
        reader = open_bag(Path(path))
        try:
            conns = [c for c in reader.connections if topics is None or c.topic in topics]
            for conn, ts, raw in reader.messages(connections=conns):
                yield conn.topic, conn.msgtype, ts, raw
        finally:
            reader.close()
