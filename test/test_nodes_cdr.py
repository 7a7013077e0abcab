"""sagg_common.cdr and sagg_common.msg_codecs against rclpy's own (de)serialization: our bytes
deserialize to the intended message, and rclpy's bytes decode to the message's values (float64 bit
for bit); the codecs built from the .msg files give the bytes of the hand-written codecs they
replaced (bags written before still read), and follow a .msg when it is edited."""
from __future__ import annotations

import inspect

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from rclpy.serialization import deserialize_message, serialize_message

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from sagg_common import cdr, msg_codecs
from sagg_msgs.msg import CompetenceReport, Evaluation, Goal, LearnerStatus, Region, RegionTree, Sample

from sagg_common.cdr import encode_joint_state

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
    ours = deserialize_message(msg_codecs.encode_sample(stamp, index, a, da, dy), Sample)
    assert stamp_of(ours) == stamp and ours.index == index
    assert same(ours.alpha, a) and same(ours.delta_alpha, da) and same(ours.delta_y, dy)
    msg = Sample(index=index, alpha=a.tolist(), delta_alpha=da.tolist(), delta_y=dy.tolist())
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    s, i, a2, da2, dy2 = msg_codecs.decode_sample(serialize_message(msg))
    assert (s, i) == (stamp, index) and same(a2, a) and same(da2, da) and same(dy2, dy)


@settings(max_examples=60, deadline=None)
@given(stamps, st.integers(0, 2**64 - 1), st.integers(0, 2**64 - 1), st.integers(0, 255),
       arrays, arrays, arrays, floats, st.integers(0, 2**64 - 1))
def test_report_both_ways(stamp, seq, goal_seq, kind, target, reached, start, comp, ma):
    ours = deserialize_message(
        msg_codecs.encode_report(stamp, seq, goal_seq, kind, target, reached, start, comp, ma), CompetenceReport)
    assert (stamp_of(ours), ours.seq, ours.goal_seq, ours.kind, ours.micro_actions) == (stamp, seq, goal_seq, kind, ma)
    assert same(ours.target, target) and same(ours.reached, reached) and same(ours.start, start)
    assert same([ours.competence], [comp])
    msg = CompetenceReport(seq=seq, goal_seq=goal_seq, kind=kind, target=target.tolist(),
                           reached=reached.tolist(), start=start.tolist(), competence=comp, micro_actions=ma)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    r = msg_codecs.decode_report(serialize_message(msg))
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
    raw = msg_codecs.encode_region_tree(stamp, goals, reports, splits,
                                        (ids, lowers.reshape(k, m), uppers.reshape(k, m), interests, counts, means),
                                        frame_id=frame)
    msg = deserialize_message(raw, RegionTree)
    assert stamp_of(msg) == stamp and msg.header.frame_id == frame
    assert (msg.goals, msg.reports, msg.splits, len(msg.regions)) == (goals, reports, splits, k)
    for i, r in enumerate(msg.regions):
        assert (r.id, r.count) == (ids[i], counts[i])
        assert same(r.lower, lowers[i]) and same(r.upper, uppers[i])
        assert same([r.interest, r.mean_competence], [interests[i], means[i]])


# ------------------------------------------------ the codecs built from the .msg files (msg_codecs)
# Bytes of the hand-written sagg_msgs codecs of commit cb9d36b (sagg_common/cdr.py before the codecs
# were built from the .msg files) for the inputs of GOLDEN_INPUTS: the generated codecs must give
# the same bytes, so the bags recorded before still read the same.
_A = np.array([0.1 + 0.2, -0.0, 1e-300, np.inf, -np.inf, 1.5, -2.25, 3.0])
_Y = np.array([12.5, -7.0])
_LO = np.array([[0.0, -150.0], [75.0, -150.0], [0.0, 0.5]])
_LO3 = np.arange(9.0).reshape(3, 3)
GOLDEN = [
    (lambda: msg_codecs.encode_sample(1_700_000_000_999_999_999, 41, _A, _A[::-1] * 1e-3, _Y, frame_id="task"),
     "0001000000f15365ffc99a3b050000007461736b000000000000000029000000000000000800000000000000343333333333d33f"
     "000000000000008059f3f8c21f6ea501000000000000f07f000000000000f0ff000000000000f83f00000000000002c000000000"
     "000008400800000000000000fa7e6abc7493683f3cdf4f8d976e62bffa7e6abc7493583f000000000000f0ff000000000000f07f"
     "c4110582caf105010000000000000080623255302aa9333f020000000000000000000000000029400000000000001cc0"),
    (lambda: msg_codecs.encode_sample(5, 0, _A[:3], np.zeros(0), _Y),
     "000100000000000005000000010000000000000000000000000000000300000000000000343333333333d33f0000000000000080"
     "59f3f8c21f6ea501000000000200000000000000000029400000000000001cc0"),
    (lambda: msg_codecs.encode_report(1_700_000_000_000_000_001, 9, 8, 2, (), _Y, _Y[::-1], -0.0, 2**64 - 1,
                                      frame_id="x"),
     "0001000000f15365010000000200000078000000090000000000000008000000000000000200000000000000020000000000000000"
     "000000000029400000000000001cc002000000000000000000000000001cc000000000000029400000000000000080ffffffffffff"
     "ffff"),
    (lambda: msg_codecs.encode_report(3, 1, 1, 0, _Y, _Y, _Y, -1.25, 77),
     "00010000000000000300000001000000000000000100000000000000010000000000000000000000020000000000000000002940"
     "0000000000001cc0020000000000000000000000000029400000000000001cc0020000000000000000000000000029400000000000"
     "001cc0000000000000f4bf4d00000000000000"),
    (lambda: msg_codecs.encode_region_tree(123, 60, 59, 2, ([1, 4, 5], _LO, _LO + 10.0, [0.5, 0.0, 1e-9], [3, 0, 7],
                                                            [-0.5, np.nan, -0.125]), frame_id="task_space"),
     "00010000000000007b0000000b0000007461736b5f737061636500003c000000000000003b00000000000000020000000300000001"
     "0000000200000000000000000000000000000000c062c00200000000000000000000000000244000000000008061c0000000000000"
     "e03f0300000000000000000000000000e0bf04000000020000000000000000c052400000000000c062c00200000000000000000000"
     "000040554000000000008061c000000000000000000000000000000000000000000000f87f050000000200000000000000000000"
     "00000000000000e03f02000000000000000000000000002440000000000000254095d626e80b2e113e07000000000000000000"
     "00000000c0bf"),
    (lambda: msg_codecs.encode_region_tree(123, 1, 0, 0, ([], np.zeros((0, 2)), np.zeros((0, 2)), [], [], []),
                                           frame_id="ts"),
     "00010000000000007b0000000300000074730000010000000000000000000000000000000000000000000000"),
    (lambda: msg_codecs.encode_region_tree(7, 2, 3, 1, ([0, 1, 2], _LO3, _LO3 + 1, [1.0, 2.0, 3.0], [1, 2, 3],
                                                        [0.0, -1.0, -2.0]), frame_id="abc"),
     "000100000000000007000000040000006162630002000000000000000300000000000000010000000300000000000000030000000000"
     "000000000000000000000000f03f00000000000000400300000000000000000000000000f03f000000000000004000000000000008"
     "40000000000000f03f0100000000000000000000000000000001000000030000000000000000000840000000000000104000000000"
     "0000144003000000000000000000000000001040000000000000144000000000000018400000000000000040020000000000000000"
     "0000000000f0bf020000000300000000000000000018400000000000001c4000000000000020400300000000000000000000000000"
     "1c40000000000000204000000000000022400000000000000840030000000000000000000000000000c0"),
]


@pytest.mark.parametrize("i", range(len(GOLDEN)))
def test_generated_codecs_give_the_hand_written_bytes(i):
    make, hexbytes = GOLDEN[i]
    assert make().hex() == hexbytes


def _rclpy_values():
    """One rclpy message per sagg_msgs message, every field set to a non-default value."""
    def hdr(msg, frame="f"):
        msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000, 123
        msg.header.frame_id = frame
        return msg
    region = Region(id=7, lower=[0.0, -1.5], upper=[2.0, 0.1 + 0.2], interest=0.25, count=9, mean_competence=-0.0)
    return {
        "Goal": hdr(Goal(seq=2**64 - 1, after_report=5, mode=3, position=[1.0, -2.0, 0.5])),
        "CompetenceReport": hdr(CompetenceReport(seq=1, goal_seq=2, kind=3, target=[], reached=[1.0, 2.0],
                                                 start=[0.0, 0.5], competence=-1.5, micro_actions=99)),
        "Region": region,
        "RegionTree": hdr(RegionTree(goals=3, reports=4, splits=1, regions=[region, Region(id=8, lower=[1.0])])),
        "Sample": hdr(Sample(index=4, alpha=[0.1, 0.2], delta_alpha=[], delta_y=[-1.0, 1.0])),
        "LearnerStatus": hdr(LearnerStatus(strategy="SAGG-RIAC", micro_actions=10, goals=2, samples=9,
                                           last_competence=-0.5, micro_actions_per_second=0.1 + 0.2,
                                           paused=True, pause_reason="waiting \u00e9"), frame=""),
        "Evaluation": hdr(Evaluation(micro_actions=5000, mean_error=1.25, median_error=0.5, errors=[0.5, 2.0])),
    }


def _values_of(msg):
    """The arguments of msg_codecs' encoder for an rclpy message (Header -> stamp ns, nested
    sequence -> columns)."""
    out = []
    for name, typ in msg.get_fields_and_field_types().items():
        v = getattr(msg, name)
        if typ == "std_msgs/Header":
            out.append(stamp_of(msg))
        elif typ.startswith("sequence<sagg_msgs/"):
            sub = msg_codecs.CODECS[typ[len("sequence<sagg_msgs/"):-1]]
            cols = [[getattr(e, n) for e in v] for _, n in sub.fields]
            out.append(tuple(cols))
        else:
            out.append(v)
    return out


def test_every_message_codec_against_rclpy():
    """Every sagg_msgs message: rclpy's bytes decode to its fields; our encoder's bytes deserialize
    (rclpy) to the message (the Region[] with unequal bound lengths goes the element-by-element
    way). Bytes are not compared with rclpy's: its padding bytes are not zeroed."""
    msgs = _rclpy_values()
    assert set(msgs) == set(msg_codecs.MESSAGES) == set(msg_codecs.CODECS)
    for name, msg in msgs.items():
        codec = msg_codecs.CODECS[name]
        theirs = serialize_message(msg)
        ours = codec.encode(*_values_of(msg), **({"frame_id": msg.header.frame_id} if codec.has_header else {}))
        assert deserialize_message(ours, type(msg)) == msg, name
        dec = codec.decode(theirs)
        for (typ, field), got in zip(codec.fields, dec):
            want = getattr(msg, field)
            if typ == "std_msgs/Header":
                assert got == stamp_of(msg)
            elif typ.endswith("[]") and typ != "float64[]":
                assert [tuple(map(float, e.lower)) for e in got] == [tuple(e.lower) for e in want]
            elif isinstance(want, float) or typ == "float64[]":
                assert same(got, want), (name, field)
            else:
                assert got == want, (name, field)


def test_codecs_follow_an_edited_msg(tmp_path):
    """A field added to a .msg (a temporary copy of sagg_msgs/msg) is in the codecs built from it:
    the encoder asks for it (the old argument list fails), and its bytes are what rosbags'
    independent parser and deserializer make of the edited definition."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    src = msg_codecs.find_msg_dir()
    for f in src.glob("*.msg"):
        (tmp_path / f.name).write_text(f.read_text())
    (tmp_path / "Sample.msg").write_text((src / "Sample.msg").read_text().replace(
        "uint64 index", "uint64 index\nuint32 COUNT_MAX=7  # a constant\nfloat32 weight  # new\nint16[] tags"))
    (tmp_path / "Region.msg").write_text((src / "Region.msg").read_text() + "uint8 depth\n")
    codecs = msg_codecs.build_codecs(tmp_path)
    sample, tree = codecs["Sample"], codecs["RegionTree"]
    assert [n for _, n in sample.fields] == ["header", "index", "weight", "tags", "alpha", "delta_alpha", "delta_y"]
    assert list(inspect.signature(sample.encode).parameters) == [
        "stamp_ns", "index", "weight", "tags", "alpha", "delta_alpha", "delta_y", "frame_id"]
    with pytest.raises(TypeError, match="missing 2 required positional arguments"):
        sample.encode(5, 1, [1.0], [2.0], [3.0])
    raw = sample.encode(5, 1, 0.5, [3, -4], [1.0], [2.0], [3.0], frame_id="fr")
    lo = np.array([[0.0, 1.0], [2.0, 3.0]])
    raw_tree = tree.encode(9, 1, 2, 3, ([1, 2], lo, lo + 1, [0.5, 0.25], [4, 5], [-1.0, -2.0], [1, 2]))
    with pytest.raises(TypeError, match="depth"):
        tree.encode(9, 1, 2, 3, ([1, 2], lo, lo + 1, [0.5, 0.25], [4, 5], [-1.0, -2.0]))
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for name in msg_codecs.MESSAGES:
        types.update(get_types_from_msg((tmp_path / f"{name}.msg").read_text(), f"sagg_msgs/msg/{name}"))
    store.register(types)
    s = store.deserialize_cdr(raw, "sagg_msgs/msg/Sample")
    assert (s.header.frame_id, s.index, s.weight, list(s.tags)) == ("fr", 1, 0.5, [3, -4])
    assert list(s.alpha) == [1.0] and list(s.delta_y) == [3.0]
    assert store.serialize_cdr(s, "sagg_msgs/msg/Sample") == raw
    t = store.deserialize_cdr(raw_tree, "sagg_msgs/msg/RegionTree")
    assert [(r.id, list(r.upper), r.count, r.depth) for r in t.regions] == [(1, [1.0, 2.0], 4, 1),
                                                                            (2, [3.0, 4.0], 5, 2)]
    assert store.serialize_cdr(t, "sagg_msgs/msg/RegionTree") == raw_tree
    back = sample.decode(raw)
    assert (back.stamp, back.index, back.weight, list(back.tags)) == (5, 1, 0.5, [3, -4])
    # the codecs of the unedited .msg files do not read the edited layout as the edited fields
    try:
        unedited = msg_codecs.decode_sample(raw).alpha.tolist()
    except ValueError:
        unedited = None
    assert unedited != [1.0]
