"""Checkpoint and resume: the write-ahead journal, the learner's and the generator's checkpoints
in-process, and the graph surviving a SIGKILL of the learner and (separately) of the generator."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np
import pytest

from sagg_bringup.inprocess.experiment import InProcessRun
from sagg_bringup.graph.setups import load_experiment_config
from sagg_common.journal import Journal, read_journal
from sagg_goal_generator.checkpoint import GeneratorCheckpointer
from sagg_goal_generator.core import GoalGenerator
from sagg_low_level.checkpoint import LearnerCheckpointer
from sagg_low_level.memory import SampleMemory

import test_nodes_graph
from sagg_low_level.checkpoint import checkpoint_memory
from test_nodes_graph import (ROOT, RUN_TIMEOUT, STARTUP_TIMEOUT, Collector, graph_params, in_process, logs,
                              same_bits, start, stop)

ros_env = test_nodes_graph.ros_env  # the fixture: a private ROS domain per test

SMALL = {"arm.dof": 7, "arm.mode": "kinematic"}


# ------------------------------------------------------------------------------- journal
def test_journal_drops_a_torn_or_corrupt_tail(tmp_path):
    path = tmp_path / "j.bin"
    j = Journal(path)
    recs = [(1, np.array([0.0, -0.0, 5e-324, np.pi])), (2, np.arange(7.0)), (3, np.empty(0))]
    for kind, v in recs:
        j.append(kind, v)
    j.close()
    full = path.read_bytes()
    got, torn = read_journal(path)
    assert torn == 0 and [k for k, _ in got] == [1, 2, 3]
    assert all(v.tobytes() == w.tobytes() for (_, v), (_, w) in zip(got, recs))
    # a kill in mid-write: every prefix gives the records complete in it, never a partial one
    sizes = [0]
    for kind, v in recs:
        sizes.append(sizes[-1] + 4 + 1 + 4 + 8 * len(v) + 4)
    for cut in range(len(full)):
        path.write_bytes(full[:cut])
        got, torn = read_journal(path)
        complete = sum(1 for s in sizes[1:] if s <= cut)
        assert len(got) == complete and torn == cut - sizes[complete]
    # a flipped bit in the second record: the first is kept, the rest dropped
    bad = bytearray(full)
    bad[sizes[1] + 12] ^= 0x10
    path.write_bytes(bytes(bad))
    got, torn = read_journal(path)
    assert len(got) == 1 and torn == len(full) - sizes[1]
    with pytest.raises(ValueError, match="kind"):
        Journal(tmp_path / "k.bin").append(256, [1.0])


# ------------------------------------------------------------------------------- in-process
def _run_with_checkpoints(cfg, ck_dir, steps, learner_every=300, gen_every=200, stop_at=None):
    """An in-process run whose learner and generator journal and checkpoint into ck_dir (as the
    nodes do); returns the run. Not closed: as if the process was killed at ``steps``."""
    run = InProcessRun(cfg)
    ck = LearnerCheckpointer(ck_dir, run.learner, learner_every)
    assert ck.resume() == []
    gk = GeneratorCheckpointer(ck_dir, run.generator, gen_every)
    assert gk.resume() == []
    forward = run.learner.on_report

    def on_report(r):
        ck.on_report(r)
        forward(r)
        gk.maybe_save()

    run.learner.on_report = on_report
    run.learner.on_sample = ck.on_sample
    choose = run.generator.next_goal

    def next_goal():
        rec = choose()
        gk.on_goal(rec)
        return rec

    run.generator.next_goal = next_goal
    for t in range(100, steps + 1, 100):
        run.step_until(t)
        ck.maybe_save()
    run.step_until(steps)
    return run


def test_learner_and_generator_resume_in_process(tmp_path):
    cfg = load_experiment_config(ROOT / "config/arm15_y50.yaml", SMALL)
    run = _run_with_checkpoints(cfg, tmp_path, 1057)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert "learner.json" in names and "generator.json" in names
    assert not [n for n in names if n.endswith(".tmp") or ".tmp." in n]
    # torn last record (a kill in mid-write): dropped, the rest restored
    journals = sorted(tmp_path.glob("learner_journal_*.bin"), key=lambda p: int(p.stem.split("_")[-1]))
    with open(journals[-1], "ab") as fh:
        fh.write(b"\x4a\x47\x41\x53\x01\x10\x00")
    run2 = InProcessRun(cfg)
    ck2 = LearnerCheckpointer(tmp_path, run2.learner, 300)
    replay = ck2.resume()
    lr, lr2 = run.learner, run2.learner
    assert ck2.resumed_from["torn_bytes"] == 7 and ck2.resumed_from["journal_records_applied"] > 0
    assert lr2.memory.digest() == lr.memory.digest() and len(lr2.memory) == 1057
    for c in ("micro_actions", "reports_sent", "attempts", "goals_done", "exploration_phases"):
        assert getattr(lr2, c) == getattr(lr, c), c
    # the journaled tail is republished: samples and reports, in order, ending with the last ones
    idx = [r for r in replay if isinstance(r, int)]
    reps = [r for r in replay if not isinstance(r, int)]
    assert idx == list(range(idx[0], 1057)) and [r.seq for r in reps] == list(range(reps[0].seq, lr.reports_sent + 1))
    # the rng continues on a jumped stream (not the numbers drawn since the checkpoint)
    assert lr2.rng.bit_generator.state != lr.rng.bit_generator.state
    # the generator: checkpoint + the reports after it + the journaled goals replayed = the original
    gen2 = GoalGenerator(cfg["sagg_goal_generator"])
    gk2 = GeneratorCheckpointer(tmp_path, gen2, 200)
    pending = gk2.resume()
    assert gen2.reports < run.generator.reports and pending, "the kill must fall between checkpoints"
    for r in reps:
        if r.seq <= gen2.reports:
            continue
        assert r.seq == gen2.reports + 1
        gen2.report(r.kind, r.target if len(r.target) else r.reached, r.competence)
        while pending and pending[0].after_report == gen2.reports:
            want = pending.pop(0)
            got = gen2.next_goal()
            assert (got.seq, got.position.tobytes()) == (want.seq, want.position.tobytes())
    g1 = run.generator
    assert not pending and gen2.reports == g1.reports
    assert [(g.seq, g.mode, g.after_report, g.position.tobytes(), g.competence) for g in gen2.goals] == \
           [(g.seq, g.mode, g.after_report, g.position.tobytes(), g.competence) for g in g1.goals]
    assert gen2.region_snapshot() == g1.region_snapshot() and gen2.tree.splits == g1.tree.splits
    assert gen2.rng.bit_generator.state == g1.rng.bit_generator.state
    assert gen2.tree.rng.bit_generator.state == g1.tree.rng.bit_generator.state
    # and it chooses the same next goal
    assert gen2.next_goal().position.tobytes() == g1.next_goal().position.tobytes()


def test_checkpoint_of_another_run_is_refused(tmp_path):
    cfg = load_experiment_config(ROOT / "config/arm15_y50.yaml", SMALL)
    _run_with_checkpoints(cfg, tmp_path, 300)
    other = InProcessRun(load_experiment_config(ROOT / "config/arm15_y50.yaml", {**SMALL, "seed": 3}))
    with pytest.raises(ValueError, match="seed"):
        LearnerCheckpointer(tmp_path, other.learner, 100).resume()
    with pytest.raises(ValueError, match="seed"):
        GeneratorCheckpointer(tmp_path, other.generator, 100).resume()
    with pytest.raises(ValueError, match="checkpoint_every"):
        LearnerCheckpointer(tmp_path / "r", other.learner, 0)


def test_actuator_riac_tree_resumes_from_its_checkpoint(tmp_path):
    """ACTUATOR-RIAC: the (α, Δα) region tree and its split stream come back as checkpointed."""
    cfg = load_experiment_config(ROOT / "config/arm15_y50.yaml", {**SMALL, "strategy": "actuator-riac"})
    run = InProcessRun(cfg)
    ck = LearnerCheckpointer(tmp_path, run.learner, 10**9)
    assert ck.resume() == []
    run.learner.on_sample = ck.on_sample
    run.step_until(1500)
    tree = run.learner.riac_tree
    assert len(tree.splits) >= 2  # a tree worth restoring
    ck.save()
    snap = [(r.id, r.count, r.lower.tobytes(), r.upper.tobytes(), r.interest) for r in tree.leaves()]
    again = InProcessRun(cfg)
    LearnerCheckpointer(tmp_path, again.learner, 10**9).resume()
    t2 = again.learner.riac_tree
    assert [(r.id, r.count, r.lower.tobytes(), r.upper.tobytes(), r.interest) for r in t2.leaves()] == snap
    assert t2.splits == tree.splits and t2.rng.bit_generator.state == tree.rng.bit_generator.state
    assert again.learner.memory.digest() == run.learner.memory.digest()
    again.step_until(again.learner.micro_actions + 200)  # and it goes on learning with that tree
    assert again.learner.riac_tree is t2 and t2.n_added > tree.n_added


# ------------------------------------------------------------------------------- graph
def _samples_by_index(col) -> dict[int, bytes]:
    """Received samples by index (republished duplicates must carry the same bits)."""
    out: dict[int, bytes] = {}
    for s in col.samples:
        b = np.concatenate([s.alpha, s.delta_alpha, s.delta_y]).tobytes()
        assert out.setdefault(int(s.index), b) == b, f"sample {s.index} republished with other values"
    return out


def _final_memory(ck_dir: Path) -> SampleMemory:
    meta = json.loads((ck_dir / "learner.json").read_text())
    mem = checkpoint_memory(ck_dir)
    assert mem.digest() == meta["memory_digest"]  # (stored at shutdown)
    assert len(meta["segments"]) >= 2  # append-only segments, one per checkpoint with new samples
    return mem


def _wait_killed(p) -> None:
    p.kill()
    p.wait(10)


def test_learner_sigkill_then_resume_keeps_every_published_sample_once(ros_env, tmp_path):
    base = ROOT / "config" / "arm15_y50.yaml"
    steps, kill_at = 1500, 600
    ck = tmp_path / "ck"
    params = graph_params(base, tmp_path / "params.yaml", {"dof": 7, "mode": "kinematic"},
                          learner={"max_micro_actions": steps, "min_sample_subscribers": 1,
                                   "checkpoint_dir": str(ck), "checkpoint_every": 250,
                                   "resume": True},  # (a restart continues: asked for, not by default)
                          generator={"min_goal_subscribers": 1})
    col = Collector(ros_env["ctx"])
    procs = [start(ros_env, s, params, tmp_path) for s in ("mujoco_bridge", "goal_generator")]
    learner = start(ros_env, "learner", params, tmp_path)
    assert col.spin_until(lambda: len(col.samples) >= kill_at, STARTUP_TIMEOUT + RUN_TIMEOUT, procs + [learner]), \
        logs(tmp_path)
    _wait_killed(learner)
    col.spin_for(1.0)  # whatever was in flight
    before = _samples_by_index(col)
    assert len(before) >= kill_at and sorted(before) == list(range(len(before)))
    assert sorted(p.name for p in ck.glob("learner_journal_*.bin")), "no journal written"
    col.status = None
    learner = start(ros_env, "learner", params, tmp_path)
    ok = col.spin_until(lambda: col.stopped() and col.status.micro_actions >= steps, STARTUP_TIMEOUT + RUN_TIMEOUT,
                        procs + [learner])
    assert ok, logs(tmp_path)
    col.spin_until(lambda: len(_samples_by_index(col)) >= steps, 20.0)
    stop(learner)  # SIGINT: final checkpoint
    assert learner.returncode == 0, logs(tmp_path)
    assert "resumed from" in (tmp_path / "learner.log").read_text()
    mem = _final_memory(ck)
    assert len(mem) == steps
    rows = [np.concatenate([mem.alpha[i], mem.delta_alpha[i], mem.delta_y[i]]).tobytes() for i in range(len(mem))]
    assert len(set(rows)) == len(rows)  # no sample twice
    for i, b in before.items():  # every sample published before the kill, at its index, bit for bit
        assert rows[i] == b
    after = _samples_by_index(col)  # ... and everything published at all is in the memory
    assert sorted(after) == list(range(steps)) and all(rows[i] == b for i, b in after.items())
    # the generator saw every report once, in order, across the restart (republished ones dropped)
    sent = json.loads((ck / "learner.json").read_text())["reports_sent"]
    assert col.spin_until(lambda: col.regions.reports == sent and max(r.seq for r in col.reports) == sent, 20.0), \
        (col.regions.reports, max(r.seq for r in col.reports), sent)
    assert "were lost or reordered" not in (tmp_path / "goal_generator.log").read_text()


# alp-gmm fitting every 5 goals: fits before and after the kill (~26 goals in the run)
TEACHER_SETS = {"sagg-riac": {}, "alp-gmm": {"alp_gmm.fit_every": 5, "alp_gmm.bootstrap": 5, "alp_gmm.k_max": 3},
                "discretized-progress": {}}


@pytest.mark.parametrize("strategy", TEACHER_SETS)
def test_generator_sigkill_then_resume_leaves_the_run_unchanged(ros_env, tmp_path, strategy):
    """The generator is killed mid-run and restarted from its checkpoint + goal journal; the
    reports it missed come from the learner's history: the lockstep run still equals the
    in-process one bit for bit (samples, goals, region tree), whatever teacher chooses the goals."""
    base = ROOT / "config" / "arm15_y50.yaml"
    arm = {"dof": 7, "mode": "kinematic"}
    steps, kill_at = 1200, 500
    ck = tmp_path / "ck"
    sets = TEACHER_SETS[strategy]
    params = graph_params(base, tmp_path / "params.yaml", arm,
                          learner={"max_micro_actions": steps, "min_sample_subscribers": 1, "goal_retry": 1.0},
                          generator={"min_goal_subscribers": 1, "checkpoint_dir": str(ck), "checkpoint_every": 150,
                                     "resume": True, **sets}, everyone={"strategy": strategy})
    col = Collector(ros_env["ctx"])
    bridge = start(ros_env, "mujoco_bridge", params, tmp_path)
    gen = start(ros_env, "goal_generator", params, tmp_path)
    learner = start(ros_env, "learner", params, tmp_path)
    assert col.spin_until(lambda: len(col.samples) >= kill_at, STARTUP_TIMEOUT + RUN_TIMEOUT, [bridge, gen, learner]), \
        logs(tmp_path)
    _wait_killed(gen)
    os.rename(tmp_path / "goal_generator.log", tmp_path / "goal_generator.1.log")
    col.spin_for(1.0)
    gen = start(ros_env, "goal_generator", params, tmp_path)
    ok = col.spin_until(lambda: col.stopped() and len(_samples_by_index(col)) >= steps,
                        STARTUP_TIMEOUT + RUN_TIMEOUT, [bridge, gen, learner])
    assert ok, logs(tmp_path)
    run, reports = in_process(base, {**{f"arm.{k}": v for k, v in arm.items()}, "strategy": strategy, **sets}, steps)
    col.spin_until(lambda: col.regions is not None and col.regions.reports >= len(reports), 30.0)
    col.spin_for(0.5)
    assert "resumed from" in (tmp_path / "goal_generator.log").read_text(), logs(tmp_path)
    if strategy == "alp-gmm":
        assert len(run.generator.teacher.fits) >= 3
    got = _samples_by_index(col)
    mem = SampleMemory(7, 7, 2)
    for i in range(steps):
        v = np.frombuffer(got[i])
        mem.add(v[:7], v[7:14], v[14:])
    if mem.digest() != run.learner.memory.digest():
        ref = run.learner.memory
        first = next(i for i in range(steps) if np.frombuffer(got[i]).tobytes() != np.concatenate(
            [ref.alpha[i], ref.delta_alpha[i], ref.delta_y[i]]).tobytes())
        pytest.fail(f"samples differ from the in-process run from index {first} (killed at >= {kill_at})\n"
                    f"graph goals {[(g.seq, g.after_report) for g in col.goals]}\nin-process goals "
                    f"{[(g.seq, g.after_report) for g in run.generator.goals]}\n{logs(tmp_path)}")
    goals = {}
    for g in col.goals:  # a goal asked again after the restart is published again: same values
        key = (g.mode, g.after_report, np.array(g.position).tobytes())
        assert goals.setdefault(int(g.seq), key) == key
    want = {g.seq: (g.mode, g.after_report, g.position.tobytes()) for g in run.generator.goals}
    assert {s: want.get(s) for s in goals} == goals  # every goal published is the in-process one
    # The restarted generator may answer the learner's waiting request before this test's
    # subscription has discovered its new /sagg/goal publisher (volatile): those goals reach the
    # learner (the samples above are the in-process ones) but not this test. Only such a run, right
    # after the restart, may be missing here; the generator's own count is checked below.
    missed = sorted(set(want) - set(goals))
    assert not missed or (missed == list(range(missed[0], missed[0] + len(missed)))
                          and missed[0] - 1 in goals and len(missed) <= 20), missed
    tree, snap = col.regions, run.generator.region_snapshot()
    assert (tree.reports, tree.goals, tree.splits) == (len(reports), len(run.generator.goals),
                                                         len(run.generator.tree.splits))
    assert [r.id for r in tree.regions] == [r["id"] for r in snap]
    for r, s in zip(tree.regions, snap):
        assert same_bits(r.lower, s["lower"]) and same_bits(r.upper, s["upper"]) and r.count == s["count"]
        assert same_bits([r.interest], [s["interest"]])


def test_a_request_answered_meanwhile_gets_the_same_goal(ros_env, tmp_path):
    """A deferred goal request whose goal was meanwhile given to a repeated request (goal_retry) is
    answered with that goal when released, never with a new one (found when a killed generator's
    restart met the learner's retries: one goal too many, the run no longer equal in-process)."""
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sagg_msgs.msg import CompetenceReport, Goal
    from sagg_msgs.srv import NextGoal
    params = graph_params(ROOT / "config" / "arm15_y50.yaml", tmp_path / "params.yaml", {"dof": 7, "mode": "kinematic"},
                          generator={"min_goal_subscribers": 1, "regions_period": 3600.0})
    gen = start(ros_env, "goal_generator", params, tmp_path)
    # (the generator takes reports from the learner only)
    node = rclpy.create_node("sagg_learner", context=ros_env["ctx"])
    ex = rclpy.executors.SingleThreadedExecutor(context=ros_env["ctx"])
    ex.add_node(node)
    pub = node.create_publisher(CompetenceReport, "/sagg/competence", QoSProfile(
        depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    client = node.create_client(NextGoal, "/sagg/next_goal")

    def spin_until(cond, timeout=STARTUP_TIMEOUT):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not cond():
            assert gen.poll() is None, logs(tmp_path)
            ex.spin_once(timeout_sec=0.05)
        return cond()

    def report(seq):
        pub.publish(CompetenceReport(seq=seq, goal_seq=0, kind=2, target=[], reached=[10.0 + seq, 0.0],
                                     start=[10.0, 0.0], competence=0.0, micro_actions=seq))

    assert spin_until(lambda: client.service_is_ready() and pub.get_subscription_count() >= 1), logs(tmp_path)
    first = client.call_async(NextGoal.Request(after_report=3))  # deferred: reports 1..3 not in yet
    for s in (1, 2, 3):
        report(s)
    ex.spin_once(timeout_sec=0.5)
    assert not first.done()  # still deferred: nobody subscribes to /sagg/goal yet
    goals = []
    node.create_subscription(Goal, "/sagg/goal", goals.append,
                             QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    time.sleep(2.0)  # let the generator match the subscriber (its release timer is off: regions_period)
    again = client.call_async(NextGoal.Request(after_report=3))  # the repeated request: answered now
    assert spin_until(again.done, 30.0), logs(tmp_path)
    report(4)  # the learner moved on; this releases the first request
    assert spin_until(first.done, 30.0), logs(tmp_path)
    spin_until(lambda: len(goals) >= 2, 5.0)
    a, b = again.result().goal, first.result().goal
    assert (a.seq, a.after_report) == (b.seq, b.after_report) == (1, 3)
    assert np.array(a.position).tobytes() == np.array(b.position).tobytes()
    assert {(g.seq, g.after_report) for g in goals} == {(1, 3)}


def test_a_checkpoint_is_continued_only_when_asked(tmp_path):
    """A directory holding a checkpoint is refused without ``resume`` (nothing
    written: the run it belongs to is left as it was); with it, or in an empty directory, fine."""
    cfg = load_experiment_config(ROOT / "config/arm15_y50.yaml", SMALL)
    _run_with_checkpoints(cfg, tmp_path, 300)
    files = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    for ck in (LearnerCheckpointer(tmp_path, InProcessRun(cfg).learner, 100),
               GeneratorCheckpointer(tmp_path, InProcessRun(cfg).generator, 100)):
        with pytest.raises(ValueError, match="resume:=true"):
            ck.check_resume(False)
        ck.check_resume(True)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == files
    LearnerCheckpointer(tmp_path / "new", InProcessRun(cfg).learner, 100).check_resume(False)
