"""``sagg run`` of the evolving-context arm (the set-up registry :mod:`.setups` chooses it): the three
nodes as processes, recorded, evaluated and reported. The jobs it composes live in their own modules:
:mod:`.arm_params` and :mod:`.params_files` (parameters), :mod:`.processes` (node processes, domains),
:mod:`.evaluator`, :mod:`.split_tracker`, :mod:`.run_state`, :mod:`.session` (the ROS session).

One run:

1. resolves the config (like :func:`~sagg_bringup.inprocess.experiment.load_experiment_config`, with the
   nodes' full schemas, so node-only parameters such as the bridge's ``timing`` are accepted) and
   writes ``DIR/params.yaml`` for the nodes: every resolved parameter, plus the learner's
   ``joints`` / ``joint_limits`` / ``rest_posture`` from the simulated arm and
   ``max_micro_actions``;
2. starts ``goal_generator``, ``learner`` and ``mujoco_bridge`` (console scripts next to
   ``sys.executable``) with ``--ros-args --params-file DIR/params.yaml`` on a private
   ``ROS_DOMAIN_ID`` with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``; logs in ``DIR/logs``;
3. records every graph topic into the mcap bag ``DIR/bag`` (:mod:`.recorder`) from a node in this
   process, and shows live progress;
4. evaluates the frozen model every ``eval_every`` micro-actions and at the end, in a separate,
   niced evaluation process (``EVAL_NICE``): the learner memory is rebuilt from ``/sagg/sample`` and an
   :class:`~sagg_low_level.learner.EvolvingContextLearner` built from the same parameters reaches
   the test goals on its own simulator (exactly what ``InProcessRun.evaluate`` does, so in lockstep
   the curve equals the in-process one); results go to ``/sagg/evaluation``. The nodes never wait
   for it, and it is not counted as learning;
5. stops when the learner reports ``max_micro_actions`` done (``/sagg/status``) or on Ctrl-C:
   SIGINT to every node, SIGKILL after a timeout; the bag is closed in every case;
6. writes ``DIR/summary.json`` (keys of ``result.json`` plus the recording) and ``DIR/report.md``.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.serialization import deserialize_message

from sagg_common.params import ConfigError
from sagg_common.progress import Progress
from sagg_msgs.msg import Evaluation

from sagg_sim_bridge.arms import arm_reachable_area

from ..inprocess.arm_params import NODES, TIMINGS, core_config, graph_params, resolve_arm
from ..bags.bag_reader import bag_messages
from ..bags.bag_recover import recover_run_bags
from ..inprocess.evaluator import Evaluator
from .params_files import run_bags, run_only_params, set_checkpoint_dirs, write_params_file
from .run_file import write_run_file
from .processes import GraphError, check_domain_id, node_processes
from ..bags.recorder import msg_class
from ..report.report import arm_rows, write_report
from .resume_check import compare
from ..inprocess.results import run_overrides
from .session import STALL_TIMEOUT, FollowedEvaluation, GraphSession
from .split_tracker import SplitTracker
from ..bags.topics import graph_topics


def run_graph(config_path: str | Path, micro_actions: int, out_dir: str | Path, *,
              seed: int | None = None, strategy: str | None = None, timing: str = "lockstep",
              eval_every: int = 1000, overrides: dict[str, Any] | None = None, progress: bool = True,
              domain_id: int | None = None, stall_timeout: float = STALL_TIMEOUT, report: bool = True,
              resume: dict | None = None) -> dict:
    """Run the graph for ``micro_actions`` micro-actions; returns the summary (also in DIR).

    ``resume``: the settings of the stopped run in ``out_dir`` to continue (``sagg run --resume
    DIR``: :func:`~sagg_bringup.graph.setups.resume_graph`; config_path is then DIR/params.yaml): the nodes resume from DIR/checkpoint, this segment is recorded into a new
    bag (``bag2``, ``bag3``, ...; logs ``logs/<node>.<k>.log``), and the earlier bags are read first,
    so the evaluation, the summary and the report cover the whole run (samples, reports and goals
    republished by the resumed nodes are dropped by index / sequence number). An unfinished bag (no
    metadata.yaml: ``sagg run`` itself was killed) is recovered first (:mod:`.bag_recover`), and the
    bags are compared with the checkpoints (:mod:`.resume_check`): what the bags lack is
    republished into the new bag."""
    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    if timing not in TIMINGS:
        raise ConfigError(f"--timing: got {timing!r}; allowed: one of {', '.join(TIMINGS)}")
    check_domain_id(domain_id)
    full, spec = resolve_arm(config_path, ov)  # (the one arm_spec_from_params of the run)
    out = Path(out_dir)
    recovered = recover_run_bags(out, lambda line: print(line, file=sys.stderr, flush=True)) if resume else []
    prior_bags = run_bags(out) if resume else []
    if resume and not prior_bags:
        raise ConfigError(f"--resume: '{out}' holds no bag; allowed: the directory of a `sagg run`")
    if not resume and (out / "bag").exists():
        raise ConfigError(f"--out: '{out}' already holds a bag; allowed: a new or empty directory "
                          "(or --resume DIR to continue that run)")
    segment = len(prior_bags) + 1
    while (out / ("bag" if segment == 1 else f"bag{segment}")).exists():
        segment += 1  # (a bag after an unrecoverable one: kept, not read)
    bag_path = out / ("bag" if segment == 1 else f"bag{segment}")
    procs = node_processes(NODES, out / "logs", segment)
    t_start = time.perf_counter()

    params = graph_params(full, micro_actions, timing, spec)
    for note in set_checkpoint_dirs(params, out, resume):
        print(f"sagg run: {note}", file=sys.stderr)
    params_file = out / "params.yaml"
    write_params_file(params_file, params)
    config = core_config(full)
    lp, bp = config["sagg_learner"], config["sagg_sim_bridge"]
    t_lower, t_upper = np.asarray(lp["task_space.lower"]), np.asarray(lp["task_space.upper"])
    checkpoints = list(range(0, micro_actions, eval_every)) + [micro_actions]

    session = GraphSession(procs, domain_id, graph_topics(params["sagg_learner"], timing), bag_path, out,
                           drain=2000)
    st = session.st
    try:  # set-up: a failure or Ctrl-C before session.run still closes the bag and rclpy
        write_run_file(out, setup="arm", driver="sim", timing=timing, domain_id=session.domain,
                       domain_private=domain_id is None, micro_actions=micro_actions, eval_every=eval_every,
                       config=(resume or {}).get("config", config_path), overrides=(resume or {}).get("overrides", ov))

        # a resumed run: the earlier segments' messages, and their evaluations (not repeated)
        prior = []
        done_evals: dict[int, np.ndarray] = {}
        if prior_bags:
            prior = list(bag_messages(prior_bags, {"/sagg/sample", "/sagg/goal", "/sagg/competence",
                                                   "/sagg/regions", "/sagg/evaluation"}))
            for topic, _, _, raw in prior:
                if topic == "/sagg/evaluation":
                    em = deserialize_message(bytes(raw), Evaluation)
                    done_evals[int(em.micro_actions)] = np.array(em.errors)
        evaluator = Evaluator(lp, spec, [c for c in checkpoints if c not in done_evals])  # computes the area and test goals meanwhile
        evaluator.checkpoints = sorted(set(checkpoints))
        for at, errors in sorted(done_evals.items()):
            evaluator.errors[at] = errors
            evaluator.curve.append({"micro_actions": at, "mean_error": float(errors.mean()),
                                    "median_error": float(np.median(errors))})

        sample_check = st.arm_sample_check(params["sagg_learner"], len(t_lower))

        def on_sample(m) -> bool | None:
            ok = st.accept_sample(m, sample_check)
            if ok:
                evaluator.add(int(m.index), np.array(m.alpha), np.array(m.delta_alpha), np.array(m.delta_y))
            return ok

        tracker = SplitTracker(t_lower, t_upper)

        def on_regions(m) -> bool:
            if st.last_regions is not None and int(m.reports) < int(st.last_regions.reports):
                return True  # a resumed generator's checkpoint, older than the bags' last tree (then the same trees again)
            st.last_regions = m
            tracker.update([(int(r.id), r.lower, r.upper) for r in m.regions], int(m.goals))
            return True

        if prior:
            handlers = {"/sagg/sample": on_sample, "/sagg/goal": st.on_goal, "/sagg/competence": st.on_report,
                        "/sagg/regions": on_regions}
            for topic, msgtype, _, raw in prior:
                if topic in handlers:
                    handlers[topic](deserialize_message(bytes(raw), msg_class(msgtype)))
            st.sample_t0 = st.sample_t1 = None  # rates: this segment only
        prior_samples = st.samples
        extra = run_only_params(params)
        check = None
        if resume:  # the bags against the checkpoints: the learner republishes what the bags lack
            check = compare(st.samples, st.reports, len(st.goals), params["sagg_learner"].get("checkpoint_dir", ""),
                            params["sagg_goal_generator"].get("checkpoint_dir", ""))
            extra.setdefault("sagg_learner", {})["republish_from"] = check["republish_from"]
            for line in check["lines"] + [f"warning: {u}" for u in check["unresolved"]]:
                print(f"--resume: {line}", file=sys.stderr, flush=True)

        st.task_lower, st.task_upper = t_lower, t_upper
        session.record({"/sagg/sample": on_sample, "/sagg/goal": st.on_goal, "/sagg/competence": st.on_report,
                        "/sagg/regions": on_regions, "/sagg/status": st.on_status})
        session.acknowledge(lambda: st.samples)  # the samples recorded and accepted, from index 0
        bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']} (graph, {timing})", enabled=progress)
        evaluation = FollowedEvaluation(session, evaluator, progress)

        def body() -> None:
            evaluator.start()
            session.start_nodes(params_file, extra)
            session.wait_for_learner(micro_actions, stall_timeout, "micro-actions", bar, tick=evaluation.tick,
                                     may_end=evaluation.may_end)
            session.final_drain()
    except BaseException:
        session.close()
        raise

    session.run(body, bar, between=evaluator.stop)

    # ---- summary
    curve = sorted(evaluator.curve, key=lambda c: c["micro_actions"])
    area = evaluator.area or arm_reachable_area(spec, t_lower, t_upper, seed=lp["eval.seed"])
    memory = evaluator.memory()
    bag_topics = session.bag.topics()
    recorder = session.recorder
    span = {t: (recorder.last_ns[t] - recorder.first_ns[t]) / 1e9 for t in recorder.first_ns}
    summary = session.summary(
        lp, config, params, params_file, timing, micro_actions, curve, area, t_start, prior_samples,
        eval_every=eval_every,
        resumed_segments=segment - 1,
        startup_seconds=session.startup_seconds(),
        eval_seconds=evaluator.eval_seconds,
        memory={"samples": len(memory), "digest": memory.digest(), "bytes": int(memory.nbytes)},
        test_goals=evaluator.test_goals.tolist() if evaluator.test_goals is not None else None,
        splits=tracker.splits,
        eval_metrics=evaluator.metrics(),
        bag={**session.bag_summary(list(prior_bags) + [bag_path], st.gaps),
             **({"recovered": recovered, "resume_check": check} if resume else {})},
        rates={t: (bag_topics[t]["count"] - 1) / s for t, s in span.items() if s > 0})

    def report_now() -> None:
        write_report(summary, out, area=area, setup_rows=arm_rows(config["sagg_sim_bridge"]))

    return session.finish(summary, report_now if report and curve else None)
