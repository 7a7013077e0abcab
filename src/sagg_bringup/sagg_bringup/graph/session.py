"""The ROS session of a graph run (every set-up's): the node processes on a private domain, this
process's rclpy node, the recorder and its bag, Ctrl-C handling, the wait for the learner, the
cleanup and the summary's common keys."""
from __future__ import annotations

import signal
import sys
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError
from sagg_common.progress import Progress
from sagg_common.publishers import UNKNOWN_NODE, describe
from sagg_goal_generator.checkpoint import checkpoint_splits, teacher_snapshot

from .markers import MarkerView  # the live view (/sagg/markers), fed by the same messages
from .processes import GraphError, NodeGroup, NodeProcess, domain_in_use
from ..bags.recorder import Acknowledger, BagWriter, TopicRecorder, TopicSpec, both
from ..inprocess.results import goal_share_stats
from .run_state import RunState
from ..bags.topics import SIM_BRIDGE_NODE, awaited_topics, robot_endpoints

# s without a new competence report after which a finished run stops waiting for the missing ones
# (they are counted as dropped; RunState.all_recorded)
REPORT_PATIENCE = 60.0
# default of `sagg run --stall-timeout`: s without a new sample before a run gives up (a hold the
# learner names lasts as long as its cause: a second source, a stopped driver, a pause)
STALL_TIMEOUT = 600.0

# s to wait for discovery to show the nodes already on a domain that has other participants, before
# a simulated bridge is started there (GraphSession.refuse_robot_on_domain): longer than Fast DDS's
# period of participant announcements (3 s), so a participant that missed the first one is still seen
DISCOVERY_WAIT = 5.0
# s more to wait for discovery to name the node of an endpoint it has shown
NAME_WAIT = 1.0

# the goal generator's second node, which serves /sagg/next_goal (sagg_goal_generator.node.GoalServer)
GOAL_SERVER_NODE = "sagg_goal_generator_goals"

# the keys of summary.json, in order (a run writes those it has)
SUMMARY_KEYS = ("format", "strategy", "seed", "config", "node_params", "params_file", "timing", "domain_id",
                "micro_actions", "micro_actions_requested", "micro_actions_per_second", "eval_every",
                "resumed_segments", "learn_seconds", "startup_seconds", "eval_seconds", "wall_seconds", "curve",
                "final_mean_error", "final_median_error", "memory", "learner_status", "scene_refusals", "prior",
                "reports", "goals", "goal_stats", "test_goals", "regions", "splits", "bag", "rates", "synergy", "nodes",
                "interrupted", "error", "eval_metrics", "driver", "curve_source", "simulated_evaluation",
                "robot_evaluation", "teacher")


def refusal_counts(text: str) -> dict[str, int]:
    """The learner status's ``refused`` ("floor 12, self 3") as {cause: count}."""
    out = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        cause, _, count = part.rpartition(" ")
        if cause and count.isdigit():
            out[cause] = int(count)
    return out


class GraphSession:
    """The orchestration one ``sagg run`` graph run needs, for the arm (:func:`run_graph`) and the
    synergy set-ups (:func:`~sagg_bringup.graph.fixed_graph.run_fixed_graph`): the node processes on
    a private ``ROS_DOMAIN_ID`` (``domain_id``, or a random one) with localhost discovery; this
    process's rclpy node, executor and ``/sagg/evaluation`` publisher; the mcap bag of ``topics``
    and its recorder (feeding :attr:`st`, a :class:`RunState`); Ctrl-C / SIGTERM as a flag; the wait
    for the learner to finish (a node exiting or a stall is a :class:`GraphError`); the cleanup in
    every case; the summary's common keys. ``drain``: at most this many queued callbacks are taken
    per loop before the bookkeeping. A graph with sagg's simulated bridge is refused on a domain
    where a robot's driver may be (:meth:`refuse_robot_on_domain`), before its bag is created."""

    def __init__(self, procs: list[NodeProcess], domain_id: int | None, topics: list[TopicSpec],
                 bag_path: Path, out: Path, drain: int, status_rate: bool = True, localhost: bool = True):
        self.procs, self.topics, self.out, self.drain = procs, topics, out, drain
        self.nodes = NodeGroup(procs, domain_id, localhost)
        self.domain, self.env = self.nodes.domain, self.nodes.env
        # (a private domain is picked free; a given one is probed before this process joins it)
        occupied = domain_id is not None and domain_in_use(self.domain)
        # lazy (heavy): ROS
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        from sagg_msgs.msg import Evaluation

        self._rclpy, self._evaluation = rclpy, Evaluation
        self.ctx = Context()
        rclpy.init(context=self.ctx, domain_id=self.domain, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("sagg_run", context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        if occupied and any(p.name == SIM_BRIDGE_NODE for p in procs):
            try:
                self.refuse_robot_on_domain()
            except BaseException:
                self.node.destroy_node()
                rclpy.shutdown(context=self.ctx)
                raise
        self.bag = BagWriter(bag_path, topics)
        self.st = RunState(status_rate=status_rate)
        self.eval_pub = self.node.create_publisher(Evaluation, "/sagg/evaluation", 100)
        self.recorder: TopicRecorder | None = None
        self.ack: Acknowledger | None = None  # backpressure (acknowledge)
        self.view = None  # markers.MarkerView, from record()
        self.stop_signal: list[int] = []
        self.interrupted = False
        self.error: GraphError | None = None
        self.t_nodes: float | None = None  # when the nodes were started
        self.t_first_sample: float | None = None  # when the first sample was in
        self.t_end: float | None = None    # when everything was stopped
        self._closed = False

    def refuse_robot_on_domain(self, wait: float = DISCOVERY_WAIT) -> None:
        """ConfigError when another node on this domain publishes the arm's state or task point or
        subscribes to its commands (:func:`~sagg_bringup.bags.topics.robot_endpoints`): a robot's
        driver may be there, and a simulated bridge beside it would publish joint states as well
        while the learner's commands reach the robot. Waits up to ``wait`` s for discovery to show
        the domain's endpoints (and :data:`NAME_WAIT` s more for it to name their nodes)."""
        print(f"sagg run: domain {self.domain} has other participants: checking that no robot's driver is "
              f"there before starting the simulated bridge (up to {wait:.0f} s)", file=sys.stderr, flush=True)
        ours = {self.node.get_name()}
        t0 = time.perf_counter()
        seen_at = None
        while True:
            found = robot_endpoints(self.node, self.topics, ours)
            now = time.perf_counter()
            if found:
                seen_at = now if seen_at is None else seen_at
                named = all(i.node_name != UNKNOWN_NODE for _, infos in found.values() for i in infos)
                if named or now - seen_at > NAME_WAIT:
                    break
            elif now - t0 > wait:
                return
            time.sleep(0.05)
        where = "; ".join(f"{topic}: {how} by {', '.join(describe(i) for i in infos)}"
                          for topic, (how, infos) in found.items())
        raise ConfigError(
            f"--domain-id {self.domain}: a robot's driver may be on this domain ({where}); sagg run "
            "with the simulated bridge would publish joint states beside it and send the learner's "
            "commands to it, so nothing was started; allowed: a domain where no other node publishes "
            "the arm's state or subscribes to its commands (another --domain-id, or none for a "
            "private one), or --driver external to learn on that robot")

    def record(self, handlers: dict[str, Callable]) -> None:
        """Record every topic (``handlers``: topic -> callback of the deserialized message).
        /sagg/sample is subscribed once the hardware topics (and /sagg/competence) are matched: the
        learner waits for that subscriber before its first command, so the bag misses no command
        or answer of the driver."""
        self.view = MarkerView(self.node, self.topics)
        handlers = dict(handlers)
        for topic, h in self.view.handlers().items():
            handlers[topic] = h if topic not in handlers else both(handlers[topic], h)
        self.recorder = TopicRecorder(self.node, self.bag, self.topics, handlers,
                                      gate=("/sagg/sample",), wait_for=awaited_topics(self.topics))
        self.st.on_reject = self.recorder.log_problem  # the handlers' rejections are logged too

    def acknowledge(self, source: Callable[[], int]) -> None:
        """Publish ``source()`` (how many samples, from index 0, are recorded and accepted) on
        /sagg/recorded, the learner's backpressure (``recorder_max_lag``). Only a session that calls
        this has the publisher: the learner waits only while an acknowledging recorder exists."""
        self.ack = Acknowledger(self.node, source)

    def publish_evaluation(self, at: int, errors: np.ndarray) -> None:
        """/sagg/evaluation (published from here, the executor's thread; recorded like the rest)."""
        msg = self._evaluation()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.micro_actions = int(at)
        msg.mean_error = float(errors.mean())
        msg.median_error = float(np.median(errors))
        msg.errors = errors.tolist()
        self.eval_pub.publish(msg)
        self.st.last_error = msg.mean_error

    def rejected(self) -> dict[str, int]:
        """Messages of the /sagg topics not used: another publisher on the topic (the recorder) or
        content/sequence rejected (the handlers); all are in the bag (it records what happened)."""
        out = dict(self.st.rejected)
        if self.recorder is not None:
            for k, v in self.recorder.rejected.items():
                out[k] = out.get(k, 0) + v
        return out

    def start_nodes(self, params_file: Path, extra: dict[str, dict] | None = None) -> None:
        """Start every node on ``params_file``, plus ``extra[node name]`` as ``-p`` parameters."""
        self.nodes.start(params_file, extra)
        self.t_nodes = time.perf_counter()

    def spin(self) -> None:
        """One loop's callbacks: wait up to 20 ms for one, then drain what is already queued (one
        callback per loop made this process fall far behind the learner and show a stale rate).
        KeyboardInterrupt after Ctrl-C / SIGTERM."""
        self.executor.spin_once(timeout_sec=0.02)
        self.recorder.poll_gate()
        if self.view is not None:
            self.view.maybe_publish()
        bag = self.bag
        for _ in range(self.drain):
            before = bag.written
            self.executor.spin_once(timeout_sec=0)
            if bag.written == before:
                break
        if self.ack is not None:
            self.ack.tick()  # on every change, and at least every 0.5 s
        if self.stop_signal:
            raise KeyboardInterrupt

    def wait_for_learner(self, micro_actions: int, stall_timeout: float, unit: str, bar: Progress, *,
                         tick: Callable[[float], bool | None] | None = None,
                         may_end: Callable[[float], bool] | None = None,
                         stall_detail: Callable[[], str] | None = None) -> None:
        """The one run loop of every graph run: spin until the learner reports ``micro_actions``
        done (/sagg/status), every sample it stored is in, and ``may_end(seconds since then)`` is
        true (None: at once), the progress line ``bar`` following the samples.

        ``tick(now)`` runs after every spin (a mode's own work: an evaluation to follow, an
        evaluation on the robot); when it returns True it held the run for a while on purpose (learning
        paused) and the stall clock starts again. GraphError when a node exits before the end (a
        node that exits 0 once the learner is done is fine) or no new sample came for
        ``stall_timeout`` s while the learner was not paused by the user (``/sagg/pause``: a pause
        never ends a run) (``unit``: what a sample counts; ``stall_detail()``: what the error
        adds, e.g. what the driver lacks)."""
        st = self.st
        last_progress = (0, time.perf_counter())
        done_at = None
        while True:
            self.spin()
            now = time.perf_counter()
            if st.samples and self.t_first_sample is None:
                self.t_first_sample = now
            bar.update(min(st.samples, micro_actions - 1), **st.progress())  # (full once, at the end)
            if tick is not None and tick(now):
                last_progress = (st.samples, time.perf_counter())
                continue
            learner_done = st.status is not None and st.status["micro_actions"] >= micro_actions
            self.nodes.check(may_exit=learner_done)
            if st.samples != last_progress[0] or st.paused_by_user():  # (a pause is no stall, however long)
                last_progress = (st.samples, now)
            elif not learner_done and now - last_progress[1] > stall_timeout:
                detail = f"; {stall_detail()}" if stall_detail is not None else ""
                raise GraphError(f"{st.stall_text(stall_timeout, unit)}; node logs in {self.out / 'logs'}{detail}")
            if learner_done and st.all_recorded(now, min(stall_timeout, REPORT_PATIENCE)):
                if done_at is None:
                    done_at = now
                if may_end is None or may_end(now - done_at):
                    break
        bar.update(st.samples, force=True, **st.progress())

    def startup_seconds(self) -> float:
        """From starting the nodes to the first sample (NaN when none came)."""
        if self.t_first_sample is None or self.t_nodes is None:
            return float("nan")
        return self.t_first_sample - self.t_nodes

    def catch_up(self, limit: float = 60.0) -> None:
        """After Ctrl-C / SIGTERM: pause the learner (/sagg/pause; the micro-action in flight
        completes) and record until every sample it stored is in and no new one came for 0.5 s (at
        most ``limit`` s; a second Ctrl-C stops at once), so that an interrupted run's bag is as
        complete as a finished one's (a recorder behind a fast lockstep learner on a loaded machine
        otherwise loses its backlog)."""
        if self.recorder is None or self.bag.closed:
            return
        # lazy (heavy): ROS
        from std_srvs.srv import SetBool
        self.stop_signal.clear()
        cli = self.node.create_client(SetBool, "/sagg/pause")
        try:
            if cli.service_is_ready():
                cli.call_async(SetBool.Request(data=True))
            else:
                return
            st = self.st
            t0 = time.perf_counter()
            # (samples, not all messages: status and idle joint states keep coming while paused)
            last, t_last, paused = st.samples, t0, False
            while time.perf_counter() - t0 < limit and not self.stop_signal:
                self.executor.spin_once(timeout_sec=0.05)
                now = time.perf_counter()
                paused = paused or bool(st.status and st.status.get("paused"))
                if st.samples != last:
                    last, t_last = st.samples, now
                elif paused and st.all_recorded(now, 0.5) and now - t_last >= 0.5:
                    break
        finally:
            self.node.destroy_client(cli)

    def drain_recorder(self, quiet: float = 0.5, limit: float = 60.0) -> None:
        """After the nodes stopped: take what the recorder's subscriptions still hold (a recorder
        that fell behind, e.g. on an interrupted run on a loaded machine, would otherwise lose its
        backlog), until nothing came on the stopped nodes' topics for ``quiet`` s (at most ``limit``
        s). A topic that another node still publishes on (an external driver's joint states, a
        gripper driver beside the simulated arm, a bag playing) is not waited on: its traffic goes
        on after ours stopped (:meth:`_foreign_live`)."""
        if self.recorder is None or self.bag.closed:
            return
        live, t_live = self._foreign_live(), time.perf_counter()

        def stopped_nodes_messages() -> int:
            return sum(n for t, n in self.bag.counts.items() if t not in live)

        t_end = time.perf_counter() + limit
        last, t_last = stopped_nodes_messages(), time.perf_counter()
        while time.perf_counter() < t_end:
            self.executor.spin_once(timeout_sec=0.05)
            now = time.perf_counter()
            if now - t_live >= 1.0:
                live, t_live = self._foreign_live(), now
            written = stopped_nodes_messages()
            if written != last:
                last, t_last = written, now
            elif now - t_last >= quiet:
                break

    def _foreign_live(self) -> frozenset[str]:
        """The recorded topics that a node other than ours (the run's nodes, this process) publishes on."""
        ours = {p.name for p in self.procs} | {GOAL_SERVER_NODE, self.node.get_name()}
        return frozenset(t.name for t in self.topics
                         if any(i.node_name not in ours for i in self.node.get_publishers_info_by_topic(t.name)))

    def final_drain(self, seconds: float = 0.3) -> None:
        """Spin a little longer: the recorder takes the final Evaluation message (and view)."""
        if self.view is not None:
            self.view.maybe_publish(force=True)
        t_end = time.perf_counter() + seconds
        while time.perf_counter() < t_end:
            self.executor.spin_once(timeout_sec=0.02)

    def run(self, body: Callable[[], None], bar: Progress, between: Callable[[], None] | None = None) -> None:
        """``body()`` (start the nodes, wait, evaluate) with Ctrl-C / SIGTERM turned into a flag
        checked between spins (a KeyboardInterrupt raised inside a callback, e.g. in rclpy's C++
        deserializer, would surface as an unrelated error); an interruption sets
        :attr:`interrupted`, a GraphError :attr:`error`. Then, whatever happened: the bar closed,
        the nodes stopped (SIGINT, SIGKILL after a timeout), ``between()``, the recorder, bag
        (closed in every case), executor and rclpy context shut down."""
        def on_signal(signum, frame):  # noqa: ARG001
            self.stop_signal.append(signum)

        old_handlers = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
        try:
            body()
        except KeyboardInterrupt:
            self.interrupted = True
            self.catch_up()
        except GraphError as exc:
            self.error = exc
        finally:
            bar.close()
            self.nodes.stop()
            for sig, handler in old_handlers.items():
                signal.signal(sig, handler)
            self.drain_recorder()
            if between is not None:
                between()
            self.close()
        self.t_end = time.perf_counter()

    def close(self) -> None:
        """Recorder, bag (closed: a later ``--resume`` reads it), executor and rclpy context; once.
        :meth:`run` ends with it; a caller that fails or is interrupted before :meth:`run` calls it
        itself, so even then the bag is closed and nothing leaks."""
        if self._closed:
            return
        self._closed = True
        if self.recorder is not None:
            self.recorder.destroy()
        self.bag.close()
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.ctx)

    def _exact_splits(self, directory: str | None, rebuilt: list[dict]) -> list[dict]:
        """The generator's own split history, from its last checkpoint (written at its shutdown:
        the same as the in-process run's, whatever the load), when that checkpoint holds at least
        the splits of the last recorded /sagg/regions snapshot; else ``rebuilt`` (the history
        :class:`~sagg_bringup.graph.split_tracker.SplitTracker` rebuilt from the snapshots, where a
        loaded machine may coalesce snapshots and so change the order of splits made between two)."""
        try:
            exact = checkpoint_splits(directory) if directory else None
        except (OSError, ValueError, KeyError) as exc:
            print(f"sagg: the split history is rebuilt from /sagg/regions: checkpoint {directory} unreadable "
                  f"({exc})", file=sys.stderr)
            return rebuilt
        seen = int(self.st.last_regions.splits) if self.st.last_regions is not None else 0
        return exact if exact is not None and len(exact) >= seen else rebuilt

    def dropped(self) -> dict[str, int]:
        """Messages published but never recorded: the gaps the recorder counted in the publishers'
        sequence numbers, and what the learner's last status counts beyond what came (a tail has
        no gap to show)."""
        out = dict(self.recorder.dropped) if self.recorder is not None else {}
        for topic, n in self.st.unrecorded().items():
            out[topic] = max(out.get(topic, 0), n)
        return out

    def bag_summary(self, paths: list[Path], sequence_gaps: dict[str, int]) -> dict:
        """summary.json's ``bag``: this run's bag (the last of ``paths``, the earlier segments' first),
        the recorded topics, the sequence gaps the handlers saw, the messages rejected and dropped."""
        return {"path": str(paths[-1]), "paths": [str(b) for b in paths], "storage": "mcap",
                "topics": self.bag.topics(), "sequence_gaps": sequence_gaps, "rejected": self.rejected(),
                "dropped": self.dropped(),
                "dropped_not_estimated": sorted(self.recorder.drops_unknown) if self.recorder else []}

    def summary(self, learner_params: dict, config: dict, params: dict, params_file: Path, timing: str,
                micro_actions: int, curve: list[dict], area, t_start: float, prior_samples: int = 0,
                **specific) -> dict:
        """summary.json: the keys every graph run has, from what was recorded, plus ``specific``
        (in :data:`SUMMARY_KEYS` order). ``area`` (with ``contains`` / ``share``) gives the goal
        statistics ({} when None); ``prior_samples``: samples of earlier segments (not in the rate)."""
        st, lp = self.st, learner_params
        learn_seconds = (st.sample_t1 - st.sample_t0) if st.samples - prior_samples > 1 else 0.0
        goals = st.goal_list()
        pos = np.array([g["position"] for g in goals], float).reshape(-1, len(lp["task_space.lower"]))
        gma = np.array([g["micro_actions"] for g in goals], float)
        out = dict(specific)
        gp = params.get("sagg_goal_generator") or {}
        if gp.get("checkpoint_dir"):  # the teacher's own view, from the generator's last checkpoint
            try:
                teacher = teacher_snapshot(gp["checkpoint_dir"], gp)
            except (OSError, ValueError, KeyError) as exc:  # (a view lost, not the run's summary)
                print(f"sagg: the teacher's view is left out of the summary: checkpoint "
                      f"{gp['checkpoint_dir']} unreadable ({exc})", file=sys.stderr)
                teacher = None
            if teacher is not None:
                out["teacher"] = teacher
        if "splits" in out:
            out["splits"] = self._exact_splits(gp.get("checkpoint_dir"), out["splits"])
        out.update({
            "format": "sagg.summary/1",
            "strategy": lp["strategy"],
            "seed": lp["seed"],
            "config": config,
            "node_params": params,
            "params_file": str(params_file),
            "timing": timing,
            "domain_id": self.domain,
            "micro_actions": int(st.status["micro_actions"] if st.status else st.samples),
            "micro_actions_requested": int(micro_actions),
            "micro_actions_per_second": ((st.samples - prior_samples - 1) / learn_seconds if learn_seconds > 0
                                         else float("nan")),
            "learn_seconds": learn_seconds,
            "wall_seconds": self.t_end - t_start,
            "curve": curve,
            "final_mean_error": curve[-1]["mean_error"] if curve else float("nan"),
            "final_median_error": curve[-1]["median_error"] if curve else float("nan"),
            "learner_status": st.status,
            "scene_refusals": refusal_counts((st.status or {}).get("refused", "")),
            "reports": st.reports,
            "goals": goals,
            "goal_stats": goal_share_stats(pos, gma, area, micro_actions) if area is not None else {},
            "regions": st.region_list(),
            "nodes": {p.name: {"pid": p.popen.pid if p.popen else None, "exit_code": p.exit_code,
                               "log": str(p.log_path)} for p in self.procs},
            "interrupted": self.interrupted,
            "error": str(self.error) if self.error else None,
        })
        if (st.status or {}).get("prior"):  # another run's samples the learner was given
            out["prior"] = st.status["prior"]
        unknown = set(out) - set(SUMMARY_KEYS)
        if unknown:
            raise ValueError(f"summary keys {sorted(unknown)}; allowed: {', '.join(SUMMARY_KEYS)}")
        return {k: out[k] for k in SUMMARY_KEYS if k in out}

    def finish(self, summary: dict, write_report: Callable[[], Any] | None) -> dict:
        """Write DIR/summary.json, then the report (``write_report``, when given); raise the
        graph's error or the interruption, else return the summary."""
        write_json_atomic(self.out / "summary.json", summary)
        if write_report is not None:
            write_report()
        if self.error is not None:
            raise self.error
        if self.interrupted:
            raise KeyboardInterrupt
        return summary


class FollowedEvaluation:
    """The offline evaluation of a graph run, followed from the run loop: an
    :class:`~sagg_bringup.inprocess.evaluator.Evaluator` process fed the recorded samples, whose
    results are published on /sagg/evaluation (recorded like the rest) as they come. Its
    :meth:`tick` and :meth:`may_end` are the run loop's parts (:meth:`GraphSession.wait_for_learner`)."""

    def __init__(self, session: GraphSession, evaluator, progress: bool):
        self.session, self.evaluator, self.progress = session, evaluator, progress
        self._noted = False

    def tick(self, now: float) -> None:  # noqa: ARG002 - the run loop's signature
        """Feed the samples recorded since, publish the evaluations done, fail on its error."""
        ev, session = self.evaluator, self.session
        ev.flush()
        for at, errors in ev.poll():
            session.publish_evaluation(at, errors)
        if ev.error:
            raise GraphError(f"evaluation failed: {ev.error}")
        if ev.test_goals is not None and session.view is not None and session.view.test_goals is None:
            session.view.set_test_goals(ev.test_goals)

    def may_end(self, waited: float) -> bool:
        """Whether the run may end ``waited`` s after learning did: once every evaluation point is
        evaluated (after a short drain, so that reports and goals published just before the end are
        recorded too). The evaluation is niced and may lag behind learning on a busy machine: it is
        waited for as long as its process lives (it reports its own errors), the user told once."""
        ev, st = self.evaluator, self.session.st
        if waited > 0.5 and ev.finished(st.samples):
            return True
        if not ev.proc.is_alive():
            raise GraphError("the evaluation process stopped before the final evaluation")
        if not self._noted and waited > 2.0:
            self._noted = True
            pending = sum(1 for c in ev.checkpoints if c <= st.samples and c not in ev.errors)
            if self.progress:
                print(f"\nlearning done; waiting for {pending} pending evaluation(s)", file=sys.stderr, flush=True)
        return False
