"""``sagg reach RUN_DIR|BAG [x y [z]] [--test-goals N]``: use what a run learned.

The run's model (its sample memory: from ``RUN_DIR/checkpoint``, or rebuilt from the bag(s) as
``sagg relearn`` does) is loaded, frozen, into a learner node (parameter ``frozen_memory``: it
never learns and serves the ``/sagg/reach`` action) next to the simulated bridge of the run's
config, on a private ROS domain; or, with ``--driver external``, next to your robot's driver
in the environment's domain. Each goal is sent to ``/sagg/reach`` (sagg_msgs/action/Reach) and
reached through the graph under the rules of learning (joint limits, ``max_joint_step`` from the
measured posture, fresh settled observations); the result of each (reached point, error, steps,
outcome) is printed and written to ``OUT/reach.json``. ``--test-goals N``: the run's own first N
test goals, each from rest (``from_rest``, as the evaluation reaches them), so the errors compare
with the run's test error (printed beside them).
"""
from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import yaml

from sagg_common.msg_codecs import decode_report
from sagg_common.params import ConfigError, flatten
from sagg_common.report_kinds import KIND_GOAL, KIND_SUBGOAL
from sagg_low_level.checkpoint import checkpoint_memory
from sagg_low_level.ik import rest_point_file, write_rest_point
from sagg_low_level.learner import SCHEMA as LEARNER_CORE
from sagg_low_level.memory import SampleMemory

from ..bags.bag_reader import bag_messages
from ..inprocess.arm_params import NODES
from ..inprocess.evaluator import evaluate_frozen, evaluation_setup
from .params_files import run_bags, write_params_file
from .processes import GraphError, NodeGroup, check_domain_id, node_processes
from .reach_client import OwnReachClient

ANSWER_TIMEOUT = 600.0  # s for one reach (a real arm in small steps is slow)


def _model_source(source: Path) -> tuple[Path, list[Path]]:
    """(the run's params.yaml, its bags) of a run directory or of one of its bags."""
    if (source / "params.yaml").is_file():
        return source / "params.yaml", run_bags(source)
    if (source.parent / "params.yaml").is_file():
        return source.parent / "params.yaml", [source]
    raise ConfigError(f"sagg reach: '{source}' is neither a run directory nor a bag of one (no params.yaml "
                      "beside it); allowed: the DIR of a `sagg run`, or DIR/bag")


def frozen_model(source: Path, out: Path, say=print) -> tuple[dict, Path]:
    """The run's node parameters and its sample memory written to ``out/memory.npz``: the
    learner's final checkpoint when the run has one, else rebuilt from its bags; and its rest point
    (``out/model.json``, :func:`rest_point_of`) when the run has one."""
    # lazy (heavy): mujoco (relearn's evaluation set-up)
    from ..bags.bags import relearn
    params_file, bags = _model_source(source)
    doc = yaml.safe_load(params_file.read_text()) or {}
    memory = out / "memory.npz"
    ck = source / "checkpoint"
    if (ck / "learner.json").is_file():
        checkpoint_memory(ck).save(memory)
        say(f"model: the learner's checkpoint in {ck}")
    elif bags:
        relearn(bags, out / "relearn", params_file, evaluate=False, report=False, out=lambda _: None)
        (out / "relearn" / "memory.npz").replace(memory)
        say(f"model: rebuilt from {', '.join(map(str, bags))}")
    else:
        raise ConfigError(f"sagg reach: '{source}' has no checkpoint and no bag to take the model from")
    rest, where = rest_point_of(ck, bags)
    if rest is not None:
        write_rest_point(out, rest, where)
        say(f"rest point: {where}")
    return doc, memory


def rest_point_of(checkpoint: Path, bags: list[Path]) -> tuple[np.ndarray | None, str]:
    """The effector's point at rest as the run measured it, and where it was read: the learner's
    (``checkpoint/model.json``), else the start of the run's first goal in its bags (an attempt
    whose learner returned to rest first: the first attempt of every goal strategy); (None, '')."""
    rest = rest_point_file(checkpoint) if checkpoint.is_dir() else None
    if rest is not None:
        return rest, f"measured by the learner ({checkpoint / 'model.json'})"
    if bags:
        for _, _, _, raw in bag_messages(bags, {"/sagg/competence"}):
            r = decode_report(raw)
            if r.kind in (KIND_GOAL, KIND_SUBGOAL) and r.seq >= 1:
                return np.asarray(r.start, dtype=float), f"the start of the first goal's attempt in {bags[0]}"
    return None, ""


def reach_goals(source: str | Path, goals: list[list[float]] | None = None, test_goals: int = 0,
                out_dir: str | Path | None = None, driver: str = "sim", domain_id: int | None = None,
                tolerance: float = 0.0, say=print) -> dict:
    """Reach ``goals`` (or the run's first ``test_goals`` test goals, from rest) with the run's
    frozen model through the graph; returns (and writes ``OUT/reach.json``) every result."""
    source = Path(source)
    out = Path(out_dir or f"runs/reach-{time.strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    check_domain_id(domain_id)
    summary = {}
    run_dir = source if (source / "params.yaml").is_file() else source.parent
    if (run_dir / "summary.json").is_file():
        summary = json.loads((run_dir / "summary.json").read_text())
    from_rest = bool(test_goals)
    if test_goals < 0:
        raise ConfigError(f"--test-goals: got {test_goals}; allowed: N >= 1 (the run's first N test goals)")
    if test_goals:
        known = summary.get("test_goals") or []
        if not known:
            raise ConfigError(f"--test-goals: '{run_dir}/summary.json' holds no test goals")
        goals = known[:test_goals]
    if not goals:
        raise ConfigError("sagg reach: no goal; allowed: x y [z] or --test-goals N")
    doc, memory = frozen_model(source, out, say)
    params = {name: flatten((body or {}).get("ros__parameters") or {}) for name, body in doc.items()}
    lp = params.setdefault("sagg_learner", {})
    dims = len(lp.get("task_space.lower") or params.get("/**", {}).get("task_space.lower") or [])
    for g in goals:
        if len(g) != dims:
            raise ConfigError(f"goal {g}: {len(g)} coordinates; allowed: {dims} (the run's task space)")
    # the learner uses the model, never learns; nothing waits for a recorder; no checkpoint
    lp.update({"frozen_memory": str(memory.resolve()), "max_micro_actions": 0, "min_sample_subscribers": 0})
    lp.pop("checkpoint_dir", None)
    if driver == "external":
        lp["rest_return"] = "stepped"
    nodes = {k: v for k, v in NODES.items() if k != "sagg_goal_generator" and (driver == "sim" or k == "sagg_learner")}
    params = {k: v for k, v in params.items() if k in nodes or k == "/**"}
    write_params_file(out / "params.yaml", params)
    procs = node_processes(nodes, out / "logs")
    group = NodeGroup(procs, domain_id if driver == "sim" else _env_domain(domain_id), localhost=driver == "sim")
    results = []
    client = OwnReachClient(group.domain, group.check)
    try:
        group.start(out / "params.yaml")
        say(f"waiting for the learner's /sagg/reach (ROS_DOMAIN_ID {group.domain}) ...")
        client.wait_for_server(120.0)
        for i, g in enumerate(goals):
            r = client.reach(g, ANSWER_TIMEOUT, from_rest, tolerance, cancel=False)
            results.append(r)
            say(f"goal {i + 1}/{len(goals)} {np.round(g, 4).tolist()}: {r['outcome']}, error {r['error']:.4g} "
                f"after {r['steps']} steps ({r['seconds']:.1f} s)")
    finally:
        client.close()
        group.stop()
    errors = np.array([r["error"] for r in results])
    res = {"source": str(source), "driver": driver, "from_rest": from_rest, "goals": results,
           "mean_error": float(errors.mean()), "median_error": float(np.median(errors)),
           "run_final_mean_error": summary.get("final_mean_error"),
           "run_final_median_error": summary.get("final_median_error")}
    if from_rest:  # the same goals, the same model, the run's own evaluation code
        offline = offline_errors(run_dir / "params.yaml", memory, goals)  # (frozen_model checked it is there)
        res["offline_errors"] = offline.tolist()
        res["offline_mean_error"] = float(offline.mean())
    (out / "reach.json").write_text(json.dumps(res, indent=1))
    line = f"{len(results)} goal(s): mean error {res['mean_error']:.4g}, median {res['median_error']:.4g}"
    if from_rest:
        line += (f"; the same goals reached offline in simulation by the run's evaluation: mean "
                 f"{res['offline_mean_error']:.4g} (largest difference "
                 f"{float(np.abs(errors - offline).max()):.3g})")
    if test_goals and res["run_final_mean_error"] is not None:
        line += (f"; the run's test error: mean {res['run_final_mean_error']:.4g}, median "
                 f"{res['run_final_median_error']:.4g} ({len(summary.get('test_goals') or [])} goals, evaluated "
                 "offline in simulation)")
    say(line + f" -> {out / 'reach.json'}")
    return res


def offline_errors(params_file: Path, memory: Path, goals) -> np.ndarray:
    """The errors of the frozen model ``memory`` on ``goals``, each reached from rest offline on the
    run's simulated arm by the run's own evaluation code (:func:`.evaluator.evaluate_frozen`): what
    the graph's reaches equal in simulation, and the simulated side of a reach on the robot."""
    # lazy (heavy): mujoco
    from sagg_sim_bridge.arms import arm_spec_from_params
    from sagg_sim_bridge.params import SCHEMA as BRIDGE_CORE
    from ..bags.bags import params_from
    full = params_from(params_file.parent, params_file)
    lp = {p.name: full["sagg_learner"][p.name] for p in LEARNER_CORE}
    spec = arm_spec_from_params({p.name: full["sagg_sim_bridge"][p.name] for p in BRIDGE_CORE})
    _, _, learner = evaluation_setup(lp, spec, SampleMemory.load(memory))
    return evaluate_frozen(learner, spec, lp, np.asarray(goals, dtype=float))


def _env_domain(domain_id: int | None) -> int:
    return int(domain_id if domain_id is not None else os.environ.get("ROS_DOMAIN_ID") or 0)


def main_reach(args) -> int:
    goals = [args.point] if args.point else None
    try:
        reach_goals(args.source, goals, args.test_goals, args.out, args.driver, args.domain_id, args.tolerance)
    except GraphError as exc:
        print(f"sagg: error: {exc}", file=sys.stderr)
        return exc.code
    return 0
