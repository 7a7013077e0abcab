"""sagg_common.cdr against rclpy's own (de)serialization: our bytes deserialize to the intended
message, and rclpy's bytes decode to the message's values (float64 bit for bit)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from rclpy.serialization import deserialize_message, serialize_message

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from sagg_common import cdr
from sagg_msgs.msg import CompetenceReport, RegionTree, Sample

from joint_state_bytes import encode_joint_state

floats = st.floats(allow_nan=False, width=64)
arrays = st.lists(floats, max_size=9).map(lambda v: np.array(v, dtype=np.float64))
# (no NUL inside strings: ROS strings are NUL-terminated, rclpy cuts them there)
text = st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=12)
names = st.lists(text, max_size=6)
stamps = st.integers(0, 2**31 * 10**9 - 1)
frames = text


def same(a, b) -> bool:
    return np.asarray(a, dtype=np.float64).tobytes() == np.asarray(b, dtype=np.float64).tobytes()


def stamp_of(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


@settings(max_examples=60, deadline=None)
@given(arrays, st.lists(st.tuples(text, st.integers(0, 2**32 - 1)), max_size=3))
def test_float64_multi_array(values, dims):
    msg = deserialize_message(cdr.encode_f64_array(values), Float64MultiArray)
    assert same(msg.data, values) and len(msg.layout.dim) == 0
    theirs = Float64MultiArray()
    theirs.layout.dim = [MultiArrayDimension(label=l, size=s, stride=s) for l, s in dims]
    theirs.layout.data_offset = 3
    theirs.data = values.tolist()
    assert same(cdr.decode_f64_array(serialize_message(theirs)), values)


@settings(max_examples=60, deadline=None)
@given(stamps, frames, names, st.data())
def test_joint_state_both_ways(stamp, frame, joint_names, data):
    n = len(joint_names)
    pos = data.draw(st.lists(floats, min_size=n, max_size=n).map(np.array))
    vel = data.draw(st.lists(floats, min_size=n, max_size=n).map(np.array))
    ours = deserialize_message(encode_joint_state(stamp, frame, joint_names, pos, vel), JointState)
    assert stamp_of(ours) == stamp and ours.header.frame_id == frame
    assert list(ours.name) == joint_names and same(ours.position, pos) and same(ours.velocity, vel)
    assert len(ours.effort) == 0
    if n:
        enc = cdr.JointStateEncoder(joint_names, frame)
        templ = deserialize_message(enc.encode(stamp, pos, vel), JointState)
        assert list(templ.name) == joint_names and same(templ.position, pos) and same(templ.velocity, vel)
        assert stamp_of(templ) == stamp
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    msg.header.frame_id = frame
    msg.name = joint_names
    msg.position = pos.tolist()
    msg.velocity = vel.tolist()
    msg.effort = [1.0] * n
    dec = cdr.JointStateDecoder()
    s, nm, p, v = dec.decode(serialize_message(msg))
    assert s == stamp and list(nm) == joint_names and same(p, pos) and same(v, vel)
    s2, nm2, _, _ = dec.decode(serialize_message(msg))
    assert nm2 is nm  # unchanged names: the cached tuple


def test_joint_state_decoder_notices_new_names():
    dec = cdr.JointStateDecoder()
    _, a, _, _ = dec.decode(encode_joint_state(0, "", ["a", "b"], [1.0, 2.0]))
    _, b, _, _ = dec.decode(encode_joint_state(0, "", ["b", "a"], [1.0, 2.0]))
    assert a == ("a", "b") and b == ("b", "a")


@settings(max_examples=60, deadline=None)
@given(stamps, frames, floats, floats, floats)
def test_point_stamped_both_ways(stamp, frame, x, y, z):
    ours = deserialize_message(cdr.PointStampedEncoder(frame).encode(stamp, x, y, z), PointStamped)
    assert stamp_of(ours) == stamp and ours.header.frame_id == frame
    assert same([ours.point.x, ours.point.y, ours.point.z], [x, y, z])
    msg = PointStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    msg.header.frame_id = frame
    msg.point.x, msg.point.y, msg.point.z = x, y, z
    s, p = cdr.decode_point_stamped(serialize_message(msg))
    assert s == stamp and same(p, [x, y, z])


@settings(max_examples=60, deadline=None)
@given(stamps, st.integers(0, 2**64 - 1), arrays, arrays, arrays)
def test_sample_both_ways(stamp, index, a, da, dy):
    ours = deserialize_message(cdr.encode_sample(stamp, index, a, da, dy), Sample)
    assert stamp_of(ours) == stamp and ours.index == index
    assert same(ours.alpha, a) and same(ours.delta_alpha, da) and same(ours.delta_y, dy)
    msg = Sample(index=index, alpha=a.tolist(), delta_alpha=da.tolist(), delta_y=dy.tolist())
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    s, i, a2, da2, dy2 = cdr.decode_sample(serialize_message(msg))
    assert (s, i) == (stamp, index) and same(a2, a) and same(da2, da) and same(dy2, dy)


@settings(max_examples=60, deadline=None)
@given(stamps, st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1), st.integers(0, 255),
       arrays, arrays, arrays, floats, st.integers(0, 2**64 - 1))
def test_report_both_ways(stamp, seq, goal_seq, kind, target, reached, start, comp, ma):
    ours = deserialize_message(
        cdr.encode_report(stamp, seq, goal_seq, kind, target, reached, start, comp, ma), CompetenceReport)
    assert (stamp_of(ours), ours.seq, ours.goal_seq, ours.kind, ours.micro_actions) == (stamp, seq, goal_seq, kind, ma)
    assert same(ours.target, target) and same(ours.reached, reached) and same(ours.start, start)
    assert same([ours.competence], [comp])
    msg = CompetenceReport(seq=seq, goal_seq=goal_seq, kind=kind, target=target.tolist(),
                           reached=reached.tolist(), start=start.tolist(), competence=comp, micro_actions=ma)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    r = cdr.decode_report(serialize_message(msg))
    assert (r.stamp, r.seq, r.goal_seq, r.kind, r.micro_actions) == (stamp, seq, goal_seq, kind, ma)
    assert same(r.target, target) and same(r.reached, reached) and same(r.start, start)
    assert same([r.competence], [comp])


@settings(max_examples=40, deadline=None)
@given(stamps, frames, st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1), st.integers(0, 2**32 - 1),
       st.integers(1, 4), st.integers(0, 5), st.data())
def test_region_tree(stamp, frame, goals, reports, splits, m, k, data):
    vec = st.lists(floats, min_size=k * m, max_size=k * m).map(lambda v: np.array(v).reshape(k, m))
    lowers, uppers = data.draw(vec), data.draw(vec)
    ids = data.draw(st.lists(st.integers(0, 2**32 - 1), min_size=k, max_size=k))
    counts = data.draw(st.lists(st.integers(0, 2**32 - 1), min_size=k, max_size=k))
    interests = data.draw(st.lists(floats, min_size=k, max_size=k))
    means = data.draw(st.lists(st.floats(width=64), min_size=k, max_size=k))  # NaN allowed
    raw = cdr.encode_region_tree(stamp, frame, goals, reports, splits, ids, lowers.reshape(k, m),
                                 uppers.reshape(k, m), interests, counts, means)
    msg = deserialize_message(raw, RegionTree)
    assert stamp_of(msg) == stamp and msg.header.frame_id == frame
    assert (msg.goals, msg.reports, msg.splits, len(msg.regions)) == (goals, reports, splits, k)
    for i, r in enumerate(msg.regions):
        assert (r.id, r.count) == (ids[i], counts[i])
        assert same(r.lower, lowers[i]) and same(r.upper, uppers[i])
        assert same([r.interest, r.mean_competence], [interests[i], means[i]])
