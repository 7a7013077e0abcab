"""A recording whose recorder was killed (SIGKILL of a whole `sagg run`): the unfinished mcap is
recovered up to its last complete chunk (bag_recover), `sagg run --resume` continues the run with
the bag's lost tail republished into bag2, and `sagg relearn bag bag2` rebuilds the run's memory."""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader

from sagg_bringup.bags.bag_channels import channel_metadata
from sagg_bringup.bags.bag_reader import bag_messages
from sagg_bringup.bags.bag_recover import REPORT_FILE, recover_bag
from sagg_bringup.bags.bags import relearn
from sagg_bringup.graph.processes import pick_domain_id
from sagg_bringup.graph.run_file import read_run_file
from sagg_bringup.bags.recorder import BagWriter, TopicSpec, make_typestore
from sagg_low_level.checkpoint import published
from installed import SAGG

ROOT = Path(__file__).resolve().parents[1]


def _finished_bag(tmp_path: Path):
    """A closed BagWriter bag of ~3 MB (several chunks), two topics, strictly increasing times;
    /a offered transient_local. Returns (mcap path, [(topic, ts, bytes)] in order)."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
    store = make_typestore()
    string = store.types["std_msgs/msg/String"]
    bag = BagWriter(tmp_path / "full", [TopicSpec("/a", "std_msgs/msg/String"),
                                        TopicSpec("/b", "std_msgs/msg/String")], typestore=store)
    zero = QosTime(0, 0)
    bag.offer("/a", [Qos(QosHistory.KEEP_LAST, 7, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL,
                         zero, zero, QosLiveliness.AUTOMATIC, zero, False)])
    msgs = []
    for i in range(6000):
        topic = "/a" if i % 3 else "/b"
        raw = bytes(store.serialize_cdr(string(data=f"{i:06d}" + "x" * (400 + i % 97)), "std_msgs/msg/String"))
        bag.write(topic, 1_000_000_000 + 1000 * i, raw)
        msgs.append((topic, 1_000_000_000 + 1000 * i, raw))
    bag.close()
    return tmp_path / "full" / "full.mcap", msgs


def _unfinished(tmp_path: Path, name: str, data: bytes) -> Path:
    d = tmp_path / name
    d.mkdir()
    (d / f"{name}.mcap").write_bytes(data)  # no metadata.yaml: a recorder killed at this byte
    return d


def test_recovery_keeps_every_complete_chunk_of_a_truncated_mcap(tmp_path):
    mcap, msgs = _finished_bag(tmp_path)
    full = mcap.read_bytes()
    with open(mcap, "rb") as f:
        summary = make_reader(f).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 3
    data_end = max(c.chunk_start_offset + c.chunk_length + c.message_index_length for c in chunks)
    c2 = chunks[1]
    c2_end = c2.chunk_start_offset + c2.chunk_length
    # what: (cut, the bytes after the last complete record that cannot be read)
    cuts = {"empty": (0, 0), "in the magic": (5, 5), "in the header": (30, 30),
            "after chunk 1 and its indexes": (c2.chunk_start_offset, 0),
            "inside chunk 2's record header": (c2.chunk_start_offset + 20, 20),
            "middle of chunk 2": (c2.chunk_start_offset + c2.chunk_length // 2, c2.chunk_length // 2),
            "chunk 2 one byte short": (c2_end - 1, c2.chunk_length - 1),
            "inside chunk 2's message indexes": (c2_end + 5, 5),
            "the whole data section": (data_end, 0),
            "a torn footer": (len(full) - 10, 0)}  # (the summary is not data: not counted)
    for k, (what, (cut, unreadable)) in enumerate(cuts.items()):
        bag = _unfinished(tmp_path, f"cut{k}", full[:cut])
        done = [c for c in chunks if c.chunk_start_offset + c.chunk_length <= cut]
        last_ns = max((c.message_end_time for c in done), default=-1)
        want = [m for m in msgs if m[1] <= last_ns]  # the messages of the complete chunks
        lines = []
        rep = recover_bag(bag, lines.append)
        assert rep["messages"] == len(want), what
        assert rep["topics"] == {t: n for t in ("/a", "/b") if (n := sum(1 for m in want if m[0] == t))}, what
        assert len(lines) == 1 and f"{len(want):,} messages" in lines[0], (what, lines)
        assert rep["bytes_unreadable"] == unreadable and rep["bytes"] == cut, what
        # a rosbag2 bag every reader takes: rosbags' Reader gives exactly those messages
        got = [(t, ts, bytes(raw)) for t, _, ts, raw in bag_messages([bag])]
        assert got == want, what
        meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        assert meta["version"] == 9 and meta["storage_identifier"] == "mcap" and meta["ros_distro"] == "jazzy"
        assert meta["message_count"] == len(want)
        counts = {t["topic_metadata"]["name"]: t["message_count"] for t in meta["topics_with_message_count"]}
        assert counts == rep["topics"], what
        if rep["topics"].get("/a"):  # the offered QoS, from the channel's metadata
            qos = next(t["topic_metadata"]["offered_qos_profiles"] for t in meta["topics_with_message_count"]
                       if t["topic_metadata"]["name"] == "/a")
            assert qos[0]["durability"] == "transient_local" and qos[0]["depth"] == 7, qos
            assert all("topic_type_hash" in m for m in channel_metadata(bag / f"cut{k}.mcap").values())
        # the user's bytes are kept; a second recovery changes nothing
        assert (bag / f"cut{k}.mcap.unfinished").read_bytes() == full[:cut]
        before = {p.name: p.read_bytes() for p in bag.iterdir()}
        assert recover_bag(bag, lines.append) == json.loads((bag / REPORT_FILE).read_text()) == rep
        assert {p.name: p.read_bytes() for p in bag.iterdir()} == before and len(lines) == 1
        assert not (tmp_path / f"cut{k}.recovering").exists()


def test_recovery_stops_at_a_corrupt_chunk(tmp_path):
    """A flipped byte inside chunk 2 (its crc no longer matches): chunk 1's messages, the rest named."""
    mcap, msgs = _finished_bag(tmp_path)
    data = bytearray(mcap.read_bytes())
    with open(mcap, "rb") as f:
        chunks = sorted(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    data[chunks[1].chunk_start_offset + chunks[1].chunk_length // 2] ^= 0xFF
    bag = _unfinished(tmp_path, "bad", bytes(data))
    rep = recover_bag(bag)
    assert rep["messages"] == sum(1 for m in msgs if m[1] <= chunks[0].message_end_time) > 0
    assert "crc" in rep["stopped"] and rep["bytes_unreadable"] == len(data) - chunks[1].chunk_start_offset


def test_resume_republishes_the_samples_a_bag_lost_and_names_what_it_cannot(tmp_path):
    """The bag of a killed run lacks a tail that can reach further back than the learner's journals
    (a short checkpoint_every): `republish_from` republishes the stored samples from the first
    index the bag lacks; reports older than the journals are named, and bags holding more than the
    checkpoints are refused, naming the indices."""
    from sagg_bringup.inprocess.experiment import InProcessRun
    from sagg_bringup.graph.resume_check import compare
    from sagg_bringup.graph.setups import load_experiment_config
    from sagg_common.params import ConfigError
    from sagg_goal_generator.checkpoint import published as gen_published
    from sagg_low_level.checkpoint import LearnerCheckpointer
    from test_checkpoint import SMALL, _run_with_checkpoints

    cfg = load_experiment_config(ROOT / "config/arm15_y50.yaml", SMALL)
    run = _run_with_checkpoints(cfg, tmp_path, 1057, learner_every=100, gen_every=50)  # killed at 1057
    lr = run.learner
    held = published(tmp_path)
    gen = gen_published(tmp_path)
    assert held["samples"] == 1057 and held["reports"] == lr.reports_sent and gen["goals"] == len(run.generator.goals)
    assert 300 < held["first_sample"] < 1057 and held["first_report"] > 1  # the journals' reach
    # the bag lost everything after sample 299 and report 10: the journals alone do not cover that
    res = compare(300, 10, 2, str(tmp_path), str(tmp_path))
    assert res["republish_from"] == 300
    assert res["lines"][0].startswith("samples 300..1056 (757) are in the learner's checkpoint, not in the bags")
    assert res["unresolved"][0].startswith(f"reports 11..{held['first_report'] - 1} ")
    assert f"{held['first_report']}..{held['reports']} are republished" in res["unresolved"][0]
    # resumed with it, the learner republishes every sample from 300 on, in order, then its journal
    again = InProcessRun(cfg)
    replay = LearnerCheckpointer(tmp_path, again.learner, 100).resume(republish_from=300)
    assert [i for i in replay if isinstance(i, int)] == list(range(300, 1057))
    assert again.learner.memory.digest() == lr.memory.digest()
    # a bag holding more than the checkpoint: refused, naming the indices
    with pytest.raises(ConfigError, match=r"the bags hold samples 1057\.\.1199 that the learner's checkpoint"):
        compare(1200, 10, 2, str(tmp_path), str(tmp_path))


def _stat(proc: Path) -> list[str]:
    """The fields of ``/proc/<pid>/stat`` after the command name: state, parent pid, ..."""
    return (proc / "stat").read_text().rsplit(")", 1)[1].split()


def _wait_gone(marker: str, timeout: float = 30.0) -> None:
    """Until no live process has ``marker`` in its command line (the killed run's nodes)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        alive = []
        for d in Path("/proc").iterdir():
            try:
                if d.name.isdigit() and marker in (d / "cmdline").read_bytes().decode(errors="replace") \
                        and _stat(d)[0] != "Z":
                    alive.append(d.name)
            except OSError:
                continue
        if not alive:
            return
        time.sleep(0.05)
    raise AssertionError(f"processes of the killed run still alive after {timeout} s: {alive}")


def test_recovery_registers_an_unknown_type_from_the_bag(tmp_path):
    """A type the typestore does not know (a user's message): registered from the mcap schema's
    ``ros2msg`` text, its messages kept; a bag whose close was cut before metadata.yaml (a finished
    mcap) is recovered whole."""
    from rosbags.typesys import get_types_from_msg
    store = make_typestore()
    store.register(get_types_from_msg("float64 x\nstring name", "foo_msgs/msg/Bar"))
    bag = BagWriter(tmp_path / "b", [TopicSpec("/bar", "foo_msgs/msg/Bar")], typestore=store)
    bar = store.types["foo_msgs/msg/Bar"]
    raws = [bytes(store.serialize_cdr(bar(x=float(i), name=f"n{i}"), "foo_msgs/msg/Bar")) for i in range(50)]
    for i, raw in enumerate(raws):
        bag.write("/bar", 10 + i, raw)
    bag.close()
    (tmp_path / "b" / "metadata.yaml").unlink()
    rep = recover_bag(tmp_path / "b")
    assert rep["topics"] == {"/bar": 50} and not rep["skipped"] and rep["bytes_unreadable"] == 0
    assert [bytes(raw) for _, ty, _, raw in bag_messages([tmp_path / "b"]) if ty == "foo_msgs/msg/Bar"] == raws


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_sigkill_of_a_whole_run_then_resume_and_relearn(tmp_path):
    """`sagg run` killed with SIGKILL (its whole process group) once its bag has a chunk on disk:
    `--resume` recovers the bag (counts reported), republishes what the bag lost, reaches the
    budget, and `relearn bag bag2` gives the run's final memory digest."""
    steps = 2000
    run = tmp_path / "run"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    log = open(tmp_path / "first.log", "w")
    p = subprocess.Popen([SAGG, "run", str(ROOT / "config/arm8.yaml"), "--micro-actions", str(steps),
                          "--eval-every", "1000", "--out", str(run), "--quiet", "--no-report",
                          "--domain-id", str(pick_domain_id())],
                         env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    mcap = run / "bag" / "bag.mcap"
    try:
        end = time.monotonic() + 120
        while not (mcap.is_file() and mcap.stat().st_size > 0):  # the first chunk (~1 MiB) is on disk
            assert p.poll() is None and time.monotonic() < end, (tmp_path / "first.log").read_text()
            time.sleep(0.1)
    finally:
        os.killpg(p.pid, signal.SIGKILL)  # sagg run and its evaluation process; the nodes get SIGKILL
        p.wait(timeout=30)                # when their parent dies (PR_SET_PDEATHSIG)
        log.close()
    _wait_gone(str(run / "params.yaml"))
    assert not (run / "bag" / "metadata.yaml").exists() and not (run / "summary.json").exists()
    original = _sha(mcap)
    before = published(run / "checkpoint")  # what the learner had published when killed
    settings = read_run_file(run)  # the run's own settings, written before its nodes started
    assert (settings["driver"], settings["micro_actions"], settings["domain_private"]) == ("sim", steps, False)

    r = subprocess.run([SAGG, "run", "--resume", str(run), "--eval-every", "1000", "--quiet",
                        "--no-report", "--domain-id", str(pick_domain_id())],
                       env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    rec = json.loads((run / "bag" / REPORT_FILE).read_text())
    n = rec["topics"]["/sagg/sample"]
    assert 0 < n <= before["samples"] < steps
    assert f"recovered unfinished bag {run / 'bag'}: {rec['messages']:,} messages" in r.stderr
    if n < before["samples"]:  # the recorder's unwritten tail, named and republished
        assert f"samples {n}..{before['samples'] - 1} ({before['samples'] - n:,}) are in the learner's " \
               "checkpoint, not in the bags: republished into the new bag" in r.stderr
    assert _sha(run / "bag" / "bag.mcap.unfinished") == original  # the user's bytes are kept
    s = json.loads((run / "summary.json").read_text())
    assert s["micro_actions"] == s["memory"]["samples"] == steps
    after = read_run_file(run)  # the resumed segment keeps what the run was started from
    assert (after["config"], after["overrides"]) == (str(ROOT / "config/arm8.yaml"), settings["overrides"])
    assert s["bag"]["paths"] == [str(run / "bag"), str(run / "bag2")]
    assert s["bag"]["recovered"] == [rec]
    assert s["bag"]["resume_check"]["republish_from"] == n and not s["bag"]["resume_check"]["unresolved"]
    assert s["bag"]["resume_check"]["checkpoints"]["samples"] == before["samples"]

    re = relearn([run / "bag", run / "bag2"], tmp_path / "re", evaluate=False, report=False, out=lambda _: None)
    ck = json.loads((run / "checkpoint" / "learner.json").read_text())
    assert re["memory"]["samples"] == steps
    assert re["memory"]["digest"] == s["memory"]["digest"] == ck["memory_digest"]
    assert re["goals_match"] and re["regions_match"] and re["reports"] == s["reports"]


def _children(pid: int) -> dict[int, str]:
    """pid -> command line of the live processes whose parent is ``pid`` (from /proc)."""
    out = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            ppid = int(_stat(d)[1])
            if ppid == pid:
                out[int(d.name)] = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except (OSError, IndexError, ValueError):
            pass
    return out


def _alive(pid: int) -> bool:
    try:
        state = _stat(Path("/proc") / str(pid))[0]
    except OSError:
        return False
    return state != "Z"


def test_the_evaluation_process_ends_when_sagg_run_is_killed_alone(tmp_path):
    """SIGKILL of the `sagg run` process only (the OOM killer, `kill -9 PID`, a timeout that kills
    the child): its evaluation process (multiprocessing, spawn) notices within seconds and exits
    instead of waiting on its queue for ever (it held both ends of it)."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    p = subprocess.Popen([SAGG, "run", str(ROOT / "config/arm8.yaml"), "--micro-actions", "100000",
                          "--eval-every", "50000", "--out", str(tmp_path / "run"), "--quiet", "--no-report",
                          "--domain-id", str(pick_domain_id())],
                         env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        end = time.monotonic() + 120
        evaluator = []
        while not evaluator:
            assert p.poll() is None and time.monotonic() < end
            evaluator = [c for c, cmd in _children(p.pid).items() if "multiprocessing.spawn" in cmd]
            time.sleep(0.2)
        assert _alive(evaluator[0])
        os.kill(p.pid, signal.SIGKILL)
        p.wait(timeout=30)
        end = time.monotonic() + 15
        while _alive(evaluator[0]) and time.monotonic() < end:
            time.sleep(0.2)
        assert not _alive(evaluator[0]), f"evaluation process {evaluator[0]} outlived sagg run"
        # (multiprocessing's resource tracker, also a child of sagg run, ends once the last process
        # holding its pipe has: not checked here, it holds no resource of ours)
    finally:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
