"""Fuzz tests: every subscription callback of the three nodes, and the config loader.

The nodes are built in this process (their own rclpy context, a parameter file) and their
callbacks are called directly with random bytes and with well-formed messages carrying bad values
(NaN/inf, wrong lengths, unknown or missing joint names, positions outside Y, duplicated or
out-of-order reports). A callback must never raise; a bad input must be counted by the node's
InputGuard (what /diagnostics publishes) and must leave the node's state as it was.
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from hypothesis import HealthCheck, example, given, settings, strategies as st
from rclpy.serialization import serialize_message

from geometry_msgs.msg import PointStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from sagg_bringup.graph.processes import pick_domain_id
from sagg_common.params import ConfigError, node_params, read_config
from sagg_goal_generator.node import GoalGeneratorNode, SCHEMA as GEN_SCHEMA
from sagg_low_level.node import LearnerNode, SCHEMA as LEARNER_SCHEMA
from sagg_msgs.msg import CompetenceReport
from sagg_sim_bridge.node import BridgeNode, SCHEMA as BRIDGE_SCHEMA

ROOT = Path(__file__).resolve().parents[1]
JOINTS = ["j0", "j1", "j2"]
FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def nodes(tmp_path_factory):
    """The three nodes on a private domain, built from one parameter file (not spun)."""
    tmp = tmp_path_factory.mktemp("fuzz")
    params = {
        "/**": {"ros__parameters": {"seed": 0, "strategy": "sagg-riac",
                                    "task_space": {"lower": [-10.0, -10.0], "upper": [10.0, 10.0]}}},
        "sagg_learner": {"ros__parameters": {"joints": JOINTS,
                                             "joint_limits": {"lower": [-1.0] * 3, "upper": [1.0] * 3},
                                             "rest_posture": [0.1, 0.2, 0.3]}},
        "sagg_sim_bridge": {"ros__parameters": {"arm": {"dof": 3, "mode": "kinematic"}}},
    }
    yield from arm_nodes(params, tmp)


def arm_nodes(params: dict, tmp: Path):
    """Learner, goal generator and bridge built in this process from ``params`` (a parameter-file
    dict) on a private domain, not spun; destroyed and the context shut down afterwards."""
    path = tmp / "params.yaml"
    path.write_text(yaml.safe_dump(params))
    rclpy.init(args=["--ros-args", "--params-file", str(path)], domain_id=pick_domain_id())
    try:
        built = {"learner": LearnerNode(), "generator": GoalGeneratorNode(), "bridge": BridgeNode()}
        yield built
        for n in built.values():
            n.destroy_node()
    finally:
        rclpy.try_shutdown()


def js_bytes(names, pos, vel, sec=1) -> bytes:
    m = JointState()
    m.header.stamp.sec = sec
    m.name, m.position, m.velocity = list(names), list(pos), list(vel)
    return serialize_message(m)


def tip_bytes(x, y, sec=1) -> bytes:
    m = PointStamped()
    m.header.stamp.sec = sec
    m.point.x, m.point.y = x, y
    return serialize_message(m)


def fresh_stamps(n: LearnerNode) -> None:
    """Forget the newest stamps (each test's messages are stamped anew) and the rejection runs."""
    from sagg_common.envelope import RejectRun, StampTracker
    p = n.params
    n.js_intake.track = StampTracker(p["plausibility.future_tolerance"], p["plausibility.resync_after"])
    n.tip_track = StampTracker(p["plausibility.future_tolerance"], p["plausibility.resync_after"])
    n.js_run, n.tip_run = RejectRun(p["plausibility.hold_after"]), RejectRun(p["plausibility.hold_after"])
    n.js_stamp = n.tip_stamp = 0


def learner_state(n: LearnerNode):
    return (None if n.js_alpha is None else n.js_alpha.tobytes(), n.js_stamp,
            None if n.tip is None else n.tip.tobytes(), n.tip_stamp, len(n.learner.memory), n.state)


floats = st.floats(allow_nan=True, allow_infinity=True, width=64)


@FUZZ
@given(data=st.binary(max_size=300))
def test_random_bytes_never_crash_any_callback(nodes, data):
    learner, gen, bridge = nodes["learner"], nodes["generator"], nodes["bridge"]
    before = (learner_state(learner), gen.gen.reports, bridge.commands)
    totals = (learner.guard.total, gen.guard.total, bridge.guard.total)
    learner.on_joint_state(data)
    learner.on_task_point(data)
    gen.on_report(data)
    bridge.on_command(data)
    after = (learner_state(learner), gen.gen.reports, bridge.commands)
    # random bytes are either rejected (counted) or happen to decode into a valid message
    if before == after:
        assert (learner.guard.total, gen.guard.total, bridge.guard.total) != totals or not data


@FUZZ
@given(names=st.lists(st.sampled_from(JOINTS + ["other", ""]), max_size=5),
       pos=st.lists(floats, max_size=5), vel=st.lists(floats, max_size=5))
# finite values far outside the limits (1e308 included): rejected
@example(names=list(JOINTS), pos=[1.7e308] * len(JOINTS), vel=[-1.7e308] * len(JOINTS))
# within the limits ± plausibility.joint_tolerance (0.1), velocities within the bound (1000): accepted
@example(names=list(JOINTS), pos=[1.05, -1.05, 0.0], vel=[999.0, -999.0, 0.0])
# one NaN velocity among finite values: rejected
@example(names=list(JOINTS), pos=[0.1] * len(JOINTS), vel=[0.0] * (len(JOINTS) - 1) + [math.nan])
def test_joint_states_with_bad_values_are_rejected_and_counted(nodes, names, pos, vel):
    n = nodes["learner"]
    fresh_stamps(n)  # this test's messages are all stamped 1 s: never "out of order"
    before, total, ignored = learner_state(n), n.guard.total, sum(n.js_intake.other_joints.values())
    n.on_joint_state(js_bytes(names, pos, vel))
    where = {nm: i for i, nm in enumerate(names)}
    lengths_ok = len(pos) == len(names) and len(vel) in (0, len(names))
    well_formed = lengths_ok and len(where) == len(names)
    valid = (well_formed and all(j in where for j in JOINTS)
             and all(-1.1 <= pos[where[j]] <= 1.1 for j in JOINTS)  # (NaN fails)
             and (not vel or all(-1000.0 <= vel[where[j]] <= 1000.0 for j in JOINTS)))
    if valid:
        assert np.array_equal(n.js_alpha, [pos[where[j]] for j in JOINTS]) and n.guard.total == total
    elif lengths_ok and not any(j in where for j in JOINTS):
        # another driver's joints only (a gripper's), however it names them: ignored, counted apart,
        # not an error (another driver's joints, e.g. a gripper's)
        assert n.guard.total == total and sum(n.js_intake.other_joints.values()) == ignored + 1
        assert learner_state(n)[0] == before[0]
    else:
        assert n.guard.total == total + 1 and learner_state(n)[0] == before[0]


@FUZZ
@given(x=floats, y=floats)
def test_task_points_with_nan_or_inf_are_rejected(nodes, x, y):
    n = nodes["learner"]
    fresh_stamps(n)
    before, total = n.tip, n.guard.total
    n.on_task_point(tip_bytes(x, y))
    # valid: finite and within Y ([-10, 10]²) enlarged by plausibility.task_margin (1: [-30, 30]²)
    if -30.0 <= x <= 30.0 and -30.0 <= y <= 30.0:
        assert np.array_equal(n.tip, [x, y])
    else:
        assert n.guard.total == total + 1 and (n.tip is before)


def test_out_of_order_observations_keep_the_newest(nodes):
    n = nodes["learner"]
    fresh_stamps(n)
    n.on_joint_state(js_bytes(JOINTS, [0.1, 0.2, 0.3], [], sec=5))
    n.on_task_point(tip_bytes(1.0, 2.0, sec=5))
    total = n.guard.total
    n.on_joint_state(js_bytes(JOINTS, [0.9, 0.9, 0.9], [], sec=4))
    n.on_task_point(tip_bytes(9.0, 9.0, sec=4))
    assert n.guard.total == total + 2
    assert np.array_equal(n.js_alpha, [0.1, 0.2, 0.3]) and np.array_equal(n.tip, [1.0, 2.0])
    assert n.guard.counts["joint_states.out_of_order"] >= 1 and n.guard.counts["task_point.out_of_order"] >= 1


def report_bytes(seq, kind=3, target=(), reached=(1.0, 1.0), competence=0.0) -> bytes:
    m = CompetenceReport()
    m.seq, m.kind, m.competence = seq, kind, competence
    m.target, m.reached, m.start = list(target), list(reached), [0.0, 0.0]
    return serialize_message(m)


@FUZZ
@given(kind=st.integers(0, 255), coords=st.lists(floats, min_size=0, max_size=4), competence=floats)
def test_reports_with_bad_content_are_skipped_without_corrupting_the_tree(nodes, kind, coords, competence):
    g = nodes["generator"]
    gen = g.gen
    seq = gen.reports + 1
    leaves, total, skipped = len(gen.tree.leaves()), g.guard.total, gen.skipped_reports
    g.on_report(report_bytes(seq, kind=kind, target=coords, reached=coords, competence=competence))
    valid = (kind in (0, 1, 2, 3) and len(coords) == 2 and all(math.isfinite(c) for c in coords)
             and math.isfinite(competence) and competence <= 0.0)
    if valid:
        assert gen.reports == seq and g.guard.total == total and gen.skipped_reports == skipped
    else:
        # rejected without consuming its seq: the real report with that number is still taken
        assert gen.reports == seq - 1 and g.guard.total == total + 1 and gen.skipped_reports == skipped
        assert len(gen.tree.leaves()) == leaves


def test_duplicated_and_lost_reports(nodes):
    g = nodes["generator"]
    gen = g.gen
    seq = gen.reports + 1
    g.on_report(report_bytes(seq))
    total = g.guard.total
    g.on_report(report_bytes(seq))  # duplicate: dropped, counted (re-sent after a resume: not a bad input)
    assert gen.reports == seq and g.duplicate_reports >= 1 and g.guard.total == total
    g.on_report(report_bytes(seq + 3))  # two missing: kept for report_reorder_wait...
    assert gen.reports == seq
    g._check_early(now=time.monotonic() + 60.0)  # ...then they are skipped, and this one is used
    assert gen.reports == seq + 3 and g.guard.counts["report.lost"] >= 1
    assert gen.skipped_reports >= 2


@FUZZ
@given(values=st.lists(floats, max_size=6))
@example(values=[1.7e308, 1.7e308, -1.7e308])  # finite, the sum overflows: accepted (and clipped)
@example(values=[0.1, math.inf, -math.inf])    # the sum is NaN: rejected
def test_bridge_commands_with_bad_values_are_rejected(nodes, values):
    b = nodes["bridge"]
    m = Float64MultiArray()
    m.data = values
    before_cmds, total = b.commands, b.guard.total
    qpos = b.sim.data.qpos.copy()
    b.on_command(serialize_message(m))
    if len(values) == 3 and all(math.isfinite(v) for v in values):
        assert b.commands == before_cmds + 1
    else:
        assert b.commands == before_cmds and b.guard.total == total + 1
        assert np.array_equal(b.sim.data.qpos, qpos)


# ---------------------------------------------------------------------------- config loader
yaml_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12), floats, st.text(max_size=8))
yaml_values = st.recursive(yaml_scalars, lambda ch: st.one_of(st.lists(ch, max_size=3),
                                                             st.dictionaries(st.text(max_size=6), ch, max_size=3)),
                           max_leaves=8)
PARAM_NAMES = sorted({p.name for s in (LEARNER_SCHEMA, GEN_SCHEMA, BRIDGE_SCHEMA) for p in s})


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(section=st.sampled_from(["/**", "sagg_learner", "sagg_goal_generator", "sagg_sim_bridge", "bogus"]),
       name=st.sampled_from(PARAM_NAMES + ["typo_param"]), value=yaml_values)
def test_config_loader_fuzz_only_raises_config_error(tmp_path, section, name, value):
    """Any value for any parameter in any section: loading gives valid parameters or a
    ConfigError naming the problem, never another exception."""
    data = yaml.safe_load((ROOT / "config" / "arm8.yaml").read_text())
    data.setdefault(section, {"ros__parameters": {}})["ros__parameters"][name] = value
    path = tmp_path / "fuzz.yaml"
    path.write_text(yaml.safe_dump(data))
    try:
        sections = read_config(path)
        for node, schema in (("sagg_learner", LEARNER_SCHEMA), ("sagg_goal_generator", GEN_SCHEMA),
                             ("sagg_sim_bridge", BRIDGE_SCHEMA)):
            node_params(sections, node, schema)
    except ConfigError as exc:
        assert str(exc)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=st.text(max_size=200))
def test_config_loader_fuzz_on_arbitrary_text(tmp_path, text):
    path = tmp_path / "text.yaml"
    path.write_text(text)
    try:
        read_config(path)
    except ConfigError as exc:
        assert "text.yaml" in str(exc)


@settings(max_examples=200, deadline=None)
@given(coords=st.lists(floats, max_size=3))
def test_goal_check_names_the_problem(coords):
    """Goals reaching a learner (both learner nodes use this check before acting on a goal)."""
    from sagg_common.diagnostics import goal_problem
    pos, problem = goal_problem(coords, [-10.0, -10.0], [10.0, 10.0])
    valid = len(coords) == 2 and all(math.isfinite(c) and -10.0 <= c <= 10.0 for c in coords)
    assert (problem == "") == valid
    if not valid:
        assert "allowed: 2 finite values within task_space" in problem
    else:
        assert pos.tolist() == coords


@settings(max_examples=300, deadline=None)
@given(values=st.lists(floats, max_size=8))
@example(values=[1.7e308, -1.7e308, 1e200])  # finite, but the quick a·a overflows: the exact check decides
@example(values=[0.0, math.nan])
def test_all_finite_is_exact(values):
    """The quick finiteness test of every command, observation and simulator call."""
    from sagg_common.diagnostics import all_finite

    a = np.array(values, dtype=np.float64)
    assert all_finite(a) == bool(np.isfinite(a).all())
