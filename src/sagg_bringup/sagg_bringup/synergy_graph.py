"""``sagg run`` for the synergy setups (quadruped, fishing rod): goal generator, synergy learner and
synergy bridge as processes, recorded and evaluated.

Like :func:`~sagg_bringup.graph.run_graph` (same helpers: node processes with a private
``ROS_DOMAIN_ID`` and localhost discovery, SIGINT then SIGKILL, the mcap recorder), with three
differences:

- nodes: ``goal_generator``, ``synergy_learner``, ``synergy_bridge``; the learner stops at
  ``max_experiments`` = ``--micro-actions`` (one micro-action = one synergy experiment);
- recorded hardware topics: ``/<controller>/joint_trajectory`` (trajectory_msgs/JointTrajectory) and
  the outcome topic (PoseStamped body / PointStamped float);
- evaluation after learning, from the recorded ``/sagg/sample`` stream: the model's reaching phase
  is a function of the stored samples only (no random draw), so a learner rebuilt from the first n
  samples answers the test goals exactly as the live learner did at n experiments; the test goals
  and evaluation simulator are those of the in-process run (:class:`SynergyRun`). The bridge runs
  each trajectory to completion before answering, so the graph is lockstep by construction
  (``--timing realtime`` is refused).
"""
from __future__ import annotations

import os
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.params import ConfigError
from sagg_common.progress import Progress

from .graph import GraphError, NodeProcess, find_node_executable, pick_domain_id, stop_processes, write_params_file
from .recorder import BagWriter, TopicRecorder, TopicSpec
from .synergy_experiment import BoxArea, SynergyRun, load_synergy_config, outcome_extents

SYNERGY_NODES = {
    "sagg_goal_generator": ("sagg_goal_generator", "goal_generator"),
    "sagg_learner": ("sagg_low_level", "synergy_learner"),
    "sagg_sim_bridge": ("sagg_sim_bridge", "synergy_bridge"),
}


def synergy_node_schemas() -> dict[str, tuple]:
    from sagg_goal_generator.node import SCHEMA as GEN
    from .synergy_experiment import LEARNER_SCHEMA, SYN_BRIDGE_SCHEMA
    return {"sagg_goal_generator": GEN, "sagg_learner": LEARNER_SCHEMA, "sagg_sim_bridge": SYN_BRIDGE_SCHEMA}


def synergy_graph_params(full: dict[str, dict], experiments: int) -> dict[str, dict]:
    params = {name: dict(values) for name, values in full.items()}
    lp, bp, gp = params["sagg_learner"], params["sagg_sim_bridge"], params["sagg_goal_generator"]
    lp["max_experiments"] = int(experiments)
    for k in ("controller", "task_topic"):
        if bp[k] != lp[k]:
            raise ConfigError(f"parameter '{k}' differs between sagg_sim_bridge ({bp[k]!r}) and "
                              f"sagg_learner ({lp[k]!r}); set it once under '/**'")
    # every goal and sample must reach the recorder
    if lp["min_sample_subscribers"] == 0:
        lp["min_sample_subscribers"] = 1
    if gp.get("min_goal_subscribers") == 0:
        gp["min_goal_subscribers"] = 1
    return params


def synergy_topics(lp: dict) -> list[TopicSpec]:
    task = lp["task_topic"] if lp["task_topic"].startswith("/") else "/" + lp["task_topic"]
    out_type = "geometry_msgs/msg/PoseStamped" if len(lp["task_space.lower"]) == 3 else "geometry_msgs/msg/PointStamped"
    return [
        TopicSpec("/sagg/goal", "sagg_msgs/msg/Goal"),
        TopicSpec("/sagg/competence", "sagg_msgs/msg/CompetenceReport"),
        TopicSpec("/sagg/regions", "sagg_msgs/msg/RegionTree", depth=1000, transient_local=True),
        TopicSpec("/sagg/sample", "sagg_msgs/msg/Sample"),
        TopicSpec("/sagg/status", "sagg_msgs/msg/LearnerStatus", depth=100),
        TopicSpec("/sagg/evaluation", "sagg_msgs/msg/Evaluation", depth=100),
        TopicSpec(f"/{lp['controller'].strip('/')}/joint_trajectory", "trajectory_msgs/msg/JointTrajectory"),
        TopicSpec(task, out_type),
    ]


def run_synergy_graph(config_path: str | Path, micro_actions: int, out_dir: str | Path, *,
                      seed: int | None = None, strategy: str | None = None, timing: str = "lockstep",
                      eval_every: int = 1000, overrides: dict[str, Any] | None = None, progress: bool = True,
                      domain_id: int | None = None, stall_timeout: float = 60.0, report: bool = True) -> dict:
    """Run the synergy graph for ``micro_actions`` experiments; returns the summary (also in DIR)."""
    from .experiment import goal_share_stats, write_json_atomic
    from sagg_goal_generator.core import KIND_GOAL, MODE_NAMES

    if micro_actions < 1:
        raise ConfigError(f"--micro-actions: got {micro_actions}; allowed: an integer >= 1")
    if eval_every < 1:
        raise ConfigError(f"--eval-every: got {eval_every}; allowed: an integer >= 1")
    if timing != "lockstep":
        raise ConfigError(f"--timing: got {timing!r}; allowed: 'lockstep' (the synergy bridge answers each "
                          "trajectory once it has run)")
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ConfigError(f"--domain-id: got {domain_id}; allowed: an integer in [0, 232]")
    ov = dict(overrides or {})
    if strategy is not None:
        ov["strategy"] = strategy
    if seed is not None:
        ov["seed"] = seed
    schemas = synergy_node_schemas()
    full = load_synergy_config(config_path, ov, learner_schema=schemas["sagg_learner"],
                               bridge_schema=schemas["sagg_sim_bridge"])
    # the goal generator's node-only parameters (load_synergy_config resolved its core schema)
    from sagg_common.params import node_params, read_config
    full["sagg_goal_generator"] = node_params(read_config(config_path), "sagg_goal_generator",
                                              schemas["sagg_goal_generator"], ov)
    out = Path(out_dir)
    if (out / "bag").exists():
        raise ConfigError(f"--out: '{out}' already holds a bag; allowed: a new or empty directory")
    procs = [NodeProcess(name, find_node_executable(pkg, script), out / "logs" / f"{script}.log")
             for name, (pkg, script) in SYNERGY_NODES.items()]
    (out / "logs").mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    params = synergy_graph_params(full, micro_actions)
    params_file = out / "params.yaml"
    write_params_file(params_file, params)
    lp = full["sagg_learner"]
    t_lower = np.asarray(lp["task_space.lower"])

    domain = pick_domain_id() if domain_id is None else domain_id
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions
    from sagg_msgs.msg import Evaluation

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("sagg_run", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    topics = synergy_topics(params["sagg_learner"])
    bag = BagWriter(out / "bag", topics)
    eval_pub = node.create_publisher(Evaluation, "/sagg/evaluation", 100)
    samples: list[tuple[np.ndarray, np.ndarray]] = []
    goals: dict[int, dict] = {}
    goal_comp: dict[int, float] = {}
    report_ma: dict[int, int] = {}
    state = {"status": None, "regions": None, "reports": 0, "gaps": 0, "t0": None, "t1": None,
             "competence": float("nan")}

    def on_sample(m) -> None:
        now = time.perf_counter()
        state["t0"] = state["t0"] or now
        state["t1"] = now
        if int(m.index) != len(samples):
            state["gaps"] += 1
        samples.append((np.array(m.alpha), np.array(m.delta_y)))

    def on_goal(m) -> None:
        goals[int(m.seq)] = {"seq": int(m.seq), "position": list(m.position), "mode": int(m.mode),
                             "mode_name": MODE_NAMES.get(int(m.mode), str(m.mode)),
                             "after_report": int(m.after_report)}

    def on_report(m) -> None:
        state["reports"] += 1
        report_ma[int(m.seq)] = int(m.micro_actions)
        if m.kind == KIND_GOAL:
            goal_comp[int(m.goal_seq)] = float(m.competence)
            state["competence"] = float(m.competence)

    def on_status(m) -> None:
        state["status"] = {"strategy": m.strategy, "micro_actions": int(m.micro_actions),
                           "goals": int(m.goals), "samples": int(m.samples),
                           "last_competence": float(m.last_competence), "paused": bool(m.paused),
                           "pause_reason": m.pause_reason}

    def on_regions(m) -> None:
        state["regions"] = m

    # /sagg/sample (which the learner waits for) is subscribed once the trajectory and outcome topics
    # are matched, so no trajectory or outcome is published before the recorder can receive it
    hw = tuple(t.name for t in topics if not t.name.startswith("/sagg/"))
    recorder = TopicRecorder(node, bag, topics, {"/sagg/sample": on_sample, "/sagg/goal": on_goal,
                                                 "/sagg/competence": on_report, "/sagg/status": on_status,
                                                 "/sagg/regions": on_regions},
                             gate=("/sagg/sample",), wait_for=hw + ("/sagg/competence",))
    bar = Progress(micro_actions, f"{full['sagg_sim_bridge']['setup']} {lp['strategy']} seed {lp['seed']} (graph)",
                   enabled=progress)
    stop_signal: list[int] = []
    old = {sig: signal.signal(sig, lambda s, f: stop_signal.append(s)) for sig in (signal.SIGINT, signal.SIGTERM)}
    error: GraphError | None = None
    interrupted = False
    curve: list[dict] = []
    eval_seconds = 0.0
    run = None
    goals_test = None
    try:
        for p in procs:
            p.start(params_file, env)
        last = (0, time.perf_counter())
        done_at = None
        while True:
            executor.spin_once(timeout_sec=0.02)
            recorder.poll_gate()
            for _ in range(500):
                before = bag.written
                executor.spin_once(timeout_sec=0)
                if bag.written == before:
                    break
            if stop_signal:
                raise KeyboardInterrupt
            now = time.perf_counter()
            bar.update(len(samples), goals=len(goals),
                       regions=len(state["regions"].regions) if state["regions"] is not None else 1,
                       competence=state["competence"], error=float("nan"))
            st = state["status"]
            learner_done = st is not None and st["micro_actions"] >= micro_actions
            for p in procs:
                code = p.poll()
                if code is not None and not (learner_done and code == 0):
                    raise GraphError(f"node {p.name} exited with code {code} (log {p.log_path}):\n"
                                     f"{p.log_tail()}", code=2 if code == 2 else 1)
            if len(samples) != last[0]:
                last = (len(samples), now)
            elif not learner_done and now - last[1] > stall_timeout:
                raise GraphError(f"no new sample for {stall_timeout:.0f} s (at {len(samples)} experiments); "
                                 f"node logs in {out / 'logs'}")
            if learner_done and len(samples) >= st["samples"]:
                done_at = done_at or now
                if now - done_at > 0.5:
                    break
        # ---- evaluation from the recorded samples (same test goals and simulator as in-process)
        run = SynergyRun({"sagg_goal_generator": full["sagg_goal_generator"], "sagg_learner": lp,
                    "sagg_sim_bridge": full["sagg_sim_bridge"]})
        pool = run.test_pool()
        goals_test = run.test_goals(pool)
        area = BoxArea(pool, lp["task_space.lower"], lp["task_space.upper"])
        checkpoints = [c for c in list(range(0, micro_actions, eval_every)) + [micro_actions] if c <= len(samples)]
        fed = 0
        for at in checkpoints:
            while fed < at:
                run.learner.add_sample(*samples[fed])
                fed += 1
            t1 = time.perf_counter()
            errors = run.evaluate(goals_test)
            eval_seconds += time.perf_counter() - t1
            curve.append({"micro_actions": int(at), "mean_error": float(errors.mean()),
                          "median_error": float(np.median(errors))})
            msg = Evaluation()
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.micro_actions = int(at)
            msg.mean_error = float(errors.mean())
            msg.median_error = float(np.median(errors))
            msg.errors = errors.tolist()
            eval_pub.publish(msg)
        bar.update(len(samples), force=True, goals=len(goals),
                   regions=len(state["regions"].regions) if state["regions"] is not None else 1,
                   competence=state["competence"], error=curve[-1]["mean_error"] if curve else float("nan"))
        t_end = time.perf_counter() + 0.3
        while time.perf_counter() < t_end:
            executor.spin_once(timeout_sec=0.02)
    except KeyboardInterrupt:
        interrupted = True
    except GraphError as exc:
        error = exc
    finally:
        bar.close()
        stop_processes(procs)
        for sig, handler in old.items():
            signal.signal(sig, handler)
        recorder.destroy()
        bag.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    wall = time.perf_counter() - t_start

    goal_list = []
    for seq in sorted(goals):
        g = dict(goals[seq])
        g["competence"] = goal_comp.get(seq)
        g["micro_actions"] = report_ma.get(g["after_report"], 0)
        goal_list.append(g)
    pos = np.array([g["position"] for g in goal_list], float).reshape(-1, len(t_lower))
    gma = np.array([g["micro_actions"] for g in goal_list], float)
    regions = []
    if state["regions"] is not None:
        regions = [{"id": int(r.id), "lower": list(r.lower), "upper": list(r.upper),
                    "interest": float(r.interest), "count": int(r.count),
                    "mean_competence": float(r.mean_competence)} for r in state["regions"].regions]
    outcomes = np.array([y for _, y in samples]).reshape(-1, len(t_lower))
    memory = {"samples": len(samples)}
    if run is not None and len(run.learner) == len(samples):
        memory.update(digest=run.learner.by_theta.digest(),
                      bytes=int(run.learner.by_theta.nbytes + run.learner.by_y.nbytes))
    learn_seconds = (state["t1"] - state["t0"]) if len(samples) > 1 else 0.0
    bag_topics = bag.topics()
    summary = {
        "format": "sagg.summary/1",
        "strategy": lp["strategy"],
        "seed": lp["seed"],
        "config": {name: {k: v for k, v in values.items()} for name, values in full.items()},
        "node_params": params,
        "params_file": str(params_file),
        "timing": timing,
        "domain_id": domain,
        "micro_actions": int(state["status"]["micro_actions"]) if state["status"] else len(samples),
        "micro_actions_requested": int(micro_actions),
        "micro_actions_per_second": (len(samples) - 1) / learn_seconds if learn_seconds > 0 else float("nan"),
        "learn_seconds": learn_seconds,
        "eval_seconds": eval_seconds,
        "wall_seconds": wall,
        "curve": curve,
        "final_mean_error": curve[-1]["mean_error"] if curve else float("nan"),
        "final_median_error": curve[-1]["median_error"] if curve else float("nan"),
        "memory": memory,
        "learner_status": state["status"],
        "reports": state["reports"],
        "goals": goal_list,
        "goal_stats": goal_share_stats(pos, gma, area, micro_actions) if run is not None else {},
        "test_goals": goals_test.tolist() if goals_test is not None else None,
        "regions": regions,
        "splits": [],
        "bag": {"path": str(out / "bag"), "storage": "mcap", "topics": bag_topics,
                "sequence_gaps": {"/sagg/sample": state["gaps"]}},
        "synergy": {"setup": full["sagg_sim_bridge"]["setup"], "outcome_extents": outcome_extents(outcomes)},
        "nodes": {p.name: {"pid": p.popen.pid if p.popen else None, "exit_code": p.exit_code,
                           "log": str(p.log_path)} for p in procs},
        "interrupted": interrupted,
        "error": str(error) if error else None,
    }
    write_json_atomic(out / "summary.json", summary)
    if report:
        write_synergy_report(summary, out)
    if error is not None:
        raise error
    if interrupted:
        raise KeyboardInterrupt
    return summary


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
    lines += ["", "## Recorded topics", "", "| topic | type | messages |", "|---|---|---|"]
    lines += [f"| `{t}` | {v['type']} | {v['count']} |" for t, v in summary["bag"]["topics"].items()]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path

