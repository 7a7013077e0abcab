"""``sagg run``: the three nodes as processes, recorded, evaluated and reported.

One run:

1. resolves the config (like :func:`~sagg_bringup.experiment.load_experiment_config`, with the
   nodes' full schemas, so node-only parameters such as the bridge's ``timing`` are accepted) and
   writes ``DIR/params.yaml`` for the nodes: every resolved parameter, plus the learner's
   ``joints`` / ``joint_limits`` / ``rest_posture`` from the simulated arm and
   ``max_micro_actions``;
2. starts ``goal_generator``, ``learner`` and ``mujoco_bridge`` (console scripts next to
   ``sys.executable``) with ``--ros-args --params-file DIR/params.yaml`` on a private
   ``ROS_DOMAIN_ID`` with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``; logs in ``DIR/logs``;
3. records every graph topic into the mcap bag ``DIR/bag`` (:mod:`.recorder`) from a node in this
   process, and shows live progress;
4. evaluates the frozen model every ``eval_every`` micro-actions and at the end, in a worker
   thread of this process: the learner memory is rebuilt from ``/sagg/sample`` and an
   :class:`~sagg_low_level.learner.EvolvingContextLearner` built from the same parameters reaches
   the test goals on its own simulator (exactly what ``InProcessRun.evaluate`` does, so in lockstep
   the curve equals the in-process one); results go to ``/sagg/evaluation``. The nodes never wait
   for it, and it is not counted as learning;
5. stops when the learner reports ``max_micro_actions`` done (``/sagg/status``) or on Ctrl-C:
   SIGINT to every node, SIGKILL after a timeout; the bag is closed in every case;
6. writes ``DIR/summary.json`` (keys of ``result.json`` plus the recording) and ``DIR/report.md``.
"""
from __future__ import annotations

import ctypes
import importlib
import os
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sagg_common.params import ConfigError, resolve_nodes
from sagg_common.progress import Progress

from .recorder import BagWriter, TopicRecorder, TopicSpec

# node section -> (module holding the node's full SCHEMA, console script)
NODES = {
    "sagg_sim_bridge": ("sagg_sim_bridge.node", "mujoco_bridge"),
    "sagg_goal_generator": ("sagg_goal_generator.node", "goal_generator"),
    "sagg_learner": ("sagg_low_level.node", "learner"),
}
TIMINGS = ("lockstep", "realtime")


def find_node_executable(package: str, script: str) -> Path:
    """A node's console script: next to this Python (the venv's bin, pip installs), else in an
    ament prefix's ``lib/<package>`` (colcon installs, ``ros2 run`` layout), else on PATH."""
    candidates = [Path(sys.executable).parent / script]
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        candidates.append(Path(prefix) / "lib" / package / script)
    found = shutil.which(script)
    if found:
        candidates.append(Path(found))
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return c
    raise ConfigError(f"node executable '{script}' of package '{package}' not found (looked in "
                      f"{', '.join(str(c.parent) for c in candidates)}): run `make setup`, or "
                      "source your colcon workspace")
# Seconds to wait for the nodes to exit after SIGINT before SIGKILL (DESIGN §5: nodes sometimes
# ignore SIGINT under load).
STOP_TIMEOUT = 5.0
# Niceness of the evaluation process: a mild preference for the graph (the nodes, and this
# process's DDS threads receiving the recorded topics). Evaluation first ran in a thread of this
# process at normal priority: on 2 cores the recorder then lost bursts of ~12 /<controller>/commands
# messages (GIL + CPU contention; the learner's writer keeps only 10). As a separate process, runs
# of 4000 micro-actions at niceness 0 and 10 lost nothing; a high niceness starves the evaluation
# on a busy machine (the live test error then lags far behind).
EVAL_NICE = 5


class GraphError(RuntimeError):
    """The graph failed (a node died, stalled, ...); ``code`` is the exit code to return."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


# ------------------------------------------------------------------------------------ config
def node_schemas() -> dict[str, tuple]:
    """Full parameter schemas (core + node-only) of the three nodes, from the node modules."""
    return {name: importlib.import_module(mod).SCHEMA for name, (mod, _) in NODES.items()}


def core_schemas() -> dict[str, tuple]:
    from sagg_goal_generator.core import SCHEMA as GEN
    from sagg_low_level.learner import SCHEMA as LEARNER
    from sagg_sim_bridge.params import SCHEMA as BRIDGE
    return {"sagg_goal_generator": GEN, "sagg_learner": LEARNER, "sagg_sim_bridge": BRIDGE}


def load_graph_config(path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
    """Resolved parameters of the three nodes (full schemas): defaults < ``/**`` < node section <
    overrides. Same checks as the in-process loader; an override no node declares is an error."""
    schemas = node_schemas()
    out = resolve_nodes(path, {name: schemas[name] for name in NODES}, overrides)
    from sagg_sim_bridge.params import arm_spec_from_params
    arm_spec_from_params(out["sagg_sim_bridge"])
    return out


def core_config(full: dict[str, dict]) -> dict[str, dict]:
    """The core parameters only (the ``config`` of an in-process ``result.json``)."""
    return {name: {p.name: full[name][p.name] for p in schema} for name, schema in core_schemas().items()}


def _nest(flat: dict[str, Any]) -> dict:
    """``{"a.b": 1}`` -> ``{"a": {"b": 1}}`` (the ROS 2 parameter-file form)."""
    out: dict = {}
    for key, value in flat.items():
        parts = key.split(".")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = value
    return out


def graph_params(full: dict[str, dict], max_micro_actions: int, timing: str) -> dict[str, dict]:
    """The parameters the nodes get: the resolved config plus what ``sagg run`` fills in."""
    from sagg_sim_bridge.params import arm_spec_from_params
    params = {name: dict(values) for name, values in full.items()}
    spec = arm_spec_from_params(full["sagg_sim_bridge"])
    lower, upper = spec.limits()
    lp = params["sagg_learner"]
    extra = {"joints": spec.joint_names(), "joint_limits.lower": lower.tolist(),
             "joint_limits.upper": upper.tolist(), "rest_posture": spec.rest_posture().tolist(),
             "max_micro_actions": int(max_micro_actions)}
    for k, v in extra.items():
        if k in lp:
            lp[k] = v
    # the bridge and the learner must agree on the topics
    bp = params["sagg_sim_bridge"]
    if "timing" in bp:
        bp["timing"] = timing
    # real-time bridge: a joint state sampled before a command arrived must not be taken for its
    # settled result; the learner's own advice is about two publish periods (0 = lockstep value)
    if timing == "realtime" and lp.get("observation_delay") == 0.0 and "publish_rate" in bp:
        lp["observation_delay"] = 2.0 / bp["publish_rate"]
    for k in ("controller", "task_topic"):
        if k in bp and k in lp and bp[k] != lp[k]:
            raise ConfigError(f"parameter '{k}' differs between sagg_sim_bridge ({bp[k]!r}) and "
                              f"sagg_learner ({lp[k]!r}); set it once under '/**'")
    # every goal and sample must reach the recorder: nodes that can wait for subscribers do so
    for name, key in (("sagg_goal_generator", "min_goal_subscribers"), ("sagg_learner", "min_sample_subscribers"),
                      ("sagg_learner", "min_subscribers")):
        if key in params[name] and params[name][key] == 0:
            params[name][key] = 1
    return params


def run_bags(out: Path) -> list[Path]:
    """The bags of a run directory in recording order: ``bag``, ``bag2``, ``bag3``, ..."""
    found = []
    k = 1
    while (out / ("bag" if k == 1 else f"bag{k}") / "metadata.yaml").is_file():
        found.append(out / ("bag" if k == 1 else f"bag{k}"))
        k += 1
    return found


def set_checkpoint_dirs(params: dict[str, dict], out: Path, resume: bool = False) -> None:
    """Learner and generator checkpoint (with their journals) into ``DIR/checkpoint`` unless the
    config names a directory: what ``sagg run --resume DIR`` continues from. When resuming, a
    node whose checkpoint is in ``DIR/checkpoint`` resumes from there even if params.yaml names
    another path (the run directory was moved or copied)."""
    own = out / "checkpoint"
    for name, meta in (("sagg_learner", "learner.json"), ("sagg_goal_generator", "generator.json")):
        p = params[name]
        if "checkpoint_dir" not in p:
            continue
        if not p["checkpoint_dir"] or (resume and (own / meta).is_file()):
            p["checkpoint_dir"] = str(own.resolve())


def write_params_file(path: Path, params: dict[str, dict]) -> None:
    doc = {name: {"ros__parameters": _nest(values)} for name, values in params.items()}
    header = ("# Generated by `sagg run`: the resolved parameters of the three nodes "
              "(ROS 2 parameter-file form).\n")
    path.write_text(header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120))


def graph_topics(learner_params: dict, timing: str = "lockstep") -> list[TopicSpec]:
    controller = learner_params.get("controller", "forward_position_controller")
    task_topic = learner_params.get("task_topic", "/tip_position")
    if not task_topic.startswith("/"):
        task_topic = "/" + task_topic
    return [
        TopicSpec("/sagg/goal", "sagg_msgs/msg/Goal"),
        TopicSpec("/sagg/competence", "sagg_msgs/msg/CompetenceReport"),
        TopicSpec("/sagg/regions", "sagg_msgs/msg/RegionTree", depth=1000, transient_local=True),
        TopicSpec("/sagg/sample", "sagg_msgs/msg/Sample"),
        TopicSpec("/sagg/status", "sagg_msgs/msg/LearnerStatus", depth=100),
        TopicSpec("/sagg/evaluation", "sagg_msgs/msg/Evaluation", depth=100),
        TopicSpec("/joint_states", "sensor_msgs/msg/JointState"),
        TopicSpec(f"/{controller}/commands", "std_msgs/msg/Float64MultiArray"),
        TopicSpec(task_topic, "geometry_msgs/msg/PointStamped"),
    ] + ([TopicSpec("/clock", "rosgraph_msgs/msg/Clock", depth=100)] if timing == "realtime" else [])


# ------------------------------------------------------------------------------------ processes
def _die_with_parent() -> None:  # pragma: no cover - runs in the child between fork and exec
    """Children get SIGKILL if `sagg run` itself dies (PR_SET_PDEATHSIG), so no orphan graph."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)
    except Exception:  # noqa: BLE001
        pass


@dataclass
class NodeProcess:
    name: str
    exe: Path
    log_path: Path
    popen: subprocess.Popen | None = None
    exit_code: int | None = None

    def start(self, params_file: Path, env: dict) -> None:
        log = open(self.log_path, "wb")
        try:
            self.popen = subprocess.Popen(
                [str(self.exe), "--ros-args", "--params-file", str(params_file)],
                stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                start_new_session=True,  # a terminal Ctrl-C reaches `sagg run` only; it stops us in order
                preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None)
        finally:
            log.close()

    def poll(self) -> int | None:
        if self.popen is not None and self.exit_code is None:
            self.exit_code = self.popen.poll()
        return self.exit_code

    def log_tail(self, lines: int = 8) -> str:
        try:
            text = self.log_path.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return "\n".join("    " + s for s in text[-lines:])


def stop_processes(procs: list[NodeProcess], timeout: float = STOP_TIMEOUT) -> None:
    """SIGINT to every running node, then SIGKILL to those still alive after ``timeout`` s."""
    running = [p for p in procs if p.popen is not None and p.poll() is None]
    for p in running:
        try:
            p.popen.send_signal(signal.SIGINT)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + timeout
    for p in running:
        try:
            p.popen.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.popen.kill()
            p.popen.wait()
        p.poll()


def pick_domain_id() -> int:
    """A random ROS_DOMAIN_ID in 1..200 (private per run: concurrent runs and tests do not mix),
    avoiding the caller's own. Drawn from OS entropy: not part of any experiment's randomness."""
    own = os.environ.get("ROS_DOMAIN_ID", "")
    rng = np.random.default_rng()
    while True:
        d = int(rng.integers(1, 201))
        if str(d) != own:
            return d


# ------------------------------------------------------------------------------------ evaluation
def evaluation_setup(learner_params: dict, bridge_params: dict):
    """``(spec, area, test_goals, learner)`` of a run's evaluation, as ``run_experiment`` computes
    them (``test_goals(spec, Y, n=eval.goals, seed=eval.seed)``); the learner (empty memory) is
    built exactly as the learner node builds its own (same neighbour search). Used by ``sagg run``'s
    evaluator and by ``sagg relearn``."""
    from sagg_low_level.learner import EvolvingContextLearner, Robot
    from sagg_sim_bridge.arm import reachable_area, test_goals
    from sagg_sim_bridge.params import arm_spec_from_params
    spec = arm_spec_from_params(bridge_params)
    lp = learner_params
    area = reachable_area(spec, lp["task_space.lower"], lp["task_space.upper"], seed=lp["eval.seed"])
    goals = test_goals(spec, lp["task_space.lower"], lp["task_space.upper"], n=lp["eval.goals"],
                       seed=lp["eval.seed"], area=area)
    lower, upper = spec.limits()
    robot = Robot(spec.joint_names(), lower, upper, spec.rest_posture())
    learner = EvolvingContextLearner(lp, robot, len(lp["task_space.lower"]))
    return spec, area, goals, learner


def evaluate_frozen(learner, spec, learner_params: dict, goals: np.ndarray) -> np.ndarray:
    """Test errors of the frozen model, as ``InProcessRun.evaluate``: a fresh
    ``ArmSim(spec, substream_seed(seed, "eval_sim"))``."""
    from sagg_common.rng import substream_seed
    from sagg_low_level.evaluate import evaluate
    from sagg_sim_bridge.arm import ArmSim
    return evaluate(learner, ArmSim(spec, seed=substream_seed(learner_params["seed"], "eval_sim")), goals)


def _eval_worker(inbox, outbox, learner_params: dict, bridge_params: dict, checkpoints: list[int],
                 nice: int) -> None:
    """Evaluation process: computes the reachable area and the test goals (as ``run_experiment``
    does: ``test_goals(spec, Y, n=eval.goals, seed=eval.seed)``), then rebuilds the memory from the
    sample batches in ``inbox`` and, whenever it holds exactly a checkpoint's number of samples,
    evaluates the frozen model as ``InProcessRun.evaluate`` does (fresh
    ``ArmSim(spec, substream_seed(seed, "eval_sim"))``). Sends ``("area", ...)``, then
    ``("eval", at, errors, seconds)`` per checkpoint, or ``("error", text)``, to ``outbox``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # `sagg run` stops us (a terminal Ctrl-C reaches us too)
    try:
        os.nice(nice)
    except OSError:
        pass
    try:
        spec, area, goals, learner = evaluation_setup(learner_params, bridge_params)
        outbox.put(("area", area.lower, area.upper, area.resolution, area.mask, area.cell_points, goals))
        memory = learner.memory
        pending = sorted(set(checkpoints))

        def due() -> None:
            while pending and len(memory) == pending[0]:
                at = pending.pop(0)
                t0 = time.perf_counter()
                errors = evaluate_frozen(learner, spec, learner_params, goals)
                outbox.put(("eval", at, errors, time.perf_counter() - t0))

        while True:
            due()
            item = inbox.get()
            if item[0] == "stop":
                return
            if item[0] == "checkpoint":
                at = int(item[1])
                if at < len(memory):
                    raise RuntimeError(f"checkpoint {at} is behind the rebuilt memory ({len(memory)})")
                pending = sorted({c for c in pending if c < at} | {at})
                continue
            _, start, alpha, dalpha, dy = item
            if start != len(memory):
                raise RuntimeError(f"sample batch starts at {start} but {len(memory)} samples were rebuilt")
            for i in range(len(alpha)):
                memory.add(alpha[i], dalpha[i], dy[i])
                due()
    except Exception as exc:  # noqa: BLE001 - reported by the orchestrator
        outbox.put(("error", f"{type(exc).__name__}: {exc}"))


class Evaluator:
    """The run's evaluation, in a separate process (its own GIL: the recorder in this process keeps
    up) at a lower CPU priority than the graph. Samples from /sagg/sample are checked for order,
    batched and shipped to it; results come back through :meth:`poll`."""

    def __init__(self, learner_params: dict, bridge_params: dict, checkpoints: list[int],
                 nice: int = EVAL_NICE):
        import multiprocessing
        ctx = multiprocessing.get_context("spawn")  # never fork a process that runs DDS threads
        self.inbox, self.outbox = ctx.Queue(), ctx.Queue()
        self.proc = ctx.Process(target=_eval_worker, name="sagg-evaluator", daemon=True,
                                args=(self.inbox, self.outbox, learner_params, bridge_params,
                                      list(checkpoints), nice))
        self.area = None  # the ReachableArea of Y, once the worker has computed it
        self.test_goals: np.ndarray | None = None
        self.checkpoints = sorted(set(checkpoints))
        self.curve: list[dict] = []
        self.errors: dict[int, np.ndarray] = {}
        self.eval_seconds = 0.0
        self.error: str | None = None
        self.samples = 0  # samples received (in order) so far
        self._batch: list[tuple] = []
        self._sent = 0
        # this process's copy of the samples: the memory digest of the summary
        self.alpha: list[np.ndarray] = []
        self.delta_alpha: list[np.ndarray] = []
        self.delta_y: list[np.ndarray] = []

    def start(self) -> None:
        self.proc.start()

    def add(self, index: int, alpha, delta_alpha, delta_y) -> None:
        if index != self.samples:
            if self.error is None:
                self.error = (f"/sagg/sample index {index} received after {self.samples} samples: samples "
                              "were lost or reordered")
            return
        self.samples += 1
        self.alpha.append(alpha)
        self.delta_alpha.append(delta_alpha)
        self.delta_y.append(delta_y)

    def flush(self) -> None:
        """Ship the samples received since the last flush (non-blocking: a feeder thread sends)."""
        if self._sent < self.samples:
            a, b = self._sent, self.samples
            self.inbox.put(("samples", a, np.array(self.alpha[a:b]), np.array(self.delta_alpha[a:b]),
                            np.array(self.delta_y[a:b])))
            self._sent = b

    def add_checkpoint(self, at: int) -> None:
        """An extra, final checkpoint (the run stopped before the planned end)."""
        self.checkpoints = sorted({c for c in self.checkpoints if c < at} | {at})
        self.inbox.put(("checkpoint", at))

    def poll(self) -> list[tuple[int, np.ndarray]]:
        """Evaluations finished since the last call, as ``(micro_actions, errors)``."""
        import queue
        done = []
        while True:
            try:
                item = self.outbox.get_nowait()
            except queue.Empty:
                break
            if item[0] == "error":
                self.error = item[1]
                continue
            if item[0] == "area":
                from sagg_sim_bridge.arm import ReachableArea
                self.area = ReachableArea(*item[1:6])
                self.test_goals = item[6]
                continue
            _, at, errors, secs = item
            self.eval_seconds += secs
            self.errors[at] = errors
            self.curve.append({"micro_actions": int(at), "mean_error": float(errors.mean()),
                               "median_error": float(np.median(errors))})
            done.append((at, errors))
        if self.error is None and not self.proc.is_alive() and self.proc.exitcode not in (None, 0):
            self.error = f"evaluation process exited with code {self.proc.exitcode}"
        return done

    def finished(self, upto: int) -> bool:
        """Every checkpoint up to ``upto`` micro-actions is evaluated."""
        return all(c in self.errors for c in self.checkpoints if c <= upto)

    def stop(self, timeout: float = 5.0) -> None:
        try:
            self.inbox.put(("stop",))
        except (OSError, ValueError):
            pass
        self.proc.join(timeout)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        for q in (self.inbox, self.outbox):
            q.cancel_join_thread()
            q.close()

    def memory(self):
        """A SampleMemory of the received samples (for the digest; same class as the learner's)."""
        from sagg_low_level.memory import SampleMemory
        n = len(self.alpha[0]) if self.alpha else 1
        m = len(self.delta_y[0]) if self.delta_y else 1
        mem = SampleMemory(n, n, m, capacity=max(1, len(self.alpha)))
        for a, da, dy in zip(self.alpha, self.delta_alpha, self.delta_y):
            mem.add(a, da, dy)
        return mem


# ------------------------------------------------------------------------------------ split history
class SplitTracker:
    """Rebuilds the goal generator's split history (``RegionTree.splits`` format: region, dim, value,
    left, right, stamp) from successive /sagg/regions snapshots.

    A snapshot is published on every split, but a reliable depth-1 writer may coalesce several; the
    leaves that replaced a region are then split back into a tree by guillotine cuts (ids of
    never-seen intermediate regions are negative). The leaves at every observed time are exact."""

    def __init__(self, lower, upper):
        self.leaves: dict[int, tuple[np.ndarray, np.ndarray]] = {0: (np.asarray(lower, float), np.asarray(upper, float))}
        self.splits: list[dict] = []
        self._synthetic = -1
        self.inconsistent = 0

    def update(self, regions: list[tuple[int, np.ndarray, np.ndarray]], stamp: int) -> None:
        new = {rid: (np.asarray(lo, float), np.asarray(hi, float)) for rid, lo, hi in regions}
        removed = [r for r in self.leaves if r not in new]
        added = [r for r in new if r not in self.leaves]
        for rid in removed:
            lo, hi = self.leaves[rid]
            kids = [a for a in added if np.all(new[a][0] >= lo) and np.all(new[a][1] <= hi)]
            self._decompose(rid, lo, hi, kids, new, stamp)
        self.leaves = new

    def _decompose(self, rid, lo, hi, kids, boxes, stamp) -> None:
        if len(kids) < 2:
            self.inconsistent += 1
            return
        for d in range(len(lo)):
            for v in sorted({float(boxes[k][0][d]) for k in kids if boxes[k][0][d] > lo[d]}):
                left = [k for k in kids if boxes[k][1][d] <= v]
                right = [k for k in kids if boxes[k][0][d] >= v]
                if left and right and len(left) + len(right) == len(kids):
                    ids = []
                    for side in (left, right):
                        if len(side) == 1:
                            ids.append(side[0])
                        else:
                            ids.append(self._synthetic)
                            self._synthetic -= 1
                    self.splits.append({"stamp": int(stamp), "region": int(rid), "dim": d, "value": v,
                                        "left": int(ids[0]), "right": int(ids[1])})
                    llo, lhi = lo, hi.copy()
                    lhi[d] = v
                    rlo, rhi = lo.copy(), hi
                    rlo[d] = v
                    if len(left) > 1:
                        self._decompose(ids[0], llo, lhi, left, boxes, stamp)
                    if len(right) > 1:
                        self._decompose(ids[1], rlo, rhi, right, boxes, stamp)
                    return
        self.inconsistent += 1


# ------------------------------------------------------------------------------------ the run
@dataclass
class RunState:
    """What the orchestrator learns from the topics."""

    samples: int = 0
    sample_t0: float | None = None
    sample_t1: float | None = None
    status: dict | None = None
    goals: dict[int, dict] = field(default_factory=dict)
    goal_competence: dict[int, float] = field(default_factory=dict)
    report_ma: dict[int, int] = field(default_factory=dict)
    reports: int = 0
    last_regions: Any = None
    last_competence: float = float("nan")
    last_error: float = float("nan")
    # messages missing from sequences the recorder can check (seq/index not consecutive)
    gaps: dict[str, int] = field(default_factory=lambda: {"/sagg/sample": 0, "/sagg/competence": 0,
                                                          "/sagg/goal": 0})


def _status_dict(m) -> dict:
    return {"strategy": m.strategy, "micro_actions": int(m.micro_actions), "goals": int(m.goals),
            "samples": int(m.samples), "last_competence": float(m.last_competence),
            "micro_actions_per_second": float(m.micro_actions_per_second), "paused": bool(m.paused),
            "pause_reason": m.pause_reason}


def run_graph(config_path: str | Path, micro_actions: int, out_dir: str | Path, *,
              seed: int | None = None, strategy: str | None = None, timing: str = "lockstep",
              eval_every: int = 1000, overrides: dict[str, Any] | None = None, progress: bool = True,
              domain_id: int | None = None, stall_timeout: float = 60.0, report: bool = True,
              resume: bool = False) -> dict:
    """Run the graph for ``micro_actions`` micro-actions; returns the summary (also in DIR).

    ``resume``: continue the stopped run in ``out_dir`` (``sagg run --resume DIR``; config_path is
    then DIR/params.yaml): the nodes resume from DIR/checkpoint, this segment is recorded into a new
    bag (``bag2``, ``bag3``, ...; logs ``logs/<node>.<k>.log``), and the earlier bags are read first,
    so the evaluation, the summary and the report cover the whole run (samples, reports and goals
    republished by the resumed nodes are dropped by index / sequence number)."""
    # synergy setups (config parameter `setup`: quadruped / fishing, paper Sec. 4-5): their own nodes
    from .synergy_experiment import config_setup
    if config_setup(config_path) is not None:
        from .synergy_graph import run_synergy_graph
        return run_synergy_graph(config_path, micro_actions, out_dir, seed=seed, strategy=strategy,
                                 timing=timing, eval_every=eval_every, overrides=overrides, progress=progress,
                                 domain_id=domain_id, stall_timeout=stall_timeout, report=report)
    from .experiment import goal_share_stats, write_json_atomic
    from sagg_goal_generator.core import KIND_GOAL, MODE_NAMES
    from sagg_sim_bridge.arm import reachable_area
    from sagg_sim_bridge.params import arm_spec_from_params

    if micro_actions < 1:
        raise ConfigError(f"--micro-actions: got {micro_actions}; allowed: an integer >= 1")
    if eval_every < 1:
        raise ConfigError(f"--eval-every: got {eval_every}; allowed: an integer >= 1")
    if timing not in TIMINGS:
        raise ConfigError(f"--timing: got {timing!r}; allowed: one of {', '.join(TIMINGS)}")
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ConfigError(f"--domain-id: got {domain_id}; allowed: an integer in [0, 232]")
    ov = dict(overrides or {})
    if strategy is not None:
        ov["strategy"] = strategy
    if seed is not None:
        ov["seed"] = seed
    full = load_graph_config(config_path, ov)
    out = Path(out_dir)
    prior_bags = run_bags(out) if resume else []
    if resume and not prior_bags:
        raise ConfigError(f"--resume: '{out}' holds no bag; allowed: the directory of a `sagg run`")
    if not resume and (out / "bag").exists():
        raise ConfigError(f"--out: '{out}' already holds a bag; allowed: a new or empty directory "
                          "(or --resume DIR to continue that run)")
    segment = len(prior_bags) + 1
    while (out / ("bag" if segment == 1 else f"bag{segment}")).exists():
        segment += 1  # (an unreadable bag: `sagg run` itself was killed; kept, not read)
    bag_path = out / ("bag" if segment == 1 else f"bag{segment}")
    procs = []
    for name, (module, script) in NODES.items():
        exe = find_node_executable(module.split(".")[0], script)
        procs.append(NodeProcess(name, exe, out / "logs" / (f"{script}.log" if segment == 1 else f"{script}.{segment}.log")))
    (out / "logs").mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()

    params = graph_params(full, micro_actions, timing)
    set_checkpoint_dirs(params, out, resume)
    params_file = out / "params.yaml"
    write_params_file(params_file, params)
    config = core_config(full)
    lp, bp = config["sagg_learner"], config["sagg_sim_bridge"]
    spec = arm_spec_from_params(bp)
    t_lower, t_upper = np.asarray(lp["task_space.lower"]), np.asarray(lp["task_space.upper"])
    checkpoints = list(range(0, micro_actions, eval_every)) + [micro_actions]

    domain = pick_domain_id() if domain_id is None else domain_id
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    # this process joins the same private domain (the rmw reads the discovery range at init)
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
    topics = graph_topics(params["sagg_learner"], timing)
    bag = BagWriter(bag_path, topics)
    st = RunState()
    eval_pub = node.create_publisher(Evaluation, "/sagg/evaluation", 100)

    def publish_eval(at: int, errors: np.ndarray) -> None:
        """/sagg/evaluation (published from here, the executor's thread; recorded like the rest)."""
        msg = Evaluation()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.micro_actions = int(at)
        msg.mean_error = float(errors.mean())
        msg.median_error = float(np.median(errors))
        msg.errors = errors.tolist()
        eval_pub.publish(msg)
        st.last_error = msg.mean_error

    # a resumed run: the earlier segments' messages, and their evaluations (not repeated)
    prior = []
    done_evals: dict[int, np.ndarray] = {}
    if prior_bags:
        from rclpy.serialization import deserialize_message
        from .bags import bag_messages
        prior = list(bag_messages(prior_bags, {"/sagg/sample", "/sagg/goal", "/sagg/competence",
                                               "/sagg/regions", "/sagg/evaluation"}))
        for topic, _, _, raw in prior:
            if topic == "/sagg/evaluation":
                em = deserialize_message(bytes(raw), Evaluation)
                done_evals[int(em.micro_actions)] = np.array(em.errors)
    evaluator = Evaluator(lp, bp, [c for c in checkpoints if c not in done_evals])  # computes the area and test goals meanwhile
    evaluator.checkpoints = sorted(set(checkpoints))
    for at, errors in sorted(done_evals.items()):
        evaluator.errors[at] = errors
        evaluator.curve.append({"micro_actions": at, "mean_error": float(errors.mean()),
                                "median_error": float(np.median(errors))})

    def on_sample(m) -> None:
        if int(m.index) < st.samples:
            return  # republished by a resumed learner (same values)
        now = time.perf_counter()
        if st.sample_t0 is None:
            st.sample_t0 = now
        st.sample_t1 = now
        if int(m.index) != st.samples:
            st.gaps["/sagg/sample"] += 1
        st.samples += 1
        evaluator.add(int(m.index), np.array(m.alpha), np.array(m.delta_alpha), np.array(m.delta_y))

    def on_goal(m) -> None:
        if int(m.seq) in st.goals:
            return  # published again (a repeated goal request after a generator restart)
        if int(m.seq) != len(st.goals) + 1:
            st.gaps["/sagg/goal"] += 1
        st.goals[int(m.seq)] = {"seq": int(m.seq), "position": list(m.position), "mode": int(m.mode),
                                "mode_name": MODE_NAMES.get(int(m.mode), str(m.mode)),
                                "after_report": int(m.after_report)}

    def on_report(m) -> None:
        if int(m.seq) <= st.reports:
            return  # republished by a resumed learner
        if int(m.seq) != st.reports + 1:
            st.gaps["/sagg/competence"] += 1
        st.reports += 1
        st.report_ma[int(m.seq)] = int(m.micro_actions)
        if m.kind == KIND_GOAL:
            st.goal_competence[int(m.goal_seq)] = float(m.competence)
            st.last_competence = float(m.competence)

    tracker = SplitTracker(t_lower, t_upper)

    def on_regions(m) -> None:
        st.last_regions = m
        tracker.update([(int(r.id), r.lower, r.upper) for r in m.regions], int(m.goals))

    def on_status(m) -> None:
        st.status = _status_dict(m)

    if prior:
        from .recorder import _msg_class
        handlers = {"/sagg/sample": on_sample, "/sagg/goal": on_goal, "/sagg/competence": on_report,
                    "/sagg/regions": on_regions}
        for topic, msgtype, _, raw in prior:
            if topic in handlers:
                handlers[topic](deserialize_message(bytes(raw), _msg_class(msgtype)))
        st.sample_t0 = st.sample_t1 = None  # rates: this segment only
    prior_samples = st.samples

    # /sagg/sample is subscribed once the hardware topics are matched: the learner waits for that
    # subscriber before its first command, so the bag misses no command, joint state or tip
    hw = tuple(t.name for t in topics if not t.name.startswith("/sagg/") and t.name != "/clock")
    recorder = TopicRecorder(node, bag, topics, {
        "/sagg/sample": on_sample, "/sagg/goal": on_goal, "/sagg/competence": on_report,
        "/sagg/regions": on_regions, "/sagg/status": on_status},
        gate=("/sagg/sample",), wait_for=hw + ("/sagg/competence",))
    bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']} (graph, {timing})", enabled=progress)
    interrupted = False
    error: GraphError | None = None
    t_first = None
    # Ctrl-C / SIGTERM set a flag checked between spins: a KeyboardInterrupt raised inside a
    # callback (e.g. in rclpy's C++ deserializer) would surface as an unrelated error.
    stop_signal: list[int] = []

    def on_signal(signum, frame):  # noqa: ARG001
        stop_signal.append(signum)

    old_handlers = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        evaluator.start()
        for p in procs:
            p.start(params_file, env)
        t_nodes = time.perf_counter()
        last_progress = (0, time.perf_counter())
        done_at = None
        waiting_note = False
        while True:
            executor.spin_once(timeout_sec=0.02)
            recorder.poll_gate()
            # drain what is already queued before the bookkeeping below (one callback per loop
            # made this process fall far behind the learner and show a stale rate)
            for _ in range(2000):
                before = bag.written
                executor.spin_once(timeout_sec=0)
                if bag.written == before:
                    break
            if stop_signal:
                raise KeyboardInterrupt
            now = time.perf_counter()
            if st.samples and t_first is None:
                t_first = now
            if st.samples < micro_actions:  # (the bar always prints a full one: once, below)
                bar.update(st.samples, goals=len(st.goals),
                           regions=len(st.last_regions.regions) if st.last_regions is not None else 1,
                           competence=st.last_competence, error=st.last_error)
            evaluator.flush()
            for at, errors in evaluator.poll():
                publish_eval(at, errors)
            if evaluator.error:
                raise GraphError(f"evaluation failed: {evaluator.error}")
            learner_done = st.status is not None and st.status["micro_actions"] >= micro_actions
            for p in procs:
                code = p.poll()
                if code is not None and not (learner_done and code == 0):
                    raise GraphError(f"node {p.name} exited with code {code} (log {p.log_path}):\n"
                                     f"{p.log_tail()}", code=2 if code == 2 else 1)
            if st.samples != last_progress[0]:
                last_progress = (st.samples, now)
            elif not learner_done and now - last_progress[1] > stall_timeout:
                raise GraphError(f"no new sample for {stall_timeout:.0f} s (at {st.samples} micro-actions); "
                                 f"node logs in {out / 'logs'}")
            if learner_done and st.samples >= st.status["samples"]:
                if done_at is None:
                    done_at = now
                # a short drain so reports/goals published just before the end are recorded too
                if now - done_at > 0.5 and evaluator.finished(st.samples):
                    break
                # evaluation is niced and may lag behind learning on a busy machine: wait for it as
                # long as its process lives (it reports its own errors), telling the user once
                if not evaluator.proc.is_alive():
                    raise GraphError("the evaluation process stopped before the final evaluation")
                if not waiting_note and now - done_at > 2.0:
                    waiting_note = True
                    pending = sum(1 for c in evaluator.checkpoints
                                  if c <= st.samples and c not in evaluator.errors)
                    if progress:
                        print(f"\nlearning done; waiting for {pending} pending evaluation(s)",
                              file=sys.stderr, flush=True)
        bar.update(st.samples, force=True, goals=len(st.goals),
                   regions=len(st.last_regions.regions) if st.last_regions is not None else 1,
                   competence=st.last_competence, error=st.last_error)
        # let the recorder take the final Evaluation message
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
        for sig, handler in old_handlers.items():
            signal.signal(sig, handler)
        evaluator.stop()
        recorder.destroy()
        bag.close()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    wall = time.perf_counter() - t_start

    # ---- summary
    learn_seconds = (st.sample_t1 - st.sample_t0) if st.samples - prior_samples > 1 else 0.0
    goals = []
    for seq in sorted(st.goals):
        g = dict(st.goals[seq])
        g["competence"] = st.goal_competence.get(seq)
        g["micro_actions"] = st.report_ma.get(g["after_report"], 0)
        goals.append(g)
    pos = np.array([g["position"] for g in goals], float).reshape(-1, len(t_lower))
    gma = np.array([g["micro_actions"] for g in goals], float)
    done = st.status["micro_actions"] if st.status else st.samples
    regions = []
    if st.last_regions is not None:
        regions = [{"id": int(r.id), "lower": list(r.lower), "upper": list(r.upper),
                    "interest": float(r.interest), "count": int(r.count),
                    "mean_competence": float(r.mean_competence)} for r in st.last_regions.regions]
    curve = sorted(evaluator.curve, key=lambda c: c["micro_actions"])
    area = evaluator.area or reachable_area(spec, t_lower, t_upper, seed=lp["eval.seed"])
    memory = evaluator.memory()
    bag_topics = bag.topics()
    span = {t: (recorder.last_ns[t] - recorder.first_ns[t]) / 1e9 for t in recorder.first_ns}
    summary = {
        "format": "sagg.summary/1",
        "strategy": lp["strategy"],
        "seed": lp["seed"],
        "config": config,
        "node_params": params,
        "params_file": str(params_file),
        "timing": timing,
        "domain_id": domain,
        "micro_actions": int(done),
        "micro_actions_requested": int(micro_actions),
        "micro_actions_per_second": (st.samples - prior_samples - 1) / learn_seconds if learn_seconds > 0 else float("nan"),
        "eval_every": eval_every,
        "resumed_segments": segment - 1,
        "learn_seconds": learn_seconds,
        "startup_seconds": (t_first - t_nodes) if t_first is not None else float("nan"),
        "eval_seconds": evaluator.eval_seconds,
        "wall_seconds": wall,
        "curve": curve,
        "final_mean_error": curve[-1]["mean_error"] if curve else float("nan"),
        "final_median_error": curve[-1]["median_error"] if curve else float("nan"),
        "memory": {"samples": len(memory), "digest": memory.digest(), "bytes": int(memory.nbytes)},
        "learner_status": st.status,
        "reports": st.reports,
        "goals": goals,
        "goal_stats": goal_share_stats(pos, gma, area, micro_actions),
        "test_goals": evaluator.test_goals.tolist() if evaluator.test_goals is not None else None,
        "regions": regions,
        "splits": tracker.splits,
        "bag": {"path": str(bag_path), "paths": [str(b) for b in prior_bags + [bag_path]], "storage": "mcap",
                "topics": bag_topics,
                "sequence_gaps": st.gaps},
        "rates": {t: (bag_topics[t]["count"] - 1) / s for t, s in span.items() if s > 0},
        "nodes": {p.name: {"pid": p.popen.pid if p.popen else None, "exit_code": p.exit_code,
                           "log": str(p.log_path)} for p in procs},
        "interrupted": interrupted,
        "error": str(error) if error else None,
    }
    write_json_atomic(out / "summary.json", summary)
    if report and curve:
        from .report import write_report
        write_report(summary, out, area=area)
    if error is not None:
        raise error
    if interrupted:
        raise KeyboardInterrupt
    return summary
