"""Nothing a publisher sends can poison, wedge or crash the graph.

One test per kind of hostile input, on the nodes built in this process (their
own rclpy context and parameter file, callbacks called directly with the hostile bytes, as in
test_bad_input) or on the `sagg run` / `sagg relearn` handlers. Each asserts that the input is
rejected, counted under its kind, changes no state, and that what follows it still works.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
import rclpy
from rclpy.serialization import serialize_message

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState

from sagg_bringup.graph.run_state import RunState
from sagg_low_level.learner import Command
from sagg_low_level.node import LearnerNode
from sagg_msgs.msg import CompetenceReport, Goal
from test_bad_input import arm_nodes

JOINTS = ["j0", "j1", "j2"]
LIMIT = 1.0
HOLD_AFTER = 4
RESYNC_AFTER = 3
SEC = 1_000_000_000


@pytest.fixture(scope="module")
def nodes(tmp_path_factory):
    """Learner, generator and bridge on a private domain (not spun). The bridge publishes
    /joint_states and /tip_position: the one expected publisher of each."""
    tmp = tmp_path_factory.mktemp("hostile")
    params = {
        "/**": {"ros__parameters": {"seed": 0, "strategy": "sagg-riac",
                                    "task_space": {"lower": [-10.0, -10.0], "upper": [10.0, 10.0]}}},
        "sagg_learner": {"ros__parameters": {
            "joints": JOINTS, "joint_limits": {"lower": [-LIMIT] * 3, "upper": [LIMIT] * 3},
            "rest_posture": [0.1, 0.2, 0.3],
            "plausibility": {"hold_after": HOLD_AFTER, "resync_after": RESYNC_AFTER, "future_tolerance": 5.0}}},
        "sagg_sim_bridge": {"ros__parameters": {"arm": {"dof": 3, "mode": "kinematic"}}},
    }
    yield from arm_nodes(params, tmp)


def js_bytes(pos, vel=(), ns=SEC, names=JOINTS) -> bytes:
    m = JointState()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(ns), SEC)
    m.name, m.position, m.velocity = list(names), [float(p) for p in pos], [float(v) for v in vel]
    return serialize_message(m)


def tip_bytes(x, y, ns=SEC) -> bytes:
    m = PointStamped()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(ns), SEC)
    m.point.x, m.point.y = float(x), float(y)
    return serialize_message(m)


def fresh_streams(n: LearnerNode) -> None:
    """Forget the stamps and rejection runs of earlier tests (the node is shared), release holds."""
    from sagg_common.envelope import RejectRun, StampTracker
    p = n.params
    n.js_intake.track = StampTracker(p["plausibility.future_tolerance"], p["plausibility.resync_after"])
    n.tip_track = StampTracker(p["plausibility.future_tolerance"], p["plausibility.resync_after"])
    n.js_run, n.tip_run = RejectRun(HOLD_AFTER), RejectRun(HOLD_AFTER)
    n.holds.clear()
    n.js_stamp = n.tip_stamp = -1
    n.js_rx = n.tip_rx = time.monotonic()  # (fresh: no stale-driver hold from an earlier test's clock)


def state(n: LearnerNode):
    return (None if n.js_alpha is None else n.js_alpha.tobytes(), n.js_stamp,
            None if n.tip is None else n.tip.tobytes(), n.tip_stamp, len(n.learner.memory))


# ------------------------------------------------------------------ row 1: joint states 3.0 rad
def test_joint_states_outside_the_limits_are_rejected_and_hold_after_a_run(nodes):
    n = nodes["learner"]
    fresh_streams(n)
    n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=1 * SEC))
    before = state(n)
    count = n.guard.counts.get("joint_states.out_of_limits", 0)
    for k in range(HOLD_AFTER):
        n.on_joint_state(js_bytes([3.0, 3.0, 3.0], ns=SEC + (k + 1) * 1000))
        assert state(n) == before  # never stored, never the posture a command's step is bounded by
    assert n.guard.counts["joint_states.out_of_limits"] == count + HOLD_AFTER
    assert "j0 = 3.0" in n.guard.last_message["joint_states.out_of_limits"]
    assert "allowed: [-1.1, 1.1]" in n.guard.last_message["joint_states.out_of_limits"]
    assert "joint_states" in n.holds and "out_of_limits" in n.holds["joint_states"]
    # the stamps of the rejected states did not move the newest stamp
    assert n.js_intake.track.newest == 1 * SEC
    # a command now is bounded by the last VALID posture
    n.learner.p["max_joint_step"] = 0.05
    target = n._safe_command(Command(np.array([1.0, 1.0, 1.0]), "micro"))
    assert np.all(np.abs(target - [0.1, 0.2, 0.3]) <= 0.05 + 1e-6)
    # a valid reading releases the hold
    n.on_joint_state(js_bytes([0.15, 0.2, 0.3], ns=SEC + 10_000))
    assert "joint_states" not in n.holds and n.js_alpha[0] == 0.15
    # within the tolerance (0.1 rad) past a limit: accepted
    n.on_joint_state(js_bytes([LIMIT + 0.05, 0.2, 0.3], ns=SEC + 20_000))
    assert n.js_alpha[0] == LIMIT + 0.05


def test_joint_velocities_beyond_the_bound_are_rejected(nodes):
    n = nodes["learner"]
    fresh_streams(n)
    n.on_joint_state(js_bytes([0.1, 0.2, 0.3], [0.0] * 3, ns=SEC))
    before = state(n)
    n.on_joint_state(js_bytes([0.1, 0.2, 0.3], [0.0, 5e3, 0.0], ns=2 * SEC))
    assert state(n) == before
    assert "j1 = 5000.0 rad/s" in n.guard.last_message["joint_states.velocity"]


# ------------------------------------------------------------------ row 2: joint states 1e308
@pytest.mark.parametrize("value", [1e308, -1.7e308, 1e10])
def test_huge_finite_joint_states_are_rejected(nodes, value):
    n = nodes["learner"]
    fresh_streams(n)
    n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=SEC))
    before = state(n)
    total = n.guard.total
    n.on_joint_state(js_bytes([value, 0.2, 0.3], ns=2 * SEC))
    assert state(n) == before and n.guard.total == total + 1
    assert n.guard.counts["joint_states.out_of_limits"] >= 1


# ------------------------------------------------------------------ row 3: task point 1e308
@pytest.mark.parametrize("x, y", [(1e308, 0.0), (0.0, -1e308), (31.0, 0.0), (0.0, -30.5)])
def test_task_points_far_outside_y_are_rejected(nodes, x, y):
    n = nodes["learner"]
    fresh_streams(n)
    n.on_task_point(tip_bytes(1.0, 2.0, ns=SEC))
    before = state(n)
    n.on_task_point(tip_bytes(x, y, ns=SEC + 1_000_000))  # stamp +1 ms, as in the issue
    assert state(n) == before
    msg = n.guard.last_message["task_point.outside_task_space"]
    assert "allowed: within [[-30.0, 30.0], [-30.0, 30.0]]" in msg  # Y [-10, 10]² ± 1·extent
    # inside Y ± margin but outside Y: a real camera may see it
    n.on_task_point(tip_bytes(-25.0, 12.0, ns=2 * SEC))
    assert list(n.tip) == [-25.0, 12.0]


def test_task_points_rejected_in_a_row_hold_and_release(nodes):
    n = nodes["learner"]
    fresh_streams(n)
    n.on_task_point(tip_bytes(1.0, 2.0, ns=SEC))
    for k in range(HOLD_AFTER):
        n.on_task_point(tip_bytes(1e308, 0.0, ns=SEC + (k + 1) * 1000))
    assert "task_point" in n.holds and "outside_task_space" in n.holds["task_point"]
    n.on_task_point(tip_bytes(1.0, 2.5, ns=SEC + 10_000))
    assert "task_point" not in n.holds


# ------------------------------------------------------------------ row 4: a stamp +1,000 s
def test_a_future_stamp_is_rejected_and_never_wedges_the_stream(nodes):
    n = nodes["learner"]
    fresh_streams(n)
    n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=100 * SEC))
    n.on_joint_state(js_bytes([0.2, 0.2, 0.3], ns=1100 * SEC))  # +1,000 s
    assert n.js_alpha[0] == 0.1 and n.js_intake.track.newest == 100 * SEC
    assert "future" in n.guard.last_message["joint_states.future_stamp"]
    # the real states after it are accepted at once
    n.on_joint_state(js_bytes([0.3, 0.2, 0.3], ns=100 * SEC + 10_000_000))
    assert n.js_alpha[0] == 0.3
    # the same for task points
    n.on_task_point(tip_bytes(1.0, 1.0, ns=100 * SEC))
    n.on_task_point(tip_bytes(2.0, 2.0, ns=1100 * SEC))
    n.on_task_point(tip_bytes(3.0, 3.0, ns=100 * SEC + 10_000_000))
    assert list(n.tip) == [3.0, 3.0] and n.guard.counts["task_point.future_stamp"] >= 1


def test_a_clock_jump_back_is_detected_and_resynchronised(nodes):
    """A driver (or sim time) restart: stamps start again near 0. After resync_after messages in a
    row older than the newest, the stream is re-synchronised, logged, counted; never a wedge."""
    n = nodes["learner"]
    fresh_streams(n)
    n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=500 * SEC))
    jumps = n.guard.counts.get("joint_states.clock_jump_back", 0)
    for k in range(RESYNC_AFTER - 1):
        n.on_joint_state(js_bytes([0.4, 0.2, 0.3], ns=(k + 1) * SEC // 10))
        assert n.js_alpha[0] == 0.1  # an isolated older stamp: out of order, kept the newest
    n.on_joint_state(js_bytes([0.5, 0.2, 0.3], ns=SEC))
    assert n.js_alpha[0] == 0.5 and n.js_stamp == SEC
    assert n.guard.counts["joint_states.clock_jump_back"] == jumps + 1
    assert "clock jumped back from 500000000000 ns" in n.guard.last_message["joint_states.clock_jump_back"]
    n.on_joint_state(js_bytes([0.6, 0.2, 0.3], ns=2 * SEC))
    assert n.js_alpha[0] == 0.6


def test_a_pending_command_is_answered_after_a_future_stamp_got_through_first(nodes):
    """The worst case: the first stamp of the stream was forged +1,000 s (no reference yet), a
    command went out; the real answers look older: after resync_after of them the command is answered."""
    n = nodes["learner"]
    fresh_streams(n)
    n.on_joint_state(js_bytes([0.1, 0.2, 0.3], ns=1000 * SEC))   # forged, first of the stream
    n.on_task_point(tip_bytes(1.0, 1.0, ns=1 * SEC))
    answered = []
    n.state, n.js_min, n.tip_min = n.RUNNING_COMMAND, n.js_stamp, 0
    n.js_fresh = n.tip_fresh = False
    n.tip_fresh = True
    old_advance = n.advance
    n.advance = answered.append
    try:
        for k in range(RESYNC_AFTER):
            n.on_joint_state(js_bytes([0.12, 0.2, 0.3], ns=SEC + k))
        assert answered and answered[0][0][0] == 0.12
    finally:
        n.advance = old_advance
        n.state = None


# ------------------------------------------------------------------ rows 5-6: reports
def report_bytes(seq, kind=3, reached=(1.0, 1.0), competence=0.0) -> bytes:
    m = CompetenceReport()
    m.seq, m.kind, m.competence = seq, kind, competence
    m.target, m.reached, m.start = [], list(reached), [0.0, 0.0]
    return serialize_message(m)


def test_a_report_far_outside_the_window_is_rejected_at_once(nodes):
    g = nodes["generator"]
    gen = g.gen
    reports, skipped = gen.reports, gen.skipped_reports
    t0 = time.perf_counter()
    g.on_report(report_bytes(gen.reports + 10**12))
    assert time.perf_counter() - t0 < 0.5  # main tried to skip 10^12 reports one by one
    assert gen.reports == reports and gen.skipped_reports == skipped
    assert g.guard.counts["report.out_of_window"] >= 1
    g.on_report(report_bytes(reports + 1))  # the real next one is taken
    assert gen.reports == reports + 1 and gen.skipped_reports == skipped


@pytest.mark.parametrize("bad", [dict(reached=(math.nan, 1.0)), dict(kind=77), dict(competence=math.inf),
                                 dict(competence=0.5), dict(reached=(1.0,))])
def test_a_bad_report_never_consumes_the_seq_of_the_real_one(nodes, bad):
    g = nodes["generator"]
    gen = g.gen
    seq, skipped, leaves = gen.reports + 1, gen.skipped_reports, len(gen.tree.leaves())
    g.on_report(report_bytes(seq, **bad))
    assert gen.reports == seq - 1 and gen.skipped_reports == skipped and len(gen.tree.leaves()) == leaves
    assert g.guard.counts["report.invalid"] >= 1
    g.on_report(report_bytes(seq))  # the learner's real report with that number
    assert gen.reports == seq and gen.skipped_reports == skipped


# ------------------------------------------------------------------ row 8: goals
def goal_msg(seq, position):
    g = Goal()
    g.seq, g.after_report, g.mode = seq, 0, 0
    g.position = [float(p) for p in position]
    return g


@pytest.mark.parametrize("position", [(math.nan, 1.0), (1e9, 0.0), (1.0,), (math.inf, math.inf)])
def test_run_state_drops_nan_and_out_of_y_goals(position):
    st = RunState(task_lower=np.array([-10.0, -10.0]), task_upper=np.array([10.0, 10.0]))
    st.on_goal(goal_msg(1, (1.0, 1.0)))
    st.on_goal(goal_msg(2, position))
    st.on_goal(goal_msg(10**12, (1.0, 1.0)))  # a forged seq far ahead
    st.on_goal(goal_msg(2, (2.0, 2.0)))        # the real goal 2
    assert sorted(st.goals) == [1, 2] and st.goals[2]["position"] == [2.0, 2.0]
    assert st.gaps["/sagg/goal"] == 0
    assert st.rejected == {"/sagg/goal position not finite or outside Y": 1, "/sagg/goal seq out of window": 1}


def test_run_state_counts_and_names_bad_samples_even_below_the_next_index():
    """A re-published sample (an earlier index) is ignored only when its content is plausible; every
    rejection is counted and handed to on_reject (sagg run's log) naming the field, value and range."""
    from types import SimpleNamespace
    logged = []
    st = RunState(on_reject=lambda key, n, detail: logged.append((key, n, detail)))
    check = st.arm_sample_check({"joint_limits.lower": [-1.0, -1.0], "joint_limits.upper": [1.0, 1.0],
                                 "plausibility.joint_tolerance": 0.1}, 2)

    def sample(i, alpha):
        return SimpleNamespace(index=i, alpha=alpha, delta_alpha=[0.0, 0.0], delta_y=[0.0, 0.0])

    assert st.accept_sample(sample(0, [0.1, 0.2]), check) is True
    assert st.accept_sample(sample(1, [0.1, 0.2]), check) is True
    assert st.accept_sample(sample(0, [0.1, 0.2]), check) is None  # re-published: ignored
    assert st.rejected == {} and not logged
    assert st.accept_sample(sample(0, [math.nan, 0.0]), check) is None  # earlier index, bad content
    assert st.accept_sample(sample(5, [0.1, 0.2]), check) is None       # ahead of the next index
    assert st.accept_sample(sample(2, [3.0, 0.0]), check) is None       # α beyond the limits
    assert st.samples == 2
    assert st.rejected == {"/sagg/sample content rejected (an earlier index)": 1,
                           "/sagg/sample index or content rejected": 2}
    assert "index 0: NaN/inf value" in logged[0][2]
    assert "index 5; allowed: 2" in logged[1][2]
    assert "alpha [3.0, 0.0]; allowed: within the joint limits ± 0.1" in logged[2][2]
    st.task_lower, st.task_upper = np.array([-10.0, -10.0]), np.array([10.0, 10.0])
    st.on_goal(goal_msg(1, (50.0, 0.0)))
    assert logged[-1][:2] == ("/sagg/goal position not finite or outside Y", 1) and "50.0" in logged[-1][2]


def test_learner_rejects_nan_and_out_of_y_goals_from_the_service(nodes):
    n = nodes["learner"]

    class Fut:
        def __init__(self, pos):
            from sagg_msgs.srv import NextGoal
            self.resp = NextGoal.Response()
            self.resp.goal = goal_msg(1, pos)

        def result(self):
            return self.resp

    for pos in [(math.nan, 0.0), (50.0, 0.0)]:
        fut = Fut(pos)
        n.goal_future = fut
        before = (n.goals_received, n.guard.counts.get("goal.invalid", 0))
        n.on_goal(fut)
        assert n.goals_received == before[0] and n.guard.counts["goal.invalid"] == before[1] + 1
    n.goal_future = None


def test_run_state_drops_reports_far_ahead_and_invalid_ones_without_consuming_their_seq():
    st = RunState(task_lower=np.array([-10.0, -10.0]), task_upper=np.array([10.0, 10.0]))
    from rclpy.serialization import deserialize_message
    for raw in (report_bytes(1), report_bytes(10**12), report_bytes(2, reached=(math.nan, 0.0)), report_bytes(2)):
        st.on_report(deserialize_message(raw, CompetenceReport))
    assert st.reports == 2 and st.gaps["/sagg/competence"] == 0
    assert st.rejected == {"/sagg/competence seq out of window": 1, "/sagg/competence invalid content": 1}


def test_run_state_waits_for_every_report_the_learner_counts_and_names_a_missing_tail():
    """A recorder behind on /sagg/competence (a resumed learner's re-published history on a loaded
    machine) must not let the run end when the samples are in: the nodes would take the reports
    still in flight with them, a tail no sequence gap shows (a CI failure: 586 reports missing from
    a resumed run's bag, counted nowhere)."""
    from rclpy.serialization import deserialize_message
    from sagg_msgs.msg import LearnerStatus
    st = RunState(task_lower=np.array([-10.0, -10.0]), task_upper=np.array([10.0, 10.0]))
    st.on_status(LearnerStatus(samples=0, reports=3))
    for seq in (1, 2):
        st.on_report(deserialize_message(report_bytes(seq), CompetenceReport))
    now = st.report_t
    assert not st.all_recorded(now + 0.1, patience=5.0)  # samples in, a report still on its way
    assert st.unrecorded() == {"/sagg/competence": 1}
    assert st.all_recorded(now + 5.1, patience=5.0)  # none for `patience` s: it will not come
    st.on_report(deserialize_message(report_bytes(3), CompetenceReport))
    assert st.all_recorded(st.report_t, patience=5.0) and st.unrecorded() == {}
    st.on_status(LearnerStatus(samples=4, reports=3))
    assert not st.all_recorded(st.report_t + 100, patience=5.0)  # samples are always waited for
    assert st.unrecorded() == {"/sagg/sample": 4}


# ------------------------------------------------------------------ row 9: a second publisher
def wait_for(cond, timeout=10.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if cond():
            return True
        time.sleep(0.05)
    return False


def test_a_forged_report_never_takes_the_seq_of_the_learners_real_one(nodes):
    """Reports reach the generator over DDS here: the learner's own publisher and an intruder's.
    While two sources send reports on /sagg/competence every report is dropped and the topic's
    publishers named (the intruder among them); once one source has been quiet for
    plausibility.source_grace the generator subscribes again and takes the learner's real reports
    from its transient_local history: the forged report never took the seq of the real one, nothing
    is lost."""
    from rclpy.executors import SingleThreadedExecutor
    from sagg_common.ros_params import reliable
    g, learner = nodes["generator"], nodes["learner"]
    ex = SingleThreadedExecutor()
    ex.add_node(g)

    def spin_until(cond, timeout=10.0) -> bool:
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            ex.spin_once(timeout_sec=0.05)
            if cond():
                return True
        return False

    intruder = rclpy.create_node("intruder2")
    try:
        r, skipped = g.gen.reports, g.gen.skipped_reports
        assert wait_for(lambda: learner.report_pub.get_subscription_count() >= 1)
        learner.report_pub.publish(report_bytes(r + 1))  # the learner's stream starts
        assert spin_until(lambda: g.gen.reports == r + 1)
        # (transient_local like the learner's: a volatile publisher does not even match the generator)
        pub = intruder.create_publisher(CompetenceReport, "/sagg/competence", reliable(10, transient_local=True))
        assert wait_for(lambda: pub.get_subscription_count() >= 1)
        before = g.guard.counts.get("report.second_source", 0)
        pub.publish(report_bytes(r + 2, reached=(9.0, 9.0)))   # forged, the next seq
        learner.report_pub.publish(report_bytes(r + 2, reached=(2.0, 2.0)))  # the real one meanwhile
        assert spin_until(lambda: g.guard.counts.get("report.second_source", 0) >= before + 2)
        assert g.gen.reports == r + 1
        assert "node /intruder2" in g.guard.last_message["report.second_source"]
        intruder.destroy_publisher(pub)
        assert spin_until(lambda: g.gen.reports == r + 2)  # the real r+2, from the learner's history
        assert g.resubscriptions >= 1 and g.gen.skipped_reports == skipped  # no real report was lost
        points = np.concatenate([leaf.points[:leaf.count] for leaf in g.gen.tree.leaves()])
        assert any(np.array_equal(p, [2.0, 2.0]) for p in points)       # the real report's point
        assert not any(np.array_equal(p, [9.0, 9.0]) for p in points)   # never the forged one
    finally:
        ex.remove_node(g)
        intruder.destroy_node()


def test_reordered_reports_are_kept_not_skipped(nodes):
    """A report ahead of the next one (reordered, or re-delivered after a re-subscription) waits for
    the ones before it: nothing is skipped when they come within report_reorder_wait."""
    g = nodes["generator"]
    gen = g.gen
    r, skipped = gen.reports, gen.skipped_reports
    g.on_report(report_bytes(r + 3))
    g.on_report(report_bytes(r + 2))
    assert gen.reports == r and sorted(g.early) == [r + 2, r + 3]
    g.on_report(report_bytes(r + 1))
    assert gen.reports == r + 3 and gen.skipped_reports == skipped and not g.early


def test_recorder_counts_the_messages_it_missed_from_publisher_sequence_numbers():
    from sagg_bringup.bags.recorder import _follow
    tails: list[int] = []
    assert [_follow(tails, s) for s in (1, 2, 5, 6, 10)] == [0, 0, 2, 0, 3]
    # a restarted publisher (numbers start again) is a new stream, not a loss
    assert [_follow(tails, s) for s in (1, 2, 3, 11)] == [0, 0, 0, 0]


# ------------------------------------------------------------------ bags: recorder backpressure
def test_the_learner_waits_for_a_lagging_recorder_and_an_impossible_ack_changes_nothing(nodes):
    """A lockstep bag is complete under overload: with a recorder acknowledging on
    /sagg/recorded, no command goes out while more than recorder_max_lag published samples are
    unacknowledged; it goes out once the recorder caught up (to half the lag). An acknowledgement
    beyond what was published is rejected and counted; without an acknowledging recorder the learner
    never waits."""
    from std_msgs.msg import UInt64
    from sagg_common.ros_params import reliable
    n = nodes["learner"]
    fresh_streams(n)
    lag = n.rec_max_lag
    assert lag == 500  # the default
    n.js_alpha, n.tip = np.array([0.1, 0.2, 0.3]), np.array([1.0, 1.0])
    cmd = Command(np.array([0.1, 0.2, 0.35]), "reach")
    sent = n.published[n.cmd_topic]
    n.samples_published, n.rec_acked = 1000, 0
    # no recorder acknowledges: no wait
    n.state = None
    n.dispatch(cmd)
    assert n.state is n.RUNNING_COMMAND and n.published[n.cmd_topic] == sent + 1 and not n.rec_waiting
    recorder = rclpy.create_node("sagg_run")
    try:
        pub = recorder.create_publisher(UInt64, "/sagg/recorded", reliable(10))
        assert wait_for(lambda: n.rec_sub.get_publisher_count() == 1)
        # a publisher that acknowledges nothing (an idle one) changes nothing
        n.state = None
        n.dispatch(cmd)
        assert n.state is n.RUNNING_COMMAND and not n.rec_waiting
        sent += 1
        n.on_recorded(UInt64(data=0))  # it acknowledges: a recorder the learner waits for
        n.state = None
        n.dispatch(cmd)
        assert n.state is n.PAUSED and n.rec_waiting and n.published[n.cmd_topic] == sent + 1
        assert "waiting for the recorder" in _status_reason(n)
        count = n.guard.counts.get("recorded.ahead", 0)
        n.on_recorded(UInt64(data=10**12))     # impossible: more than was published
        assert n.guard.counts["recorded.ahead"] == count + 1 and n.rec_acked == 0 and n.rec_waiting
        n.on_recorded(UInt64(data=400))        # still 600 behind
        assert n.rec_waiting and n.state is n.PAUSED and n.published[n.cmd_topic] == sent + 1
        n.on_recorded(UInt64(data=100))        # older than the largest: changes nothing
        assert n.rec_acked == 400
        n.on_recorded(UInt64(data=1000 - lag // 2))
        assert not n.rec_waiting and n.state is n.RUNNING_COMMAND and n.published[n.cmd_topic] == sent + 2
        assert n.rec_waits >= 1 and n.rec_wait_seconds > 0
        # the recorder gone while the learner waits: it goes on (never a wedge)
        n.samples_published = 5000
        n.state = None
        n.dispatch(cmd)
        assert n.rec_waiting
        recorder.destroy_publisher(pub)
        assert wait_for(lambda: n.rec_sub.get_publisher_count() == 0)
        n.on_poll()
        assert not n.rec_waiting and n.published[n.cmd_topic] == sent + 3
    finally:
        recorder.destroy_node()
        n.state, n.samples_published, n.rec_acked = None, 0, 0


def _status_reason(n) -> str:
    got = []
    n.status_pub.publish = got.append   # (the message the status timer would publish)
    try:
        n.publish_status()
    finally:
        del n.status_pub.publish
    return got[-1].pause_reason


def publisher_info(node: str, gid: int):
    from types import SimpleNamespace
    return SimpleNamespace(node_name=node, node_namespace="/", endpoint_gid=bytes([gid] * 16))


def stream_at_100(topic: str):
    """A PublisherStream of ``topic`` over a fake graph whose one publisher (the learner) has sent
    messages 1..100; returns (graph, watch, stream): change ``graph[topic]`` to add publishers."""
    from types import SimpleNamespace
    from sagg_common.publishers import PublisherStream, PublisherWatch
    graph = {topic: [publisher_info("sagg_learner", 1)]}
    node = SimpleNamespace(get_publishers_info_by_topic=lambda t: list(graph[t]),
                           count_publishers=lambda t: len(graph[t]))
    watch = PublisherWatch(node)
    watch.watch(topic, None, "sagg_learner")
    stream = PublisherStream(watch, topic, "sagg_learner")
    for seq in range(1, 101):
        assert stream.check(seq, time.time_ns()) == ""
        stream.commit(seq)
    return graph, watch, stream


def test_a_forged_message_queued_after_its_publisher_left_never_moves_the_stream():
    """The soak's wedge (publishers phase): forged samples numbered far beyond ours, still queued at
    the recorder after the forger had left (the topic looked fine again), were taken as a gap; the
    stream then stood at the forger's number and every real sample was rejected. A gap is taken
    only from a message sent after another publisher was last seen on the topic."""
    graph, watch, stream = stream_at_100("/sagg/sample")
    t_forged = time.time_ns()                  # the forger publishes (numbers up to 27,312) ...
    graph["/sagg/sample"].append(publisher_info("sagg_fuzzer", 2))
    assert "2 publishers" in watch.refresh("/sagg/sample")
    assert "while the topic has" in stream.check(27312, t_forged)
    graph["/sagg/sample"].pop()                # ... and leaves; its messages are still queued
    assert watch.refresh("/sagg/sample") == ""
    assert "before another publisher" in stream.check(27312, t_forged)
    assert stream.last == 100
    assert stream.check(101, time.time_ns()) == ""   # the real stream goes on
    stream.commit(101)
    time.sleep(0.001)
    assert stream.check(105, time.time_ns()) == ""   # a real gap (messages missed), sent afterwards


def test_a_replay_whose_numbers_catch_up_with_a_silent_publisher_never_takes_its_stream():
    """A long replay beside a running learner: the learner holds (silent at number 100), a replay numbers its
    messages from 1; its 101st continued the learner's stream exactly and was taken, and from then
    on every real message was "not after" the replay's numbers (sagg run's bag, summary and
    relearn took the replay's run as the live one)."""
    graph, watch, stream = stream_at_100("/sagg/competence")
    graph["/sagg/competence"].append(publisher_info("sagg_replay", 2))  # the replay joins; the learner holds
    watch.refresh("/sagg/competence")
    for seq in range(1, 101):
        assert "not after 100" in stream.check(seq, time.time_ns())
    assert "continues the expected publisher's stream and another's" in stream.check(101, time.time_ns())
    for seq in range(102, 150):
        assert stream.check(seq, time.time_ns())  # above ours while the replay is on the topic
    graph["/sagg/competence"].pop()  # the replay ends; the learner goes on
    watch.refresh("/sagg/competence")
    time.sleep(0.001)
    for seq in range(101, 120):
        assert stream.check(seq, time.time_ns()) == ""
        stream.commit(seq)
    assert stream.last == 119 and stream.gaps == 0


def test_a_reach_canceled_before_its_turn_releases_its_hold(nodes):
    """Seen once under colcon test: /sagg/pause while a command was in flight, a reach sent (queued:
    its hold set, the command's answer first), then canceled; the canceled job was answered, but
    its 'reach' hold stayed, so releasing the pause left learning held for ever."""
    from sagg_low_level.reach_server import ReachJob
    n = nodes["learner"]
    fresh_streams(n)
    saved = (n.state, n.pending)
    try:
        n.holds["service"] = "paused by the /sagg/pause service"
        n.state = n.RUNNING_COMMAND                  # the micro-action in flight completes first
        job = ReachJob(np.array([1.0, 1.0]), 0.1, 10)
        n.reach_server.jobs.append(job)
        n._poll_reach()
        assert "reach" in n.holds and n.reach is None and list(n.reach_server.jobs) == [job]
        n.state, n.pending = n.PAUSED, None          # its answer came; the next command is held
        job.cancel = True
        n.on_poll()
        assert job.done.is_set() and job.result[3] == "canceled" and job.result[2] == 0
        assert "reach" not in n.holds and n.holds == {"service": "paused by the /sagg/pause service"}
    finally:
        n.holds.clear()
        n.reach_server.jobs.clear()
        n.state, n.pending = saved
