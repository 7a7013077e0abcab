"""``sagg run`` for the fixed-context set-ups (quadruped, fishing rod, the arm with ``context: fixed``;
each a :class:`~sagg_bringup.graph.setups.FixedContext` entry of the registry, passed in as ``setup``): goal
generator, synergy learner and the set-up's bridge as processes, recorded and evaluated.

Like :func:`~sagg_bringup.graph.graph.run_graph` (same helpers: node processes with a private
``ROS_DOMAIN_ID`` and localhost discovery, SIGINT then SIGKILL, the mcap recorder), with three
differences:

- nodes: ``goal_generator``, ``fixed_learner``, ``synergy_bridge``; the learner stops at
  ``max_experiments`` = ``--micro-actions`` (one micro-action = one synergy experiment);
- recorded hardware topics: ``/<controller>/joint_trajectory`` (trajectory_msgs/JointTrajectory) and
  the outcome topic (PoseStamped body / PointStamped float);
- evaluation after learning, from the recorded ``/sagg/sample`` stream: the model's reaching phase
  is a function of the stored samples only (no random draw), so a learner rebuilt from the first n
  samples answers the test goals exactly as the live learner did at n experiments; the test goals
  and evaluation simulator are those of the in-process run (:class:`FixedRun`). The bridge runs
  each trajectory to completion before answering, so the graph is lockstep by construction
  (``--timing realtime`` is refused).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.params import ConfigError, node_params, read_config
from sagg_common.progress import Progress
from sagg_low_level.eval_metrics import error_metrics, metric_frame

from .run_file import write_run_file
from .params_files import run_only_params, set_checkpoint_dirs, write_params_file
from .processes import check_domain_id, node_processes
from ..inprocess.results import run_overrides
from .run_state import finite_sample_problem
from .session import STALL_TIMEOUT, GraphSession
from ..inprocess.fixed_experiment import FixedRun, load_fixed_config, outcome_extents
from ..report.report import fig_teacher


def resolve_fixed_graph(setup, config_path: str | Path, overrides: dict[str, Any] | None) -> dict[str, dict]:
    """The nodes' parameters (full node schemas) of a fixed-context config for the registry's set-up
    ``setup`` (its ``adapter`` and ``node_schemas()``)."""
    schemas = setup.node_schemas()
    full = load_fixed_config(config_path, overrides, setup.adapter, learner_schema=schemas["sagg_learner"],
                               bridge_schema=schemas["sagg_sim_bridge"])
    # the goal generator's node-only parameters (load_fixed_config resolved its core schema)
    full["sagg_goal_generator"] = node_params(read_config(config_path), "sagg_goal_generator",
                                              schemas["sagg_goal_generator"], overrides)
    return full


def fixed_graph_params(full: dict[str, dict], experiments: int) -> dict[str, dict]:
    params = {name: dict(values) for name, values in full.items()}
    lp, bp = params["sagg_learner"], params["sagg_sim_bridge"]
    lp["max_experiments"] = int(experiments)
    if "timing" in bp:  # the MuJoCo arm bridge (context: fixed): one settled answer per command
        bp["timing"] = "lockstep"
    for k in ("controller", "task_topic"):
        if bp[k] != lp[k]:
            raise ConfigError(f"parameter '{k}' differs between sagg_sim_bridge ({bp[k]!r}) and "
                              f"sagg_learner ({lp[k]!r}); set it once under '/**'")
    # (the waits for the recorder are given on the command line: params_files.run_only_params)
    return params


def run_fixed_graph(setup, config_path: str | Path, micro_actions: int, out_dir: str | Path, *,
                      seed: int | None = None, strategy: str | None = None, timing: str = "lockstep",
                      eval_every: int = 1000, overrides: dict[str, Any] | None = None, progress: bool = True,
                      domain_id: int | None = None, stall_timeout: float = STALL_TIMEOUT, report: bool = True) -> dict:
    """Run the graph of the fixed-context set-up ``setup`` (a registry entry: its nodes, schemas,
    adapter and topics) for ``micro_actions`` experiments; returns the summary (also in DIR)."""
    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    out = Path(out_dir)
    full, params, procs = _fixed_plan(setup, config_path, micro_actions, out, ov, timing, domain_id)
    t_start = time.perf_counter()
    params_file = out / "params.yaml"
    setup_name = setup.name
    lp = full["sagg_learner"]

    # the learner status has no rate here (the synergy summary's learner_status never had one)
    session = GraphSession(procs, domain_id, setup.topics(params["sagg_learner"]), out / "bag", out,
                           drain=500, status_rate=False)
    st = session.st
    try:  # set-up: a failure or Ctrl-C before session.run still closes the bag and rclpy
        write_run_file(out, setup=setup_name, driver="sim", timing=timing, domain_id=session.domain,
                       domain_private=domain_id is None, micro_actions=micro_actions, eval_every=eval_every,
                       config=config_path, overrides=ov)
        samples: list[tuple[np.ndarray, np.ndarray]] = []

        def on_sample(m) -> bool | None:
            # no resume here: an older index is not a re-publication but a bad sample
            ok = st.accept_sample(m, finite_sample_problem, republished_ok=False)
            if ok:
                samples.append((np.array(m.alpha, float), np.array(m.delta_y, float)))
            return ok

        session.record({"/sagg/sample": on_sample, "/sagg/goal": st.on_goal, "/sagg/competence": st.on_report,
                        "/sagg/status": st.on_status, "/sagg/regions": st.on_regions})
        bar = Progress(micro_actions, f"{setup_name} {lp['strategy']} seed {lp['seed']} (graph)",
                       enabled=progress)
        evaluation = SampleEvaluation(setup, full)
        points = list(range(0, micro_actions, eval_every)) + [micro_actions]

        def body() -> None:
            session.start_nodes(params_file, run_only_params(params))
            session.wait_for_learner(micro_actions, stall_timeout, "experiments", bar,
                                     may_end=lambda waited: waited > 0.5)  # (a short drain)
            evaluation.run(session, samples, [c for c in points if c <= len(samples)])
            bar.update(st.samples, force=True, **st.progress())  # (error: the last evaluation's)
            session.final_drain()
    except BaseException:
        session.close()
        raise

    session.run(body, bar)
    summary = _fixed_summary(session, setup_name, full, params, timing, micro_actions, evaluation, samples, t_start)
    return session.finish(summary, (lambda: write_synergy_report(summary, out)) if report else None)


def _fixed_plan(setup, config_path, micro_actions: int, out: Path, ov: dict, timing: str,
                domain_id: int | None) -> tuple[dict, dict, list]:
    """The checks and parameters of a fixed-context graph run, ``DIR/params.yaml`` written:
    (resolved config, the nodes' parameters, the node processes)."""
    if timing != "lockstep":
        raise ConfigError(f"--timing: got {timing!r}; allowed: 'lockstep' (the synergy bridge answers each "
                          "trajectory once it has run)")
    check_domain_id(domain_id)
    full = resolve_fixed_graph(setup, config_path, ov)
    if (out / "bag").exists():
        raise ConfigError(f"--out: '{out}' already holds a bag; allowed: a new or empty directory")
    procs = node_processes(setup.nodes, out / "logs")
    params = fixed_graph_params(full, micro_actions)
    # the goal generator checkpoints into DIR/checkpoint (no resume here: its last checkpoint, written
    # at its shutdown, gives the summary the teacher's view)
    for note in set_checkpoint_dirs(params, out):
        print(f"sagg run: {note}", file=sys.stderr)
    write_params_file(out / "params.yaml", params)
    return full, params, procs


def _fixed_summary(session, setup_name: str, full: dict, params: dict, timing: str, micro_actions: int,
                   evaluation, samples: list, t_start: float) -> dict:
    """summary.json of a fixed-context graph run: the session's, its evaluation from the recorded
    samples, and the outcomes' extents."""
    lp, out, st = full["sagg_learner"], session.out, session.st
    outcomes = np.array([y for _, y in samples]).reshape(-1, len(lp["task_space.lower"]))
    return session.summary(
        lp, {name: {k: v for k, v in values.items()} for name, values in full.items()}, params,
        out / "params.yaml", timing, micro_actions, evaluation.curve, evaluation.area, t_start,
        eval_seconds=evaluation.seconds,
        memory=evaluation.memory(len(samples)),
        test_goals=evaluation.goals.tolist() if evaluation.goals is not None else None,
        splits=[],
        bag=session.bag_summary([out / "bag"], {"/sagg/sample": st.gaps["/sagg/sample"]}),
        synergy={"setup": setup_name, "outcome_extents": outcome_extents(outcomes)})


class SampleEvaluation:
    """The fixed-context graph's evaluation, after learning: the recorded samples fed in order to an
    in-process learner of the same parameters (:class:`~sagg_bringup.inprocess.fixed_experiment.FixedRun`)
    and its frozen model evaluated at every evaluation point on the in-process run's test goals, with
    the same simulator, each result published on /sagg/evaluation (so the curve equals the in-process
    one)."""

    def __init__(self, setup, full: dict[str, dict]):
        self.setup, self.full = setup, full
        self.curve: list[dict] = []
        self.seconds = 0.0
        self.learning = None   # the FixedRun the samples were fed to
        self.goals = None      # the test goals
        self.area = None

    def run(self, session: GraphSession, samples: list[tuple[np.ndarray, np.ndarray]], points: list[int]) -> None:
        full = self.full
        self.learning = run = FixedRun({"sagg_goal_generator": full["sagg_goal_generator"],
                                        "sagg_learner": full["sagg_learner"],
                                        "sagg_sim_bridge": full["sagg_sim_bridge"]}, self.setup.adapter)
        self.goals, self.area, _ = run.test_goals()
        frame = metric_frame(self.goals, run.setup.metric_base)  # as in-process (eval_metrics)
        fed = 0
        for at in points:
            while fed < at:
                run.learner.add_sample(*samples[fed])
                fed += 1
            t1 = time.perf_counter()
            errors = run.evaluate(self.goals)
            self.seconds += time.perf_counter() - t1
            self.curve.append({"micro_actions": int(at), **error_metrics(errors, frame)})
            session.publish_evaluation(at, errors)

    def memory(self, samples: int) -> dict:
        """summary.json's ``memory``: the samples recorded, and the digest of the learner fed them all."""
        out = {"samples": samples}
        run = self.learning
        if run is not None and len(run.learner) == samples:
            out.update(digest=run.learner.by_theta.digest(), bytes=run.learner.memory_bytes)
        return out


def write_synergy_report(summary: dict, out: Path) -> Path:
    """A short report.md: key numbers, the learning curve and the recorded topics."""
    lines = [f"# Graph run: {summary['synergy']['setup']}, {summary['strategy']}, seed {summary['seed']}", "",
             "| key | value |", "|---|---|",
             f"| experiments | {summary['micro_actions']} |",
             f"| experiments / s (learning) | {summary['micro_actions_per_second']:.1f} |",
             f"| wall time (s) | {summary['wall_seconds']:.1f} |",
             f"| goals | {len(summary['goals'])} |",
             f"| final mean test error | {summary['final_mean_error']:.3f} |", "",
             "## Learning curve", "", "| experiments | mean error | median error |", "|---|---|---|"]
    lines += [f"| {c['micro_actions']} | {c['mean_error']:.3f} | {c['median_error']:.3f} |" for c in summary["curve"]]
    if summary.get("teacher") and fig_teacher(summary, out / "teacher.png", None):
        lines += ["", f"## Where {summary['strategy']} sent its goals", "", "![teacher](teacher.png)"]
    lines += ["", "## Recorded topics", "", "| topic | type | messages |", "|---|---|---|"]
    lines += [f"| `{t}` | {v['type']} | {v['count']} |" for t, v in summary["bag"]["topics"].items()]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path

