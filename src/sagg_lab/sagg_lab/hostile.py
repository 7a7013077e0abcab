"""``sagg bench hostile``: a running graph under a fuzzer (docs/safety.md).

Two phases, each a real ``sagg run`` (lockstep, its own ROS domain, recorder and evaluator) and a
fuzzer node in this process publishing the hostile cases (:func:`cases`) on the graph's topics:

- ``content``: the learner's ``plausibility.check_sources`` off, so that each content check is
  what meets the fuzzer's messages (joint states outside the limits / 1e308 / NaN / unknown joint /
  wrong length / a future stamp, task points 1e308 / NaN, reports with seq +10^12 / NaN / a bad
  kind at the next seq, NaN samples and goals, bad commands to the bridge), and random mixtures;
- ``publishers``: the defaults, on a run with the next seed: a second source flooding
  /joint_states with 2,000 valid-looking states/s, forged valid samples at each of the next 300
  indices, a forged valid report at the next seq, a second publisher on /sagg/goal; and the
  ordinary neighbours of a real graph: a gripper driver publishing only its own joint,
  idle publishers on every watched topic, a burst from a publisher that then stays (idle), and the
  content phase's bag replayed into the live graph by ``sagg replay``.

Each case is active for a few seconds (or sent once), then the fuzzer's publishers are destroyed
and the graph is watched for a few quiet seconds. Per case: **rate**: micro-actions per second
while the case is active as a share of the rate in as long a quiet window just before it (at
least ``target`` for the gripper and the idle publishers); **survived** (the run and its nodes
alive, /sagg/status fresh), **counted** (the expected rejection counter on /diagnostics grew, or
for `sagg run`'s own handlers the summary's ``bag.rejected``), **logged** (the node logs name the
kind), **learning went on** (micro-actions grew after the case: in the quiet seconds, or later
within ``RESUME_LIMIT``; **longest wait**: the longest such delay beyond the quiet seconds, 0 if
none: a learner waits while the recorder works through a flood), **reports lost** (the generator's
skipped reports grew during the case). At the end, per phase, the invariants: all nodes alive (no
error in the summary), final test error below the initial one, no stored α outside the joint limits
(± tolerance), nothing non-finite in memory / goals / regions / curve, every command within
``max_joint_step`` of a preceding measured posture of the driver (or the rest posture: a return to
rest), the bag complete for the legitimate publishers (the nodes' published counts equal the
bag's counts less the fuzzer's own messages; nothing dropped by the recorder), and ``sagg relearn``
on the bag rebuilding exactly the run's memory and reports (no forged message took a real one's place).
"""
from __future__ import annotations

import dataclasses
import json
import os
import re
import signal
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from sagg_bringup.bags.recorder import msg_class
from sagg_common.cdr import (JointStateDecoder, PointStampedEncoder, decode_f64_array, decode_point_stamped,
                             encode_f64_array, encode_joint_state)
from sagg_common.msg_codecs import encode_report, encode_sample
from sagg_common.params import parse_set
from sagg_common.ros_params import reliable
from sagg_low_level.checkpoint import checkpoint_memory

from sagg_bringup.bags.bag_reader import bag_messages
from sagg_bringup.inprocess.arm_params import graph_params, load_graph_config
from sagg_bringup.graph.processes import find_node_executable, pick_domain_id
from sagg_bringup.bags.topics import watched_topics

SEC = 1_000_000_000
RESUME_LIMIT = 60.0  # s after a case within which learning must have gone on again
MATCH_WAIT = 5.0  # s a new publisher of the fuzzer waits for the graph's subscriptions to match it
FUZZ = "fuzz"  # frame_id of the fuzzer's stamped messages


@dataclass
class Case:
    name: str
    phase: str                      # "content" or "publishers"
    row: str                        # what the case is (its row of the hostile-input table)
    kinds: tuple[str, ...]          # expected rejection kinds: "<node>:<kind>" or "run:<key prefix>"
    send: Callable                  # send(fuzzer, k): the k-th burst of the case
    seconds: float = 3.0            # active time (bursts every `period` s); once: one burst
    once: bool = False
    period: float = 0.02
    target: float = 0.0             # the rate while active, as a share of the quiet rate, at least
    keep: bool = False              # the case's publishers stay (idle) through the quiet seconds
    stop: Callable | None = None    # stop(fuzzer): ends what the case started (e.g. a replay)
    log: str = ""                   # a line the node logs must hold (e.g. the hold's naming)


@dataclass
class Outcome:
    runs: int = 0
    survived: int = 0
    counted: int = 0
    learning: int = 0
    reports_lost: int = 0
    longest_resume: float = 0.0  # s from the case's end until micro-actions grew again (largest)
    shares: list = field(default_factory=list)  # micro-actions/s while active / quiet rate, per run


REPLAY_STARTUP = 60.0  # s: the longest wait for `sagg replay`'s first joint state


class Fuzzer:
    """The hostile node: publishers created per case (and destroyed after it), and what it
    watches (/diagnostics counters, /sagg/status, the bridge's newest stamp)."""

    def __init__(self, domain: int, learner: dict, replay_bag: Path | None = None):
        # lazy (heavy): ROS
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        from diagnostic_msgs.msg import DiagnosticArray
        from sensor_msgs.msg import JointState
        from sagg_msgs.msg import LearnerStatus

        self.rclpy = rclpy
        self.domain, self.replay_bag, self.replaying = domain, replay_bag, None
        self.replay_windows: list[tuple] = []  # (start, end) of each replay, ns
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("sagg_fuzzer", context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.learner = learner
        self.joints = list(learner["joints"])
        self.n = len(self.joints)
        self.task_topic = learner["task_topic"]
        self.cmd_topic = f"/{learner['controller'].strip('/')}/commands"
        self.rng = np.random.default_rng(12345)
        self.diag: dict[str, dict[str, str]] = {}     # node -> values
        self.status = None
        self.status_t = 0.0
        self.status_stamp = 0
        self.bridge_stamp = 0
        self.older_joint_states = 0  # /joint_states stamped before the bridge's newest: a replayed bag's
        self.sent: dict[str, int] = {}                # topic -> messages the fuzzer published
        self.pubs: dict[str, object] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, 100)
        self.node.create_subscription(LearnerStatus, "/sagg/status", self._on_status, 10)
        self._dec = JointStateDecoder()
        self.node.create_subscription(JointState, "/joint_states", self._on_js, 100, raw=True)

    # ------------------------------------------------------------------ watching
    def _on_diag(self, m) -> None:
        for st in m.status:
            self.diag[st.hardware_id] = {kv.key: kv.value for kv in st.values}

    def _on_status(self, m) -> None:
        # the live learner's only: a replayed bag's /sagg/status (another run's, stamped earlier)
        # would make its counts jump
        stamp = m.header.stamp.sec * SEC + m.header.stamp.nanosec
        if stamp < self.status_stamp:
            return
        self.status, self.status_t, self.status_stamp = m, time.monotonic(), stamp

    def _on_js(self, raw) -> None:
        st = self._dec.decode(raw)[0]
        if st < 10**15:  # (the fuzzer's own stamps are ~1e18 ns of wall time, or +1,000 s)
            # (the bridge's own stamps only increase: an older one is another run's, replayed)
            self.older_joint_states += st < self.bridge_stamp
            self.bridge_stamp = max(self.bridge_stamp, st)

    def count(self, node: str, kind: str) -> int:
        return int(self.diag.get(node, {}).get(f"rejected.{kind}", 0))

    def value(self, node: str, key: str) -> int:
        try:
            return int(self.diag.get(node, {}).get(key, 0))
        except ValueError:
            return 0

    def input_rejections(self) -> int:
        """The learner's rejected joint states and task points and both nodes' second-source
        rejections so far (what a gripper or an idle publisher must not cause)."""
        return sum(int(v) for node in ("sagg_learner", "sagg_goal_generator")
                   for k, v in self.diag.get(node, {}).items()
                   if k.startswith(("rejected.joint_states.", "rejected.task_point.")) or k.endswith(".second_source"))

    def micro_actions(self) -> int:
        return int(self.status.micro_actions) if self.status is not None else 0

    def spin(self, seconds: float) -> None:
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            self.ex.spin_once(timeout_sec=min(0.01, max(0.0, t_end - time.monotonic())))

    # ------------------------------------------------------------------ publishing
    def _pub(self, topic: str, cls_name: str, transient_local: bool = False):
        if topic not in self.pubs:
            pub = self.node.create_publisher(msg_class(cls_name), topic,
                                             reliable(1000, transient_local=transient_local))
            # a volatile message published before discovery matched the graph's subscriptions is
            # lost for them: wait, up to MATCH_WAIT s, until every subscription the graph has on the
            # topic matched this publisher (and see drop_publishers)
            want = self.node.count_subscribers(topic)
            t_end = time.monotonic() + MATCH_WAIT
            while pub.get_subscription_count() < want and time.monotonic() < t_end:
                self.spin(0.02)
            self.pubs[topic] = pub
        return self.pubs[topic]

    def publish(self, topic: str, cls_name: str, data: bytes, transient_local: bool = False) -> None:
        self._pub(topic, cls_name, transient_local).publish(data)
        self.sent[topic] = self.sent.get(topic, 0) + 1

    def drop_publishers(self) -> None:
        """Destroy the case's publishers once every matched reliable subscription acknowledged what
        they sent (up to MATCH_WAIT s each): a writer destroyed first takes its unacknowledged
        messages with it. Seen on a loaded machine: the publisher had matched the recorder, but the
        recorder had not matched it yet when the writer went, and the forged /sagg/sample burst
        never arrived (so nothing was there to reject and the case counted 0)."""
        # lazy (heavy): ROS
        from rclpy.duration import Duration
        for p in self.pubs.values():
            p.wait_for_all_acked(Duration(seconds=MATCH_WAIT))
            self.node.destroy_publisher(p)
        self.pubs = {}

    def joint_state(self, pos, vel=(), stamp: int | None = None, names=None) -> None:
        st = self.bridge_stamp + 1_000_000 if stamp is None else stamp
        self.publish("/joint_states", "sensor_msgs/msg/JointState",
                     encode_joint_state(max(1, st), FUZZ, names or self.joints, pos, vel))

    def tip(self, x: float, y: float, stamp: int | None = None) -> None:
        st = self.bridge_stamp + 1_000_000 if stamp is None else stamp
        self.publish(self.task_topic, "geometry_msgs/msg/PointStamped",
                     PointStampedEncoder(FUZZ).encode(max(1, st), x, y))

    def report(self, seq: int, kind: int = 2, reached=(10.0, 0.0), competence: float = 0.0) -> None:
        self.publish("/sagg/competence", "sagg_msgs/msg/CompetenceReport",
                     encode_report(time.time_ns(), seq, 0, kind, (), reached, (0.0, 0.0), competence, 0, frame_id=FUZZ),
                     transient_local=True)

    def sample(self, index: int, alpha=None) -> None:
        a = np.zeros(self.n) if alpha is None else np.asarray(alpha, float)
        self.publish("/sagg/sample", "sagg_msgs/msg/Sample",
                     encode_sample(time.time_ns(), index, a, np.zeros(self.n), np.zeros(2), frame_id=FUZZ))

    def goal(self, seq: int, position) -> None:
        # lazy (heavy): ROS
        from sagg_msgs.msg import Goal
        from rclpy.serialization import serialize_message
        g = Goal()
        g.header.frame_id, g.seq, g.position = FUZZ, seq, [float(p) for p in position]
        self.publish("/sagg/goal", "sagg_msgs/msg/Goal", serialize_message(g))

    def command(self, values) -> None:
        self.publish(self.cmd_topic, "std_msgs/msg/Float64MultiArray", encode_f64_array(np.asarray(values, float)))

    def idle_publishers(self) -> None:
        """A publisher on every topic the graph watches, sending nothing (it must change nothing)."""
        for t in watched_topics(self.learner):
            self._pub(t.name, t.msgtype, t.transient_local)

    def replay(self) -> None:
        """``sagg replay`` of :attr:`replay_bag` (another run's bag) into the graph's domain, as a
        user would start it beside a live run (its defaults: no command topic); the time it ran
        (wall clock, ns: the bag's receive times) is kept in :attr:`replay_windows`."""
        self.replay_windows.append((time.time_ns(), None))
        cmd = [str(find_node_executable("sagg_bringup", "sagg")), "replay", str(self.replay_bag), "--quiet",
               "--domain-id", str(self.domain)]
        self.replaying = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                          start_new_session=True)
        # the case's time runs from the first replayed joint state this node receives: neither the
        # process's start-up nor the bag's lead-in before its first joint state (the recorded run's
        # own start-up) is part of it, each seconds on a loaded machine
        t_end = time.monotonic() + REPLAY_STARTUP
        seen = self.older_joint_states
        while time.monotonic() < t_end and self.replaying.poll() is None and self.older_joint_states == seen:
            self.spin(0.1)

    def stop_replay(self) -> None:
        p, self.replaying = self.replaying, None
        if p is not None:
            stop_group(p, 10.0)
            self.replay_windows[-1] = (self.replay_windows[-1][0], time.time_ns() + 5 * SEC)  # (+ the queued)

    def pause(self, on: bool) -> None:
        """/sagg/pause (std_srvs/SetBool), waiting up to 10 s for the answer."""
        # lazy (heavy): ROS
        from std_srvs.srv import SetBool
        cli = self.node.create_client(SetBool, "/sagg/pause")
        if cli.wait_for_service(timeout_sec=5.0):
            fut = cli.call_async(SetBool.Request(data=on))
            t_end = time.monotonic() + 10.0
            while not fut.done() and time.monotonic() < t_end:
                self.ex.spin_once(timeout_sec=0.05)
        self.node.destroy_client(cli)

    def close(self) -> None:
        self.stop_replay()
        self.drop_publishers()
        self.ex.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.ctx)


def stop_group(proc: subprocess.Popen, timeout: float) -> None:
    """SIGINT to a process started in a session of its own (and its children), SIGKILL after
    ``timeout`` s."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def _next_report(f: Fuzzer) -> int:
    return f.value("sagg_goal_generator", "reports") + 1


def _next_sample(f: Fuzzer) -> int:
    return int(f.status.samples) if f.status is not None else 0


def cases() -> list[Case]:
    """Every hostile case, one row each (and the rows that were already fine)."""
    L, G, B = "sagg_learner", "sagg_goal_generator", "sagg_sim_bridge"
    return [
        Case("joint states 3.0 rad", "content", "joint states outside the limits",
             (f"{L}:joint_states.out_of_limits",), lambda f, k: f.joint_state([3.0] * f.n)),
        Case("joint states 1e308", "content", "huge finite joint states",
             (f"{L}:joint_states.out_of_limits",), lambda f, k: f.joint_state([1e308] * f.n)),
        Case("joint velocities 1e6", "content", "velocities beyond a bound",
             (f"{L}:joint_states.velocity",), lambda f, k: f.joint_state([0.0] * f.n, [1e6] * f.n)),
        Case("task point 1e308", "content", "task point 1e308 (stamp +1 ms)",
             (f"{L}:task_point.outside_task_space",), lambda f, k: f.tip(1e308, 0.0)),
        Case("joint state stamped +1,000 s", "content", "one joint state in the future",
             (f"{L}:joint_states.future_stamp",),
             lambda f, k: f.joint_state([0.0] * f.n, stamp=f.bridge_stamp + 1000 * SEC), once=True),
        Case("report seq +10^12", "content", "one report far outside the window",
             (f"{G}:report.out_of_window",), lambda f, k: f.report(_next_report(f) + 10**12), once=True),
        Case("report NaN at the next seq", "content", "a NaN report takes no seq",
             (f"{G}:report.invalid",), lambda f, k: f.report(_next_report(f), reached=(float("nan"), 0.0)),
             once=True),
        Case("report bad kind at the next seq", "content", "a bad kind takes no seq",
             (f"{G}:report.invalid",), lambda f, k: f.report(_next_report(f), kind=77), once=True),
        Case("NaN sample", "content", "one NaN sample on /sagg/sample",
             ("run:/sagg/sample",), lambda f, k: f.sample(_next_sample(f), [float("nan")] * f.n), once=True),
        Case("NaN goal", "content", "a goal with NaN on /sagg/goal",
             ("run:/sagg/goal",), lambda f, k: f.goal(10**6, [float("nan"), 0.0]), once=True),
        # (names none of which is the learner's: another driver's message, ignored)
        Case("NaN / unknown / wrong-length joint states", "content", "already fine: keep so",
             (f"{L}:joint_states.non_finite", f"{L}:joint_states.length"),
             lambda f, k: [f.joint_state([float("nan")] * f.n), f.joint_state([0.0] * f.n, names=["nope"] * f.n),
                           f.joint_state([0.0] * (f.n + 1))]),
        Case("NaN tip", "content", "already fine: keep so", (f"{L}:task_point.non_finite",),
             lambda f, k: f.tip(float("nan"), 0.0)),
        Case("bad commands to the bridge", "content", "already fine: keep so",
             (f"{B}:command.non_finite", f"{B}:command.length"),
             lambda f, k: [f.command([float("nan")] * f.n), f.command([0.0] * (f.n + 3))], seconds=1.0),
        Case("2,000 joint states/s from a second publisher", "publishers", "the same joints from two sources",
             (f"{L}:joint_states.second_source",),
             lambda f, k: [f.joint_state([0.1] * f.n) for _ in range(20)], period=0.01),
        Case("forged sample with the next index", "publishers", "a forged sample never takes the real index",
             ("run:/sagg/sample",),  # (every index of the next 300: the learner's count is up to 0.5 s old)
             lambda f, k: [f.sample(_next_sample(f) + d) for d in range(300)], once=True),
        Case("forged report at the next seq", "publishers", "a forged report never takes the real seq",
             (f"{G}:report.second_source",),  # (spread: the generator's report count is up to 1 s old)
             lambda f, k: [f.report(_next_report(f) + d) for d in (0, 20, 50, 100, 200, 400, 800)], once=True),
        Case("second publisher on /sagg/goal", "publishers", "a forged goal",
             ("run:/sagg/goal",), lambda f, k: f.goal(10**6, [10.0, 0.0]), once=True),
        Case("gripper publisher (other joints only)", "publishers", "a gripper driver on /joint_states",
             (), lambda f, k: f.joint_state([0.01 * (k % 10)], [0.0], names=["gripper_finger"]),
             seconds=8.0, period=0.05, target=0.9, log="carry none of the learner's joints: ignored"),
        Case("idle publishers on every watched topic", "publishers", "publishers that send nothing",
             (), lambda f, k: f.idle_publishers() if k == 0 else None, seconds=8.0, period=0.5, target=0.9),
        Case("burst, then an idle publisher", "publishers", "a burst, then the publisher stays",
             (f"{L}:joint_states.second_source",),
             lambda f, k: [f.joint_state([0.1] * f.n) for _ in range(50)], once=True, keep=True,
             log="2 sources on /joint_states (publishers: "),
        Case("a replayed bag", "publishers", "`sagg replay` of another run into the live graph",
             (f"{L}:joint_states.second_source",), lambda f, k: f.replay() if k == 0 else None,
             seconds=6.0, period=0.5, stop=lambda f: f.stop_replay(), log="/sagg_replay"),
    ]


def _run_case(f: Fuzzer, case: Case, proc, out: Outcome, quiet: float) -> None:
    node_kinds = [k.split(":", 1) for k in case.kinds if not k.startswith("run:")]
    before = {tuple(k): f.count(*k) for k in node_kinds}
    totals = f.input_rejections()
    skipped0 = f.value("sagg_goal_generator", "skipped_reports")
    bursts = 1 if case.once else max(1, int(case.seconds / case.period))
    # the quiet rate just before, over as long a window as the case is active (at least 2 s)
    window = max(2.0, 0.0 if case.once else case.seconds)
    ma_q, t_q = f.micro_actions(), time.monotonic()
    f.spin(window)
    quiet_rate = (f.micro_actions() - ma_q) / (time.monotonic() - t_q)
    ma_a, t_a = f.micro_actions(), time.monotonic()
    for k in range(bursts):
        case.send(f, k)
        f.spin(case.period)
    active = time.monotonic() - t_a
    if not case.once and quiet_rate > 0:  # (a case sent once is active for a moment: no rate)
        out.shares.append(round((f.micro_actions() - ma_a) / active / quiet_rate, 3))
    if case.stop is not None:
        case.stop(f)
    f.spin(0.3)
    if not case.keep:
        f.drop_publishers()
    f.spin(1.2)  # /diagnostics comes once a second
    ma0 = f.micro_actions()
    t0 = time.monotonic()
    f.spin(quiet)
    # learning went on: micro-actions grew in the quiet time, or later within RESUME_LIMIT s (a
    # learner waits while the recorder works through a flood: the bag stays complete); how long
    # it took is reported
    while f.micro_actions() <= ma0 and time.monotonic() - t0 < RESUME_LIMIT and proc.poll() is None:
        f.spin(0.25)
    resumed = f.micro_actions() > ma0
    waited = time.monotonic() - t0
    if resumed and waited > quiet + 0.3:  # (resumed only after the quiet seconds)
        out.longest_resume = max(out.longest_resume, round(waited, 1))
    if case.keep:
        f.drop_publishers()
    out.runs += 1
    alive = proc.poll() is None and time.monotonic() - f.status_t < 3.0
    out.survived += alive
    # (a case that must be rejected: its counters grew; one that must be ignored: no new rejection)
    out.counted += (all(f.count(*k) > before[tuple(k)] for k in node_kinds) if node_kinds
                    else case.target > 0 and f.input_rejections() == totals)
    out.learning += resumed
    out.reports_lost += f.value("sagg_goal_generator", "skipped_reports") - skipped0


def _start_run(config: str, out: Path, domain: int, sets: list[str], micro_actions: int, eval_every: int):
    cmd = [str(find_node_executable("sagg_bringup", "sagg")), "run", config, "--micro-actions", str(micro_actions),
           "--eval-every", str(eval_every), "--out", str(out), "--domain-id", str(domain), "--quiet"]
    for s in sets:
        cmd += ["--set", s]
    out.mkdir(parents=True, exist_ok=True)
    log = open(out.parent / f"{out.name}.sagg_run.log", "w")
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True), log, cmd


def published_counts(logs: Path) -> dict[str, int]:
    """The nodes' 'published counts: {...}' shutdown lines, summed per topic over the logs (two
    processes publishing one topic both reach the bag)."""
    counts: dict[str, int] = {}
    for log in logs.glob("*.log"):
        for line in log.read_text(errors="replace").splitlines():
            m = re.search(r"published counts: (\{.*\})", line)
            if m:
                for t, n in json.loads(m.group(1)).items():
                    counts[t] = counts.get(t, 0) + n
    return counts


def invariants(run_dir: Path, sent: dict[str, int], replayed: Path | None = None,
               windows: list[tuple] = ()) -> dict[str, object]:
    """The end-of-phase invariants, from the run's summary, checkpoint, bag and logs; ``replayed``:
    a bag replayed into the run during ``windows`` (receive times, ns): its messages in the run's
    bag then are not the driver's (the same bytes outside it are: two runs' first messages may
    be byte-identical, a posture at rest stamped with the same simulation time)."""

    s = json.loads((run_dir / "summary.json").read_text())
    lp = yaml.safe_load((run_dir / "params.yaml").read_text())["sagg_learner"]["ros__parameters"]
    lo, hi = np.array(lp["joint_limits"]["lower"]), np.array(lp["joint_limits"]["upper"])
    tol = lp.get("plausibility", {}).get("joint_tolerance", 0.1)
    step = lp.get("max_joint_step", 0.05)
    rest = np.array(lp["rest_posture"])
    mem = checkpoint_memory(run_dir / "checkpoint")
    k = len(mem)
    alpha, dalpha, dy = mem.alpha[:k], mem.delta_alpha[:k], mem.delta_y[:k]
    curve = s.get("curve") or []
    out: dict[str, object] = {}
    out["all nodes alive (no error)"] = s.get("error") is None and all(
        v.get("exit_code") in (0, None) for v in s.get("nodes", {}).values())
    # (None: fewer than two evaluations finished, e.g. a run of seconds with a niced evaluator)
    out["final test error below initial"] = (curve[-1]["mean_error"] < curve[0]["mean_error"]
                                             if len(curve) >= 2 else None)
    out["no stored α outside the limits"] = bool(((alpha >= lo - tol) & (alpha <= hi + tol)).all())
    goals = np.array([g["position"] for g in s.get("goals", [])], float)
    out["nothing non-finite"] = bool(np.isfinite(alpha).all() and np.isfinite(dalpha).all() and np.isfinite(dy).all()
                                     and np.isfinite(goals).all()
                                     and all(np.isfinite(c["mean_error"]) for c in curve))
    # commands against the measured postures: the micro-action commands (every command but a return
    # to rest) are, in order, the commands of the stored samples, each sent from its sample's α; and
    # every stored α is a joint state the driver published (never the fuzzer's)
    dec = JointStateDecoder()
    cmd_topic = f"/{lp.get('controller', 'forward_position_controller')}/commands"
    task_topic = lp.get("task_topic", "/tip_position")
    driver_postures: set[bytes] = set()
    micro: list[np.ndarray] = []
    counts: dict[str, int] = {}
    foreign = {bytes(raw) for _, _, _, raw in bag_messages([replayed])} if replayed is not None and windows else set()
    for topic, _, ts, raw in bag_messages([run_dir / "bag"]):
        fuzz = FUZZ.encode() in bytes(raw[:64]) or (bool(foreign) and bytes(raw) in foreign
                                                     and any(a <= ts <= b for a, b in windows))
        if topic == "/joint_states":
            st, names, pos, _ = dec.decode(raw)
            if not fuzz:
                driver_postures.add(np.ascontiguousarray(pos[:len(lo)], dtype=float).tobytes())
                if st > 0:
                    counts[topic] = counts.get(topic, 0) + 1
            continue
        if topic == task_topic:
            if not fuzz and decode_point_stamped(raw)[0] > 0:
                counts[topic] = counts.get(topic, 0) + 1
            continue
        if topic == cmd_topic:  # (the fuzzer's commands are the malformed ones: no header to mark)
            try:
                c = decode_f64_array(raw)
            except Exception:  # noqa: BLE001 - the fuzzer's undecodable commands
                continue
            if c.shape == lo.shape and np.isfinite(c).all():
                counts[topic] = counts.get(topic, 0) + 1
                if not np.array_equal(c, rest):
                    micro.append(c)
            continue
        if not fuzz:  # (the fuzzer's stamped messages carry frame_id "fuzz")
            counts[topic] = counts.get(topic, 0) + 1
    m = min(len(micro), k)
    steps = np.abs(np.array(micro[:m]) - alpha[:m]).max(axis=1) if m else np.zeros(0)
    out["micro-action commands / stored samples"] = f"{len(micro)} / {k}"
    out["largest command step from the sample's measured α"] = round(float(steps.max()) if m else 0.0, 6)
    out["no command farther than max_joint_step"] = bool(m and steps.max() <= step + 1e-6 and abs(len(micro) - k) <= 1)
    out["every stored α is a posture the driver published"] = all(
        np.ascontiguousarray(a).tobytes() in driver_postures for a in alpha)
    published = published_counts(run_dir / "logs")
    legit = {t: counts.get(t, 0) for t in published}
    out["bag complete for the legitimate publishers"] = legit == published and not s["bag"].get("dropped")
    out["published vs bag"] = {t: [published[t], legit[t]] for t in sorted(published)}
    out["recorder dropped"] = s["bag"].get("dropped", {})
    out["sagg run rejected"] = s["bag"].get("rejected", {})
    # sagg relearn on the bag rebuilds exactly the run's memory: no forged sample (nor report) took
    # the place of a real one (the recorder's foreign_messages.json names what it attributed to
    # other publishers)
    try:
        # lazy (heavy): relearn loads mujoco (the evaluation set-up); `sagg` imports this module
        from sagg_bringup.bags.bags import relearn
        r = relearn([run_dir / "bag"], run_dir / "relearn", evaluate=False, report=False, out=lambda _: None)
        out["relearn rebuilds the run's memory"] = (r["memory"]["digest"] == s["memory"]["digest"]
                                                    and r["reports"] == s.get("reports"))
        out["relearn rejected"] = r["rejected"]
    except Exception as exc:  # noqa: BLE001 - reported as a failed invariant
        out["relearn rebuilds the run's memory"] = False
        out["relearn rejected"] = f"{type(exc).__name__}: {exc}"
    out["micro_actions"] = s.get("micro_actions")
    out["curve"] = [(c["micro_actions"], round(c["mean_error"], 3)) for c in curve]
    return out


def run_phase(phase: str, config: str, seconds: float, out: Path, sets: list[str], quiet: float,
              log: Callable[[str], None], only: list[str] | None = None,
              eval_every: int = 5000, drain: float = 20.0,
              case_scale: float = 1.0) -> tuple[dict[str, Outcome], dict, dict]:
    domain = pick_domain_id()
    run_dir = out / phase
    if phase == "content":
        phase_sets = list(sets) + ["plausibility.check_sources=false"]
    else:  # (the next seed: the content phase's bag, replayed here, is another run)
        seed = graph_params(load_graph_config(config, parse_set(sets)), 1, "lockstep")["sagg_learner"]["seed"]
        phase_sets = list(sets) + [f"seed={seed + 1}"]
    replay_bag = out / "content" / "bag" if phase == "publishers" else None
    proc, fh, cmd = _start_run(config, run_dir, domain, phase_sets, micro_actions=2_000_000, eval_every=eval_every)
    log(f"[{phase}] {' '.join(cmd)}")
    params = graph_params(load_graph_config(config, parse_set(phase_sets)), 1, "lockstep")
    f = Fuzzer(domain, params["sagg_learner"], replay_bag)
    outcomes: dict[str, Outcome] = {}
    my_cases = [dataclasses.replace(c, seconds=c.seconds * case_scale) for c in cases()
                if c.phase == phase and (only is None or c.name in only)
                and (c.name != "a replayed bag" or (replay_bag / "metadata.yaml").is_file())]
    try:
        t0 = time.monotonic()
        while f.micro_actions() < 200 and time.monotonic() - t0 < 180 and proc.poll() is None:
            f.spin(0.5)  # the graph is up and learning
        t_end = time.monotonic() + seconds
        rng = np.random.default_rng(7)
        k = 0
        while (time.monotonic() < t_end or k < len(my_cases)) and proc.poll() is None:  # every case once at least
            case = my_cases[k % len(my_cases)]
            if k % (len(my_cases) + 1) == len(my_cases):  # a random mixture of three cases at once
                picks = [my_cases[i] for i in rng.choice(len(my_cases), 3, replace=False)]
                case = Case("mixture of 3 random cases", phase, "random mixtures",
                            tuple(x for p in picks for x in p.kinds if not x.startswith("run:")),
                            # (a case sent once is sent once in a mixture too: repeated every 20 ms,
                            # the 300 forged samples made 30,000 a mixture, which the recorder took
                            # minutes to work through while the learner waited for it)
                            lambda f, j, picks=picks: [p.send(f, j) for p in picks if not (p.once and j)],
                            seconds=2.0,
                            # (a case that stops what it started, e.g. the replay, stops it in a mixture
                            # too: a replay left running republished the first phase's whole bag)
                            stop=lambda f, picks=picks: [p.stop(f) for p in picks if p.stop is not None])
            o = outcomes.setdefault(case.name, Outcome())
            _run_case(f, case, proc, o, quiet)
            log(f"[{phase}] {case.name}: survived {o.survived}/{o.runs}, counted {o.counted}, learning "
                f"{o.learning}, reports lost {o.reports_lost}; micro-actions {f.micro_actions()}")
            k += 1
        sent = dict(f.sent)
        # a clean end: pause the learner (the micro-action in flight completes), give the recorder
        # time to take what is queued, then stop the run
        f.pause(True)
        f.spin(drain)
    finally:
        f.close()
        stop_group(proc, 180.0)
        fh.close()
    inv = invariants(run_dir, sent, replay_bag, f.replay_windows)
    logs_text = "\n".join(p.read_text(errors="replace") for p in (run_dir / "logs").glob("*.log"))
    logs_text += (out / f"{phase}.sagg_run.log").read_text(errors="replace")
    logged = {}
    summary = json.loads((run_dir / "summary.json").read_text())
    rejected = summary["bag"].get("rejected", {})
    for c in my_cases:
        node_kinds = [k.split(":", 1)[1] for k in c.kinds if not k.startswith("run:")]
        run_keys = [k.split(":", 1)[1] for k in c.kinds if k.startswith("run:")]
        logged[c.name] = (all(f"[{k}]" in logs_text for k in node_kinds) and c.log in logs_text
                          and all(any(r.startswith(k) for r in rejected) for k in run_keys))
        if run_keys and c.name in outcomes:  # counted by sagg run's handlers (summary)
            outcomes[c.name].counted = outcomes[c.name].runs if all(any(r.startswith(k) for r in rejected)
                                                                   for k in run_keys) else 0
    return outcomes, inv, logged


def bench_hostile(config: str, minutes: float, out_dir: str | None, sets: list[str] | None = None,
                  quiet: float = 3.0, out: Callable[[str], None] = print, only: list[str] | None = None,
                  eval_every: int = 5000, drain: float = 20.0, rate_targets: bool = True,
                  case_scale: float = 1.0) -> dict:
    """Both phases (half of ``minutes`` each); prints the per-case table and the invariants;
    writes OUT/hostile.json. Returns it (``ok``: every case survived, counted, logged and learning
    went on, at its rate target (``rate_targets``: a timing target, for a quiet machine), and every
    invariant holds). ``case_scale``: the cases' active seconds scaled (a short test run)."""
    outp = Path(out_dir or f"runs/hostile-{time.strftime('%Y%m%d-%H%M%S')}")
    outp.mkdir(parents=True, exist_ok=True)
    result = {"config": config, "minutes": minutes, "sets": sets or [], "phases": {}}
    ok = True
    rows = []
    for phase in ("content", "publishers"):
        outcomes, inv, logged = run_phase(phase, config, minutes * 30.0, outp, sets or [], quiet, out, only,
                                          eval_every, drain, case_scale)
        result["phases"][phase] = {"cases": {k: vars(v) for k, v in outcomes.items()}, "logged": logged,
                                   "invariants": inv}
        targets = {c.name: c.target for c in cases()}
        for name, o in outcomes.items():
            target = targets.get(name, 0.0) if rate_targets else 0.0
            fast = all(sh >= target for sh in o.shares)
            good = o.survived == o.runs and (o.counted == o.runs) and o.learning == o.runs and fast
            lg = logged.get(name, True)
            ok &= good and lg
            share = f"{min(o.shares):.2f}" if o.shares else "-"
            rows.append(f"| {phase} | {name} | {o.runs} | {o.survived}/{o.runs} | {'yes' if lg else 'NO'} | "
                        f"{o.counted}/{o.runs} | {o.learning}/{o.runs} | {o.longest_resume:g} | {o.reports_lost} | "
                        f"{share}{f' (>= {target:g})' if target else ''}{'' if fast else ' NO'} |")
        ok &= all(v or v is None for k, v in inv.items() if k.startswith((
            "all nodes", "final test", "no stored", "nothing", "no command", "every stored", "bag complete",
            "relearn rebuilds")))
    table = ["| phase | case | times | survived | logged | counted | learning went on | longest wait (s) "
             "| reports lost | rate while active / quiet (lowest) |",
             "|---|---|---:|---:|---|---:|---:|---:|---:|---:|"] + rows
    out("\n".join(table))
    for phase, r in result["phases"].items():
        out(f"\ninvariants ({phase}):")
        for k, v in r["invariants"].items():
            out(f"  {k}: {v}")
    result["ok"] = bool(ok)
    result["table"] = table
    (outp / "hostile.json").write_text(json.dumps(result, indent=1, default=str))
    out(f"\n{'ALL OK' if ok else 'NOT ALL OK'} -> {outp / 'hostile.json'}")
    return result
