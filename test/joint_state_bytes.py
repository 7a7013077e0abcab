"""Test helper: sensor_msgs/JointState bytes written with sagg_common.cdr's Writer (input for the
nodes' joint-state decoders; the nodes never write joint states this way)."""
from __future__ import annotations

from sagg_common.cdr import Writer


def encode_joint_state(stamp_ns: int, frame_id: str, names, position, velocity=(), effort=()) -> bytes:
    w = Writer()
    w.header(stamp_ns, frame_id)
    w.strings(list(names))
    w.f64_seq(position)
    w.f64_seq(velocity)
    w.f64_seq(effort)
    return w.tobytes()
