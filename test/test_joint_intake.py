"""The one /joint_states reader (sagg_common.joint_intake): each rule once, with the field, value and
range it names; and every reader of the arm's joint states (learner, fixed-context position link,
the external run's driver monitor, check-driver) goes through it."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState

from sagg_common import joint_intake as ji
from sagg_low_level.schema import LEARNER_SCHEMA, joint_intake

ROOT = Path(__file__).resolve().parents[1]
SEC = 1_000_000_000
JOINTS = ["a", "b", "c"]


def js(pos, vel=(), ns=SEC, names=JOINTS) -> bytes:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(ns), SEC)
    m.name, m.position, m.velocity = list(names), [float(p) for p in pos], [float(v) for v in vel]
    return serialize_message(m)


def intake(**rules) -> ji.JointStateIntake:
    p = {q.name: q.default for q in LEARNER_SCHEMA}
    p.update(rules)
    return joint_intake(p, JOINTS, [-1.0] * 3, [1.0] * 3)


def test_a_valid_message_in_any_order_is_the_newest_reading():
    it = intake()
    v = it.take(js([0.3, 0.1, 0.2], [0.0, 0.0, 0.01], names=["c", "a", "b"]), seq=1)
    assert v.code == ji.TAKEN and not v.kind
    np.testing.assert_array_equal(it.position, [0.1, 0.2, 0.3])
    assert it.stamp == SEC and it.settled
    assert it.take(js([0.1, 0.2, 0.3], [0.0, 0.2, 0.0], ns=2 * SEC), seq=2).code == ji.TAKEN
    assert not it.settled  # 0.2 rad/s > settle_velocity (0.05)
    assert it.take(js([0.1, 0.2, 0.3], ns=3 * SEC), seq=3).code == ji.TAKEN
    assert it.settled and it.velocity is None  # no velocities: settled


@pytest.mark.parametrize("data, kind, words", [
    (b"\x00\x01\x00\x00garbage", "joint_states.undecodable", "undecodable"),
    (js([0.1, 0.2], names=JOINTS), "joint_states.length", "3 names but 2 positions"),
    (js([0.1, 0.2, 0.3], [0.0]), "joint_states.length", "1 velocities"),
    (js([0.1, 0.2, 0.3, 0.4], names=["a", "b", "c", "a"]), "joint_states.names", "names a joint twice"),
    (js([0.1, 0.2], names=["a", "b"]), "joint_states.names", "lacks joint(s) c"),
    (js([0.1, float("nan"), 0.3]), "joint_states.non_finite", "of b"),
    (js([0.1, 0.2, 0.3], [0.0, float("inf"), 0.0]), "joint_states.non_finite", "of b"),
    (js([0.1, 1.5, 0.3]), "joint_states.out_of_limits", "position of b = 1.5 rad; allowed: [-1.1, 1.1]"),
    (js([0.1, 0.2, 0.3], [0.0, 0.0, -2000.0]), "joint_states.velocity", "velocity of c = -2000.0"),
])
def test_bad_content_is_rejected_by_name_and_changes_nothing(data, kind, words):
    it = intake()
    assert it.take(js([0.1, 0.2, 0.3]), seq=1).code == ji.TAKEN
    before = (it.position.copy(), it.stamp, it.track.newest)
    v = it.take(data, seq=2)
    assert (v.code, v.kind) == (ji.REJECTED, kind) and words in v.message, v.message
    assert np.array_equal(it.position, before[0]) and (it.stamp, it.track.newest) == before[1:]
    # not taken for its content: no gap in its publisher's chain (the next one is taken)
    assert it.take(js([0.1, 0.2, 0.3], ns=2 * SEC), seq=3).code == ji.TAKEN


def test_another_drivers_joints_are_ignored_and_counted():
    it = intake()
    assert it.take(js([0.5], names=["gripper"]), seq=1).code == ji.OTHER
    assert it.take(js([0.5], names=["gripper"]), seq=2).code == ji.OTHER
    assert it.other_joints == {("gripper",): 2} and it.position is None
    assert it.take(js([0.1, 0.2, 0.3]), seq=3).code == ji.TAKEN  # (its numbers are no gap)


def test_one_source_a_gap_and_a_second_source():
    it = intake(**{"plausibility.source_grace": 0.5})
    assert it.take(js([0.1, 0.2, 0.3]), seq=10, now=0.0).code == ji.TAKEN
    assert it.take(js([0.1, 0.2, 0.3], ns=2 * SEC), seq=12, now=0.1).code == ji.GAP
    assert it.take(js([0.1, 0.2, 0.3], ns=3 * SEC), seq=13, now=0.2).code == ji.TAKEN
    assert it.take(js([0.9, 0.9, 0.9], ns=4 * SEC), seq=1, now=0.3).code == ji.AMBIGUOUS  # another publisher
    assert it.take(js([0.1, 0.2, 0.3], ns=5 * SEC), seq=14, now=0.4).code == ji.AMBIGUOUS
    assert it.stamp == 3 * SEC
    assert it.take(js([0.1, 0.2, 0.3], ns=6 * SEC), seq=15, now=1.0).code == ji.TAKEN  # the other went quiet
    off = intake(**{"plausibility.check_sources": False})
    assert off.take(js([0.1, 0.2, 0.3]), seq=10).code == off.take(js([0.1, 0.2, 0.3]), seq=1).code == ji.TAKEN


def test_stamps_out_of_order_in_the_future_and_a_clock_jump_back():
    it = intake(**{"plausibility.resync_after": 3, "plausibility.future_tolerance": 5.0})
    assert it.take(js([0.1, 0.2, 0.3], ns=100 * SEC), seq=1).code == ji.TAKEN
    v = it.take(js([0.1, 0.2, 0.3], ns=99 * SEC), seq=2)
    assert (v.code, v.kind) == (ji.OUT_OF_ORDER_STAMP, "joint_states.out_of_order")
    v = it.take(js([0.1, 0.2, 0.3], ns=200 * SEC), seq=3)
    assert (v.code, v.kind) == (ji.FUTURE_STAMP, "joint_states.future_stamp") and it.stamp == 100 * SEC
    it.take(js([0.1, 0.2, 0.3], ns=50 * SEC), seq=4)
    v = it.take(js([0.4, 0.2, 0.3], ns=51 * SEC), seq=5)  # the 3rd older one in a row: a restart
    assert (v.code, v.kind) == (ji.TAKEN, "joint_states.clock_jump_back") and it.stamp == 51 * SEC
    assert "re-synchronised" in v.message and it.position[0] == 0.4


def test_every_reader_of_joint_states_uses_the_intake():
    """No JointState is decoded anywhere else in the product (one rule set, one place to change
    it; the lab's fuzzer watches the bridge's stamps for its own bookkeeping)."""
    readers = []
    for path in sorted(p for p in (ROOT / "src").rglob("*.py") if "sagg_lab" not in p.parts):
        text = path.read_text()
        if re.search(r"JointStateDecoder\(\)|\.decoder\.decode\(|msg\.position\b|msg\.name\b", text):
            readers.append(path.relative_to(ROOT).as_posix())
    assert readers == ["src/sagg_common/sagg_common/joint_intake.py"], readers
    for path in ("src/sagg_low_level/sagg_low_level/node.py", "src/sagg_low_level/sagg_low_level/position_link.py",
                 "src/sagg_bringup/sagg_bringup/graph/driver_monitor.py"):
        assert "joint_intake(" in (ROOT / path).read_text(), path
    assert "DriverMonitor(lp" in (ROOT / "src/sagg_bringup/sagg_bringup/graph/check_driver.py").read_text()
