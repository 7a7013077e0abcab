"""On a real robot's ROS graph nothing legitimate stalls learning, nothing jumps.

Sources told apart by the publishers' sequence numbers (sagg_common.sources), the learner's
/joint_states by joint (a gripper driver's messages are ignored), holds that name the second
source and end by themselves, an idle publisher that changes nothing, recorders told apart by
their publishers, and the return to rest in steps of max_joint_step. The nodes are built in this
process (test_bad_input.arm_nodes: their own rclpy context and parameter file) and their callbacks
are called with the message info a subscription hands them.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
import rclpy

from sensor_msgs.msg import JointState
from std_msgs.msg import UInt64

from sagg_common.sources import ACCEPT, AMBIGUOUS, GAP, SourceChains, with_message_info
from sagg_low_level.learner import Command, Robot, step_toward
from sagg_low_level.recorder_acks import RecorderAcks
from test_bad_input import arm_nodes
from test_hostile import JOINTS, LIMIT, SEC, fresh_streams, js_bytes, state, tip_bytes, wait_for
from installed import SAGG

GRACE = 0.4


def info(seq: int) -> dict:
    return {"publication_sequence_number": seq, "source_timestamp": time.time_ns()}


# ------------------------------------------------------------------ SourceChains
def test_one_source_is_accepted_and_a_gap_is_not_taken_but_its_next_message_is():
    c = SourceChains(grace=10.0)
    assert [c.classify(s, 0.1 * s) for s in (40, 41, 42)] == [ACCEPT] * 3  # (the stream's first chain)
    assert c.classify(45, 4.5) == GAP            # numbers skipped: not taken ...
    assert c.classify(46, 4.6) == ACCEPT         # ... the chain's next message is
    assert c.classify(None, 5.0) == ACCEPT       # an rmw without numbers: nothing can be told apart
    assert c.gaps == 1 and c.episodes == 0


def test_a_second_source_makes_the_stream_ambiguous_until_it_has_been_quiet_for_grace():
    c = SourceChains(grace=1.0)
    assert c.classify(100, 0.0) == ACCEPT
    assert c.classify(101, 0.1) == ACCEPT
    assert c.classify(1, 0.2) == AMBIGUOUS       # another publisher (its numbers start at 1)
    assert c.classify(102, 0.3) == AMBIGUOUS     # the real one too: which is real cannot be told
    assert c.classify(2, 0.4) == AMBIGUOUS
    assert c.classify(103, 1.0) == AMBIGUOUS and c.ambiguous(1.3)
    assert not c.ambiguous(1.41)                 # grace after the second source's last message
    assert c.classify(104, 1.5) == ACCEPT        # learning resumes by itself
    assert c.episodes == 1


def test_a_second_publisher_with_higher_numbers_never_passes_as_ours():
    # its first message looks like a gap of our chain: not taken; our next one then starts a chain
    # of its own while the other is live: ambiguous
    c = SourceChains(grace=1.0)
    assert c.classify(10, 0.0) == ACCEPT
    assert c.classify(5000, 0.1) == GAP
    assert c.classify(11, 0.2) == AMBIGUOUS
    assert c.classify(5001, 0.3) == AMBIGUOUS
    assert c.classify(12, 1.4) == ACCEPT         # the other went quiet at 0.3


def test_a_live_chain_passing_a_silent_ones_numbers_keeps_its_messages():
    # seen in the hostile bench: a second publisher's burst left a silent chain at some number;
    # when ours reached that number too, its next message went to the silent chain, which came
    # alive again: a false second source
    c = SourceChains(grace=1.0)
    assert [c.classify(k, 0.01 * (k - 100)) for k in range(100, 106)] == [ACCEPT] * 6
    for k in range(1, 301):                          # another publisher's burst, numbered 1..300
        assert c.classify(k, 0.1 + 0.001 * k) == AMBIGUOUS
    for k in range(106, 111):                        # ours meanwhile: refused too
        assert c.classify(k, 0.4) == AMBIGUOUS
    verdicts = [c.classify(k, 2.0 + 0.01 * (k - 111)) for k in range(111, 400)]   # ours, past 300
    assert verdicts == [ACCEPT] * len(verdicts) and c.episodes == 1


def test_a_restarted_publisher_is_taken_again_after_grace():
    c = SourceChains(grace=1.0)
    for s in range(1, 50):
        assert c.classify(s, 0.01 * s) == ACCEPT
    assert c.classify(1, 0.6) == AMBIGUOUS       # numbers start again: a restart or another publisher
    assert c.classify(2, 0.7) == AMBIGUOUS
    assert c.classify(3, 1.6) == ACCEPT          # the old chain has been quiet since 0.49


def test_numbers_of_messages_not_taken_are_no_gap_and_make_nothing_accepted():
    # one publisher alternating its arm's and its gripper's joints: the gripper's numbers skipped
    c = SourceChains(grace=10.0)
    verdicts = []
    for k in range(1, 41):
        if k % 2:
            verdicts.append(c.classify(k, 0.01 * k))
        else:
            c.skip(k)
    assert verdicts == [ACCEPT] * 20 and c.gaps == 0
    c.skip(41)                                   # a rejected value (NaN) of the arm: no gap either
    assert c.classify(43, 0.5) == GAP            # 42 was neither received nor skipped: a gap
    c.skip(44)
    assert c.classify(45, 0.6) == ACCEPT
    c.skip(1000)                                 # a skipped number elsewhere fills no gap of ours
    assert c.classify(47, 0.7) == GAP and c.classify(48, 0.8) == ACCEPT
    assert c.live(0.8) == 1                      # skipping made no chain


def test_message_info_reaches_the_handler_from_either_executor_call_form():
    got = []
    cb = with_message_info(lambda msg, inf: got.append((msg, inf)))
    cb(b"m", {"publication_sequence_number": 3})      # SingleThreadedExecutor: two arguments
    cb((b"n", {"publication_sequence_number": 4}))    # Jazzy's EventsExecutor: one (msg, info) tuple
    assert got == [(b"m", {"publication_sequence_number": 3}), (b"n", {"publication_sequence_number": 4})]


def test_recorders_are_told_apart_and_the_slowest_live_one_is_waited_for():
    acks = RecorderAcks(timeout=5.0)
    acks.ack(5, 100, 0.0)      # recorder A (its publisher's numbers ..., 5, 6, ...)
    acks.ack(1, 40, 0.1)       # recorder B, started later (1, 2, ...)
    acks.ack(6, 120, 0.5)
    acks.ack(2, 60, 0.6)
    assert acks.recorders_seen == 2 and acks.slowest(1.0) == 60 and acks.largest() == 120
    acks.ack(7, 130, 5.2)      # B says nothing more: after the timeout only A is waited for
    assert acks.newly_stale(5.5) == [] and acks.slowest(5.7) == 130
    assert acks.newly_stale(5.7) == [60] and acks.newly_stale(5.8) == []   # (said once)
    stuck = RecorderAcks(timeout=5.0)  # a publisher repeating one number (a stopped recorder, a stray one)
    for k in range(1, 20):
        stuck.ack(k, 0, 0.5 * k)
    assert stuck.slowest(9.9) is None


def test_a_stepped_move_reaches_the_target_in_steps_of_at_most_max_step():
    robot = Robot(["a", "b", "c"], [-2.0] * 3, [2.0] * 3, [0.0, 0.0, 0.0])
    alpha, rest, steps = np.array([1.5, -1.2, 0.05]), robot.rest, []
    while True:
        nxt = step_toward(alpha, rest, 0.1, robot)
        assert np.abs(nxt - alpha).max() <= 0.1 + 1e-12
        steps.append(nxt)
        alpha = nxt
        if (nxt == rest).all():
            break
    assert len(steps) == 15


# ------------------------------------------------------------------ the learner node
@pytest.fixture(scope="module")
def nodes(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sources")
    params = {
        "/**": {"ros__parameters": {"seed": 0, "strategy": "sagg-riac",
                                    "task_space": {"lower": [-10.0, -10.0], "upper": [10.0, 10.0]},
                                    "plausibility": {"source_grace": GRACE}}},
        "sagg_learner": {"ros__parameters": {
            "joints": JOINTS, "joint_limits": {"lower": [-LIMIT] * 3, "upper": [LIMIT] * 3},
            "rest_posture": [0.125, 0.25, 0.375], "max_joint_step": 0.125}},  # (exact in binary)
        "sagg_sim_bridge": {"ros__parameters": {"arm": {"dof": 3, "mode": "kinematic"}}},
    }
    yield from arm_nodes(params, tmp)


def test_a_gripper_and_idle_publishers_change_nothing(nodes):
    """A JointState naming only another driver's joint is ignored (counted apart, not an error, no
    hold); a second publisher that sends nothing, on every input, changes nothing."""
    from geometry_msgs.msg import PointStamped
    from sagg_common.ros_params import reliable
    n = nodes["learner"]
    fresh_streams(n)
    n.js_intake.sources, n.tip_sources = SourceChains(GRACE), SourceChains(GRACE)
    idle = rclpy.create_node("idle_publishers")
    try:
        for cls, topic in ((JointState, "/joint_states"), (PointStamped, "/tip_position"), (UInt64, "/sagg/recorded")):
            idle.create_publisher(cls, topic, reliable(10))
        assert wait_for(lambda: n.count_publishers("/joint_states") >= 2 and n.count_publishers("/sagg/recorded") >= 1)
        total = n.guard.total
        for k in range(1, 6):
            n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=k * SEC), info(100 + k))
            n.on_joint_state(js_bytes([0.01 * k], [0.0], ns=k * SEC, names=["gripper_finger"]), info(k))
            n.on_task_point(tip_bytes(1.0, 2.0, ns=k * SEC), info(200 + k))
            assert n.js_stamp == k * SEC and n.tip_stamp == k * SEC   # every arm state taken
        assert n.guard.total == total and not n.holds
        assert n.js_intake.other_joints[("gripper_finger",)] == 5
        # one driver publishing its arm's and its gripper's joints in turn through ONE publisher:
        # every arm state is still taken (the gripper's numbers are no gap in the chain)
        n.js_intake.sources = SourceChains(GRACE)
        for k in range(6, 12):
            n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=k * SEC), info(300 + 2 * k))
            n.on_joint_state(js_bytes([0.01 * k], [0.0], ns=k * SEC, names=["gripper_finger"]), info(301 + 2 * k))
            assert n.js_stamp == k * SEC
        n.samples_published = 10_000
        assert not n._recorder_behind()   # an idle /sagg/recorded publisher is no recorder to wait for
    finally:
        n.samples_published = 0
        idle.destroy_node()


def test_the_same_joints_from_two_publishers_are_held_named_and_released(nodes):
    from sagg_common.ros_params import reliable
    n = nodes["learner"]
    fresh_streams(n)
    n.js_intake.sources = SourceChains(GRACE)
    intruder = rclpy.create_node("intruder")
    try:
        intruder.create_publisher(JointState, "/joint_states", reliable(10))
        assert wait_for(lambda: n.count_publishers("/joint_states") >= 2)
        n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=1 * SEC), info(500))
        before = state(n)
        n.on_joint_state(js_bytes([0.9, 0.9, 0.9], ns=2 * SEC), info(1))      # the intruder's
        n.on_joint_state(js_bytes([0.12, 0.2, 0.3], ns=3 * SEC), info(501))   # ours, meanwhile
        assert state(n) == before                  # neither taken: which is real cannot be told
        hold = n.holds["sources /joint_states"]
        assert "2 sources" in hold and "node /intruder" in hold and "gid " in hold
        assert n.guard.counts["joint_states.second_source"] >= 2
        assert "plausibility.source_grace" in n.guard.last_message["joint_states.second_source"]
        # the stale-driver hold that may follow names the second source, not a stopped driver
        n.js_rx -= 10 * n.params["joint_state_timeout"]
        n._check_driver()
        assert "2 sources" in n.holds["driver"] and "driver stopped" not in n.holds["driver"]
        n.js_rx = time.monotonic()
        # it ends by itself: the remaining source's first message once the second one has been
        # quiet for source_grace is taken, and releases the hold (no command from an older posture)
        time.sleep(GRACE + 0.1)
        n.on_poll()
        assert "sources /joint_states" in n.holds
        n.on_joint_state(js_bytes([0.13, 0.2, 0.3], ns=4 * SEC), info(502))
        assert n.js_stamp == 4 * SEC and "sources /joint_states" not in n.holds
    finally:
        intruder.destroy_node()
        n.holds.clear()


def test_a_return_to_rest_goes_in_steps_of_max_joint_step_from_the_measured_posture(nodes):
    """rest_return 'stepped' (the default): a reset is a sequence of commands, each at most
    max_joint_step from the newest measured posture, not counted as micro-actions; the learner's
    request is answered by the observation after the step that reaches the rest posture."""
    n = nodes["learner"]
    fresh_streams(n)
    sent: list[np.ndarray] = []
    from sagg_common.cdr import decode_f64_array
    n.cmd_pub.publish = lambda data: sent.append(decode_f64_array(data).copy())
    answers = []
    n.advance = answers.append   # (what the coroutine would get)
    try:
        n.state = None  # (no command in flight from an earlier test's poll)
        posture = np.array([-0.875, 0.75, 0.375])
        n.on_joint_state(js_bytes(posture, ns=1 * SEC))
        n.on_task_point(tip_bytes(1.0, 2.0, ns=1 * SEC))
        rest = np.array(n.params["rest_posture"])
        ma, stamp = n.learner.micro_actions, 1
        n.dispatch(Command(rest.copy(), "reset"))
        while not answers:
            assert len(sent) < 50
            assert np.abs(sent[-1] - posture).max() <= 0.125   # a step from the measured posture
            stamp += 1
            posture = sent[-1]                                      # the driver follows
            n.on_joint_state(js_bytes(posture, ns=stamp * SEC))
            n.on_task_point(tip_bytes(1.0, 2.0, ns=stamp * SEC))
        assert np.array_equal(sent[-1], rest) and len(sent) == 8   # 1.0 rad of joint 0 in steps of 0.125
        assert np.array_equal(answers[0][0], rest) and n.learner.micro_actions == ma
        assert n.rest_moves.steps >= 8
    finally:
        del n.cmd_pub.publish
        del n.advance
        n.state = None


def test_sagg_run_names_the_hold_it_gives_up_on(tmp_path):
    """A second source on /joint_states that never stops: the learner holds, `sagg run` shows why on
    its progress line and, after --stall-timeout, exits 1 with a message that names the hold
    (it said only "no new sample for 60 s")."""
    import os
    import subprocess
    from pathlib import Path

    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from sagg_bringup.graph.processes import pick_domain_id
    from sagg_common.ros_params import reliable

    domain = pick_domain_id()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    out = tmp_path / "run"
    proc = subprocess.Popen([SAGG, "run", "config/arm8.yaml",
                             "--micro-actions", "100000", "--eval-every", "100000", "--out", str(out),
                             "--domain-id", str(domain), "--stall-timeout", "12"],
                            cwd=Path(__file__).resolve().parents[1], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("second_arm_driver", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    try:
        status = []
        from sagg_msgs.msg import LearnerStatus
        node.create_subscription(LearnerStatus, "/sagg/status", status.append, 10)
        t_end = time.monotonic() + 120
        while time.monotonic() < t_end and not (status and status[-1].micro_actions > 0):
            ex.spin_once(timeout_sec=0.1)   # the run learns first
        # (a publisher there before the run starts is a robot's driver: the simulated bridge is refused)
        pub = node.create_publisher(JointState, "/joint_states", reliable(10))
        m = JointState()
        m.name = [f"joint_{i}" for i in range(8)]
        while proc.poll() is None and time.monotonic() < t_end:
            m.header.stamp = node.get_clock().now().to_msg()
            m.position = [0.0] * 8
            pub.publish(m)                  # for ever: the learner holds, and says why
            ex.spin_once(timeout_sec=0.02)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 9)
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    assert proc.returncode == 1, stderr[-2000:]
    assert ("no new sample for 12 s" in stderr
            and "the learner holds: 2 sources on /joint_states" in stderr), stderr[-2000:]
    assert "second_arm_driver" in stderr                       # the second publisher, named
    assert "held 2 sources on /joint_states" in stderr         # on the progress line meanwhile (printed
                                                               # every 10 s to a pipe)
    assert (out / "summary.json").is_file()                    # partial results written
