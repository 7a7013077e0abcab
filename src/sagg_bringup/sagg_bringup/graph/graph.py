"""``sagg run`` of the evolving-context arm with the simulated bridge (the set-up registry :mod:`.setups`
chooses it): the three nodes as processes, recorded, evaluated and reported. The jobs it composes
live in their own modules: :mod:`.arm_run` (what every arm run shares: the plan, the recorded
streams, the summary's arm keys), :mod:`.params_files` (parameters), :mod:`.processes` (node
processes, domains), :mod:`.evaluator`, :mod:`.session` (the ROS session and the run loop).

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

from pathlib import Path
from typing import Any


from sagg_common.params import ConfigError
from sagg_common.progress import Progress

from sagg_sim_bridge.arms import arm_reachable_area

from ..inprocess.arm_params import NODES, TIMINGS, graph_params
from ..inprocess.evaluator import Evaluator
from ..report.report import arm_rows, write_report
from ..bags.topics import graph_topics
from .arm_run import ArmStreams, plan_arm_run
from .run_file import write_run_file
from .session import STALL_TIMEOUT, FollowedEvaluation, GraphSession


def run_graph(config_path: str | Path, micro_actions: int, out_dir: str | Path, *,
              seed: int | None = None, strategy: str | None = None, timing: str = "lockstep",
              eval_every: int = 1000, overrides: dict[str, Any] | None = None, progress: bool = True,
              domain_id: int | None = None, stall_timeout: float = STALL_TIMEOUT, report: bool = True,
              resume: dict | None = None) -> dict:
    """Run the graph for ``micro_actions`` micro-actions; returns the summary (also in DIR).

    ``resume``: the settings of the stopped run in ``out_dir`` to continue (``sagg run --resume
    DIR``: :func:`~sagg_bringup.graph.setups.resume_graph`; config_path is then DIR/params.yaml):
    the nodes resume from DIR/checkpoint, this segment is recorded into a new
    bag (``bag2``, ``bag3``, ...; logs ``logs/<node>.<k>.log``), and the earlier bags are read first,
    so the evaluation, the summary and the report cover the whole run (samples, reports and goals
    republished by the resumed nodes are dropped by index / sequence number). An unfinished bag (no
    metadata.yaml: ``sagg run`` itself was killed) is recovered first (:mod:`.bag_recover`), and the
    bags are compared with the checkpoints (:mod:`.resume_check`): what the bags lack is
    republished into the new bag."""
    if timing not in TIMINGS:
        raise ConfigError(f"--timing: got {timing!r}; allowed: one of {', '.join(TIMINGS)}")
    plan = plan_arm_run(config_path, micro_actions, out_dir, nodes=NODES, eval_every=eval_every, strategy=strategy,
                        seed=seed, overrides=overrides, domain_id=domain_id, resume=resume is not None,
                        node_params=lambda full, spec, ov: graph_params(full, micro_actions, timing, spec))
    out, lp, spec = plan.out, plan.config["sagg_learner"], plan.spec
    session = GraphSession(plan.procs, domain_id, graph_topics(plan.lp, timing), plan.bag_path, out, drain=2000)
    try:  # set-up: a failure or Ctrl-C before session.run still closes the bag and rclpy
        write_run_file(out, setup="arm", driver="sim", timing=timing, domain_id=session.domain,
                       domain_private=domain_id is None, micro_actions=micro_actions, eval_every=eval_every,
                       config=(resume or {}).get("config", config_path),
                       overrides=(resume or {}).get("overrides", plan.overrides))
        # the evaluation (a process: it computes the area and test goals meanwhile); a resumed
        # run's earlier evaluations are kept, not repeated
        streams = ArmStreams(session, plan)
        evaluator = streams.resume_evaluation(lambda todo: Evaluator(lp, spec, todo))
        extra = streams.node_extra()
        streams.record()
        bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']} (graph, {timing})", enabled=progress)
        evaluation = FollowedEvaluation(session, evaluator, progress)

        def body() -> None:
            evaluator.start()
            session.start_nodes(plan.params_file, extra)
            session.wait_for_learner(micro_actions, stall_timeout, "micro-actions", bar, tick=evaluation.tick,
                                     may_end=evaluation.may_end)
            session.final_drain()
    except BaseException:
        session.close()
        raise

    session.run(body, bar, between=evaluator.stop)

    # ---- summary
    curve = sorted(evaluator.curve, key=lambda c: c["micro_actions"])
    t_lower, t_upper = plan.task_box
    area = evaluator.area or arm_reachable_area(spec, t_lower, t_upper, seed=lp["eval.seed"])
    summary = session.summary(
        lp, plan.config, plan.params, plan.params_file, timing, micro_actions, curve, area, plan.t_start,
        streams.prior_samples, eval_seconds=evaluator.eval_seconds,
        test_goals=evaluator.test_goals.tolist() if evaluator.test_goals is not None else None,
        eval_metrics=evaluator.metrics(), **streams.summary_keys())

    def report_now() -> None:
        write_report(summary, out, area=area, setup_rows=arm_rows(plan.config["sagg_sim_bridge"]))

    return session.finish(summary, report_now if report and curve else None)
