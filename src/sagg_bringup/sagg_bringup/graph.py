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

import ctypes
import json
import multiprocessing
import os
import queue
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

from sagg_common.diagnostics import goal_problem, report_problem, sample_problem
from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError, resolve_nodes
from sagg_common.progress import Progress
from sagg_common.report_kinds import KIND_GOAL, KIND_NAMES
from sagg_goal_generator.core import MODE_NAMES, SCHEMA as GEN
from sagg_goal_generator.schema import SCHEMA as GEN_NODE_SCHEMA
from sagg_low_level.eval_metrics import error_metrics, metric_frame
from sagg_low_level.learner import EvolvingContextLearner, Robot, SCHEMA as LEARNER
from sagg_low_level.memory import SampleMemory
from sagg_low_level.schema import LEARNER_SCHEMA as LEARNER_NODE_SCHEMA

from .bag_reader import bag_messages
from .markers import MarkerView
from .recorder import BagWriter, TopicRecorder, TopicSpec, _msg_class
from .report import write_report
from .results import goal_share_stats, run_overrides

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
    """Full parameter schemas (core + node-only) of the three nodes, from their packages' schema
    modules."""
    # lazy (heavy): mujoco
    from sagg_sim_bridge.schema import BRIDGE_SCHEMA
    return {"sagg_sim_bridge": BRIDGE_SCHEMA, "sagg_goal_generator": GEN_NODE_SCHEMA, "sagg_learner": LEARNER_NODE_SCHEMA}


def core_schemas() -> dict[str, tuple]:
    # lazy (heavy): mujoco
    from sagg_sim_bridge.params import SCHEMA as BRIDGE
    return {"sagg_goal_generator": GEN, "sagg_learner": LEARNER, "sagg_sim_bridge": BRIDGE}


def load_graph_config(path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
    """Resolved parameters of the three nodes (full schemas): defaults < ``/**`` < node section <
    overrides. Same checks as the in-process loader; an override no node declares is an error."""
    schemas = node_schemas()
    out = resolve_nodes(path, {name: schemas[name] for name in NODES}, overrides)
    # lazy (heavy): mujoco
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
    # lazy (heavy): mujoco
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
    # (the waits for `sagg run`'s recorder are not written here: run_only_params)
    return params


def run_only_params(params: dict[str, dict]) -> dict[str, dict]:
    """What only ``sagg run`` gives the nodes, on their command line (``-p``), never in
    ``DIR/params.yaml``: every goal and sample must reach its recorder, so nodes that can wait for
    subscribers wait for one. Written into params.yaml, these waits made a graph started from it
    with ``ros2 run`` / ``ros2 launch`` (no recorder) wait forever."""
    out: dict[str, dict] = {}
    for name, key in (("sagg_goal_generator", "min_goal_subscribers"), ("sagg_learner", "min_sample_subscribers")):
        if params.get(name, {}).get(key) == 0:
            out.setdefault(name, {})[key] = 1
    return out


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


def sagg_topics() -> list[TopicSpec]:
    """The /sagg topics every graph run records (the hardware topics depend on the set-up)."""
    return [
        TopicSpec("/sagg/goal", "sagg_msgs/msg/Goal", publisher="sagg_goal_generator"),
        TopicSpec("/sagg/competence", "sagg_msgs/msg/CompetenceReport", publisher="sagg_learner"),
        TopicSpec("/sagg/regions", "sagg_msgs/msg/RegionTree", depth=1000, transient_local=True,
                  publisher="sagg_goal_generator"),
        TopicSpec("/sagg/sample", "sagg_msgs/msg/Sample", publisher="sagg_learner"),
        TopicSpec("/sagg/status", "sagg_msgs/msg/LearnerStatus", depth=100, publisher="sagg_learner"),
        TopicSpec("/sagg/evaluation", "sagg_msgs/msg/Evaluation", depth=100),
        TopicSpec("/sagg/markers", "visualization_msgs/msg/MarkerArray", depth=1, transient_local=True),
    ]


def graph_topics(learner_params: dict, timing: str = "lockstep") -> list[TopicSpec]:
    controller = learner_params.get("controller", "forward_position_controller")
    task_topic = learner_params.get("task_topic", "/tip_position")
    if not task_topic.startswith("/"):
        task_topic = "/" + task_topic
    return sagg_topics() + [
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

    def start(self, params_file: Path, env: dict, extra: dict | None = None) -> None:
        """Start the node on ``params_file``; ``extra``: parameters given as ``-p name:=value``."""
        log = open(self.log_path, "wb")
        args = [a for k, v in (extra or {}).items() for a in ("-p", f"{k}:={json.dumps(v)}")]  # (JSON is YAML)
        try:
            self.popen = subprocess.Popen(
                [str(self.exe), "--ros-args", "--params-file", str(params_file), *args],
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


def node_processes(nodes: dict[str, tuple[str, str]], logs: Path, segment: int = 1) -> list[NodeProcess]:
    """The (not yet started) processes of ``nodes`` (node section -> (package or node module,
    console script)), logging to ``logs/<script>.log``, or ``<script>.<segment>.log`` for the later
    segments of a resumed run; ``logs`` is created."""
    procs = []
    for name, (module, script) in nodes.items():
        exe = find_node_executable(module.split(".")[0], script)
        procs.append(NodeProcess(name, exe, logs / (f"{script}.log" if segment == 1 else f"{script}.{segment}.log")))
    logs.mkdir(parents=True, exist_ok=True)
    return procs


def check_domain_id(domain_id: int | None) -> None:
    if domain_id is not None and not 0 <= domain_id <= 232:
        raise ConfigError(f"--domain-id: got {domain_id}; allowed: an integer in [0, 232]")


def domain_in_use(domain_id: int, participants: int = 8) -> bool:
    """True if a DDS participant on this host already uses ``domain_id``: participant i of a domain
    binds its unicast discovery port (RTPS: 7400 + 250 * domain + 10 + 2 * i), so if the ports of
    the first ``participants`` are free, nobody here is in that domain (unless those all left and
    a later one stayed). It cannot see a run that picked the domain but has not started its first
    participant yet (about a second for the node processes): a small window, not a guarantee."""
    for i in range(participants):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            try:
                sock.bind(("0.0.0.0", 7410 + 250 * domain_id + 2 * i))
            except OSError:
                return True
    return False


def pick_domain_id() -> int:
    """A random ROS_DOMAIN_ID in 1..200 (private per run: concurrent runs and tests do not mix),
    avoiding the caller's own and any domain that already has a participant on this host
    (``domain_in_use``; with 200 domains a random pick alone collides for ~5 % of 5 concurrent
    runs, and a collision would silently mix two graphs). Drawn from OS entropy: not part of any
    experiment's randomness."""
    own = os.environ.get("ROS_DOMAIN_ID", "")
    # every domain once, in a random order: a free one is found whenever there is one (1000
    # random draws missed the only free domain for (199/200)^1000 = 0.7 % of the picks)
    for d in np.random.default_rng().permutation(np.arange(1, 201)).tolist():
        if str(d) != own and not domain_in_use(d):
            return d
    raise GraphError("no free ROS_DOMAIN_ID in 1..200 on this host (every domain has a DDS participant)")


# ------------------------------------------------------------------------------------ evaluation
def evaluation_setup(learner_params: dict, bridge_params: dict):
    """``(spec, area, test_goals, learner)`` of a run's evaluation, as ``run_experiment`` computes
    them (``test_goals(spec, Y, n=eval.goals, seed=eval.seed)``); the learner (empty memory) is
    built exactly as the learner node builds its own (same neighbour search). Used by ``sagg run``'s
    evaluator and by ``sagg relearn``."""
    # lazy (heavy): mujoco
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
    """Test errors of the frozen model, as ``InProcessRun.evaluate`` (``arm_eval.evaluate_arm``)."""
    # lazy (heavy): mujoco
    from .arm_eval import evaluate_arm
    return evaluate_arm(learner, spec, learner_params["seed"], goals)


def _eval_worker(inbox, outbox, learner_params: dict, bridge_params: dict, checkpoints: list[int],
                 nice: int) -> None:
    """Evaluation process: computes the reachable area and the test goals (as ``run_experiment``
    does: ``test_goals(spec, Y, n=eval.goals, seed=eval.seed)``), then rebuilds the memory from the
    sample batches in ``inbox`` and, whenever it holds exactly a checkpoint's number of samples,
    evaluates the frozen model as ``InProcessRun.evaluate`` does (``arm_eval.evaluate_arm``).
    Sends ``("area", ...)``, then ``("eval", at, errors, seconds)`` per checkpoint, or ``("error", text)``, to ``outbox``."""
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
        ctx = multiprocessing.get_context("spawn")  # never fork a process that runs DDS threads
        self.inbox, self.outbox = ctx.Queue(), ctx.Queue()
        self.proc = ctx.Process(target=_eval_worker, name="sagg-evaluator", daemon=True,
                                args=(self.inbox, self.outbox, learner_params, bridge_params,
                                      list(checkpoints), nice))
        self.area = None  # the ReachableArea of Y, once the worker has computed it
        self.test_goals: np.ndarray | None = None
        self._frame: dict | None = None  # eval_metrics.metric_frame of the test goals, with them
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

    def poll(self) -> list[tuple[int, np.ndarray]]:
        """Evaluations finished since the last call, as ``(micro_actions, errors)``."""
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
                # lazy (heavy): mujoco
                from sagg_sim_bridge.arm import ReachableArea
                self.area = ReachableArea(*item[1:6])
                self.test_goals = item[6]
                # the evaluation's metrics (eval_metrics, as in-process; base at the origin), also
                # for points evaluated before (a resumed run's, from its bags)
                self._frame = metric_frame(self.test_goals, np.zeros(np.asarray(self.test_goals).shape[1]))
                for c in self.curve:
                    c.update(error_metrics(self.errors[c["micro_actions"]], self._frame))
                continue
            _, at, errors, secs = item
            self.eval_seconds += secs
            self.errors[at] = errors
            self.curve.append({"micro_actions": int(at), "mean_error": float(errors.mean()),
                               "median_error": float(np.median(errors))})
            if self._frame is not None:
                self.curve[-1].update(error_metrics(errors, self._frame))
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
    status_rate: bool = True  # keep /sagg/status's micro_actions_per_second in `status`
    # messages from the expected publisher that were rejected, by "<topic> <problem>" (DESIGN §8)
    rejected: dict[str, int] = field(default_factory=dict)
    task_lower: Any = None  # Y, for checking goals (None: not checked)
    task_upper: Any = None
    window: int = 10000     # a goal or report seq further than this beyond the last is rejected

    def reject(self, topic: str, kind: str) -> None:
        key = f"{topic} {kind}"
        self.rejected[key] = self.rejected.get(key, 0) + 1

    def on_goal(self, m) -> None:
        """/sagg/goal (keyed by seq)."""
        if int(m.seq) in self.goals:
            return  # published again (a repeated goal request after a generator restart)
        if not 0 < int(m.seq) <= len(self.goals) + self.window:
            self.reject("/sagg/goal", "seq out of window")
            return
        if self.task_lower is not None and goal_problem(m.position, self.task_lower, self.task_upper)[1]:
            self.reject("/sagg/goal", "position not finite or outside Y")
            return
        if int(m.seq) != len(self.goals) + 1:
            self.gaps["/sagg/goal"] += 1
        self.goals[int(m.seq)] = {"seq": int(m.seq), "position": list(m.position), "mode": int(m.mode),
                                  "mode_name": MODE_NAMES.get(int(m.mode), str(m.mode)),
                                  "after_report": int(m.after_report)}
        return True

    def on_report(self, m) -> None:
        """/sagg/competence: the micro-actions at each report, the competence of each goal."""
        if int(m.seq) <= self.reports:
            return  # republished by a resumed learner
        if int(m.seq) > self.reports + self.window:
            self.reject("/sagg/competence", "seq out of window")
            return
        target = m.target if len(m.target) else m.reached
        dim = len(self.task_lower) if self.task_lower is not None else len(m.reached)
        if report_problem(int(m.kind), target, float(m.competence), dim, KIND_NAMES):
            self.reject("/sagg/competence", "invalid content")
            return
        if int(m.seq) != self.reports + 1:
            self.gaps["/sagg/competence"] += 1
        self.reports += 1
        self.report_ma[int(m.seq)] = int(m.micro_actions)
        if m.kind == KIND_GOAL:
            self.goal_competence[int(m.goal_seq)] = float(m.competence)
            self.last_competence = float(m.competence)
        return True

    def on_regions(self, m) -> bool:
        self.last_regions = m
        return True

    def on_status(self, m) -> bool:
        self.status = _status_dict(m, self.status_rate)
        return True

    def progress(self) -> dict:
        """The progress bar's fields."""
        return {"goals": len(self.goals),
                "regions": len(self.last_regions.regions) if self.last_regions is not None else 1,
                "competence": self.last_competence, "error": self.last_error}

    def goal_list(self) -> list[dict]:
        """The goals in seq order, with their final competence and the micro-actions done when
        they were chosen (the summary's ``goals``)."""
        goals = []
        for seq in sorted(self.goals):
            g = dict(self.goals[seq])
            g["competence"] = self.goal_competence.get(seq)
            g["micro_actions"] = self.report_ma.get(g["after_report"], 0)
            goals.append(g)
        return goals

    def region_list(self) -> list[dict]:
        """The leaves of the last /sagg/regions (the summary's ``regions``)."""
        if self.last_regions is None:
            return []
        return [{"id": int(r.id), "lower": list(r.lower), "upper": list(r.upper),
                 "interest": float(r.interest), "count": int(r.count),
                 "mean_competence": float(r.mean_competence)} for r in self.last_regions.regions]


def _status_dict(m, rate: bool = True) -> dict:
    out = {"strategy": m.strategy, "micro_actions": int(m.micro_actions), "goals": int(m.goals),
           "samples": int(m.samples), "last_competence": float(m.last_competence)}
    if rate:
        out["micro_actions_per_second"] = float(m.micro_actions_per_second)
    out.update(paused=bool(m.paused), pause_reason=m.pause_reason)
    return out


# the keys of summary.json, in order (a run writes those it has)
SUMMARY_KEYS = ("format", "strategy", "seed", "config", "node_params", "params_file", "timing", "domain_id",
                "micro_actions", "micro_actions_requested", "micro_actions_per_second", "eval_every",
                "resumed_segments", "learn_seconds", "startup_seconds", "eval_seconds", "wall_seconds", "curve",
                "final_mean_error", "final_median_error", "memory", "learner_status", "reports", "goals",
                "goal_stats", "test_goals", "regions", "splits", "bag", "rates", "synergy", "nodes",
                "interrupted", "error", "driver", "curve_source", "simulated_evaluation", "robot_evaluation")


def _both(first: Callable, second: Callable) -> Callable:
    """Both handlers; the first one's answer (truthy: message used) is the recorder's, which
    advances the expected publisher's stream with it (dropping it left the stream at 0: while a
    second publisher was on the topic, every real message was then rejected as foreign)."""
    def handler(msg):
        used = first(msg)
        second(msg)
        return used
    return handler


class GraphSession:
    """The orchestration one ``sagg run`` graph run needs, for the arm (:func:`run_graph`) and the
    synergy set-ups (:func:`~sagg_bringup.synergy_graph.run_synergy_graph`): the node processes on
    a private ``ROS_DOMAIN_ID`` (``domain_id``, or a random one) with localhost discovery; this
    process's rclpy node, executor and ``/sagg/evaluation`` publisher; the mcap bag of ``topics``
    and its recorder (feeding :attr:`st`, a :class:`RunState`); Ctrl-C / SIGTERM as a flag; the wait
    for the learner to finish (a node exiting or a stall is a :class:`GraphError`); the cleanup in
    every case; the summary's common keys. ``drain``: at most this many queued callbacks are taken
    per loop before the bookkeeping."""

    def __init__(self, procs: list[NodeProcess], domain_id: int | None, topics: list[TopicSpec],
                 bag_path: Path, out: Path, drain: int, status_rate: bool = True, localhost: bool = True):
        self.procs, self.topics, self.out, self.drain = procs, topics, out, drain
        self.domain = pick_domain_id() if domain_id is None else domain_id
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain), PYTHONUNBUFFERED="1")
        if localhost:  # (an external driver may run on another host: the environment's range then)
            self.env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
            # this process joins the same private domain (the rmw reads the discovery range at init)
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
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
        self.bag = BagWriter(bag_path, topics)
        self.st = RunState(status_rate=status_rate)
        self.eval_pub = self.node.create_publisher(Evaluation, "/sagg/evaluation", 100)
        self.recorder: TopicRecorder | None = None
        # backpressure (acknowledge): ack_source() = the samples recorded and accepted from index 0
        self.ack_source: Callable[[], int] | None = None
        self.ack_pub = None
        self._acked, self._ack_t = -1, 0.0
        self.view = None  # markers.MarkerView, from record()
        self.stop_signal: list[int] = []
        self.interrupted = False
        self.error: GraphError | None = None
        self.t_nodes: float | None = None  # when the nodes were started
        self.t_end: float | None = None    # when everything was stopped
        self._closed = False

    def record(self, handlers: dict[str, Callable]) -> None:
        """Record every topic (``handlers``: topic -> callback of the deserialized message).
        /sagg/sample is subscribed once the hardware topics (and /sagg/competence) are matched: the
        learner waits for that subscriber before its first command, so the bag misses no command
        or answer of the driver."""
        hw = tuple(t.name for t in self.topics if not t.name.startswith("/sagg/") and t.name != "/clock")
        self.view = MarkerView(self.node, self.topics)
        handlers = dict(handlers)
        for topic, h in self.view.handlers().items():
            handlers[topic] = h if topic not in handlers else _both(handlers[topic], h)
        self.recorder = TopicRecorder(self.node, self.bag, self.topics, handlers,
                                      gate=("/sagg/sample",), wait_for=hw + ("/sagg/competence",))

    def acknowledge(self, source: Callable[[], int]) -> None:
        """Publish ``source()`` (how many samples, from index 0, are recorded and accepted) on
        /sagg/recorded, the learner's backpressure (``recorder_max_lag``). Only a session that calls
        this has the publisher: the learner waits only while an acknowledging recorder exists."""
        # lazy (heavy): ROS interface package
        from std_msgs.msg import UInt64
        self._uint64 = UInt64
        self.ack_pub = self.node.create_publisher(UInt64, "/sagg/recorded", 10)
        self.ack_source = source

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
        for p in self.procs:
            p.start(params_file, self.env, (extra or {}).get(p.name))
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
        if self.ack_source is not None:
            # on every change, and at least every 0.5 s (a learner subscribing later, e.g. a
            # resumed one whose count starts where the earlier bags end, gets it too)
            n, now = self.ack_source(), time.monotonic()
            if n != self._acked or now - self._ack_t >= 0.5:
                self._acked, self._ack_t = n, now
                self.ack_pub.publish(self._uint64(data=n))
        if self.stop_signal:
            raise KeyboardInterrupt

    def wait_for_learner(self, micro_actions: int, stall_timeout: float, unit: str,
                         tick: Callable[[float], None], may_end: Callable[[float], bool]) -> None:
        """Spin until the learner reports ``micro_actions`` done (/sagg/status), every sample it
        stored is in, and ``may_end(seconds since then)`` is true. ``tick(now)`` runs after every
        spin. GraphError when a node exits before (a node that exits 0 once the learner is done is
        fine) or no new sample came for ``stall_timeout`` s (``unit``: what a sample counts)."""
        st = self.st
        last_progress = (0, time.perf_counter())
        done_at = None
        while True:
            self.spin()
            now = time.perf_counter()
            tick(now)
            learner_done = st.status is not None and st.status["micro_actions"] >= micro_actions
            for p in self.procs:
                code = p.poll()
                if code is not None and not (learner_done and code == 0):
                    raise GraphError(f"node {p.name} exited with code {code} (log {p.log_path}):\n"
                                     f"{p.log_tail()}", code=2 if code == 2 else 1)
            if st.samples != last_progress[0]:
                last_progress = (st.samples, now)
            elif not learner_done and now - last_progress[1] > stall_timeout:
                raise GraphError(f"no new sample for {stall_timeout:.0f} s (at {st.samples} {unit}); "
                                 f"node logs in {self.out / 'logs'}")
            if learner_done and st.samples >= st.status["samples"]:
                if done_at is None:
                    done_at = now
                if may_end(now - done_at):
                    return

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
                elif paused and st.status and st.samples >= st.status["samples"] and now - t_last >= 0.5:
                    break
        finally:
            self.node.destroy_client(cli)

    def drain_recorder(self, quiet: float = 0.5, limit: float = 60.0) -> None:
        """After the nodes stopped: take what the recorder's subscriptions still hold (a recorder
        that fell behind, e.g. on an interrupted run on a loaded machine, would otherwise lose its
        backlog), until nothing came for ``quiet`` s (at most ``limit`` s)."""
        if self.recorder is None or self.bag.closed:
            return
        t_end = time.perf_counter() + limit
        last, t_last = self.bag.written, time.perf_counter()
        while time.perf_counter() < t_end:
            self.executor.spin_once(timeout_sec=0.05)
            now = time.perf_counter()
            if self.bag.written != last:
                last, t_last = self.bag.written, now
            elif now - t_last >= quiet:
                break

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
            stop_processes(self.procs)
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
            "reports": st.reports,
            "goals": goals,
            "goal_stats": goal_share_stats(pos, gma, area, micro_actions) if area is not None else {},
            "regions": st.region_list(),
            "nodes": {p.name: {"pid": p.popen.pid if p.popen else None, "exit_code": p.exit_code,
                               "log": str(p.log_path)} for p in self.procs},
            "interrupted": self.interrupted,
            "error": str(self.error) if self.error else None,
        })
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
    # lazy (heavy): mujoco
    from sagg_sim_bridge.arm import reachable_area
    from sagg_sim_bridge.params import arm_spec_from_params

    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    if timing not in TIMINGS:
        raise ConfigError(f"--timing: got {timing!r}; allowed: one of {', '.join(TIMINGS)}")
    check_domain_id(domain_id)
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
    procs = node_processes(NODES, out / "logs", segment)
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

    session = GraphSession(procs, domain_id, graph_topics(params["sagg_learner"], timing), bag_path, out,
                           drain=2000)
    st = session.st
    try:  # set-up: a failure or Ctrl-C before session.run still closes the bag and rclpy

        # a resumed run: the earlier segments' messages, and their evaluations (not repeated)
        prior = []
        done_evals: dict[int, np.ndarray] = {}
        if prior_bags:
            # lazy (heavy): ROS
            from rclpy.serialization import deserialize_message
            from sagg_msgs.msg import Evaluation
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

        j_lo, j_hi = params["sagg_learner"]["joint_limits.lower"], params["sagg_learner"]["joint_limits.upper"]
        j_tol, t_dim = params["sagg_learner"]["plausibility.joint_tolerance"], len(t_lower)

        def on_sample(m) -> None:
            if int(m.index) < st.samples:
                return  # republished by a resumed learner (same values)
            # a sample must continue the sequence and be plausible (a forged one is dropped and
            # counted; it never takes the index of the real one)
            if sample_problem(int(m.index), st.samples, m.alpha, m.delta_alpha, m.delta_y, j_lo, j_hi, t_dim, j_tol):
                st.reject("/sagg/sample", "index or content rejected")
                return
            now = time.perf_counter()
            if st.sample_t0 is None:
                st.sample_t0 = now
            st.sample_t1 = now
            st.samples += 1
            evaluator.add(int(m.index), np.array(m.alpha), np.array(m.delta_alpha), np.array(m.delta_y))
            return True

        tracker = SplitTracker(t_lower, t_upper)

        def on_regions(m) -> bool:
            st.last_regions = m
            tracker.update([(int(r.id), r.lower, r.upper) for r in m.regions], int(m.goals))
            return True

        if prior:
            handlers = {"/sagg/sample": on_sample, "/sagg/goal": st.on_goal, "/sagg/competence": st.on_report,
                        "/sagg/regions": on_regions}
            for topic, msgtype, _, raw in prior:
                if topic in handlers:
                    handlers[topic](deserialize_message(bytes(raw), _msg_class(msgtype)))
            st.sample_t0 = st.sample_t1 = None  # rates: this segment only
        prior_samples = st.samples

        st.task_lower, st.task_upper = t_lower, t_upper
        session.record({"/sagg/sample": on_sample, "/sagg/goal": st.on_goal, "/sagg/competence": st.on_report,
                        "/sagg/regions": on_regions, "/sagg/status": st.on_status})
        session.acknowledge(lambda: st.samples)  # the samples recorded and accepted, from index 0
        bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']} (graph, {timing})", enabled=progress)
        t_first = None
        waiting_note = False

        def tick(now: float) -> None:
            nonlocal t_first
            if st.samples and t_first is None:
                t_first = now
            if st.samples < micro_actions:  # (the bar always prints a full one: once, below)
                bar.update(st.samples, **st.progress())
            evaluator.flush()
            for at, errors in evaluator.poll():
                session.publish_evaluation(at, errors)
            if evaluator.error:
                raise GraphError(f"evaluation failed: {evaluator.error}")
            if evaluator.test_goals is not None and session.view.test_goals is None:
                session.view.set_test_goals(evaluator.test_goals)

        def may_end(waited: float) -> bool:
            nonlocal waiting_note
            # a short drain so reports/goals published just before the end are recorded too
            if waited > 0.5 and evaluator.finished(st.samples):
                return True
            # evaluation is niced and may lag behind learning on a busy machine: wait for it as
            # long as its process lives (it reports its own errors), telling the user once
            if not evaluator.proc.is_alive():
                raise GraphError("the evaluation process stopped before the final evaluation")
            if not waiting_note and waited > 2.0:
                waiting_note = True
                pending = sum(1 for c in evaluator.checkpoints
                              if c <= st.samples and c not in evaluator.errors)
                if progress:
                    print(f"\nlearning done; waiting for {pending} pending evaluation(s)",
                          file=sys.stderr, flush=True)
            return False

        def body() -> None:
            evaluator.start()
            session.start_nodes(params_file, run_only_params(params))
            session.wait_for_learner(micro_actions, stall_timeout, "micro-actions", tick, may_end)
            bar.update(st.samples, force=True, **st.progress())
            session.final_drain()
    except BaseException:
        session.close()
        raise

    session.run(body, bar, between=evaluator.stop)

    # ---- summary
    curve = sorted(evaluator.curve, key=lambda c: c["micro_actions"])
    area = evaluator.area or reachable_area(spec, t_lower, t_upper, seed=lp["eval.seed"])
    memory = evaluator.memory()
    bag_topics = session.bag.topics()
    recorder = session.recorder
    span = {t: (recorder.last_ns[t] - recorder.first_ns[t]) / 1e9 for t in recorder.first_ns}
    summary = session.summary(
        lp, config, params, params_file, timing, micro_actions, curve, area, t_start, prior_samples,
        eval_every=eval_every,
        resumed_segments=segment - 1,
        startup_seconds=(t_first - session.t_nodes) if t_first is not None else float("nan"),
        eval_seconds=evaluator.eval_seconds,
        memory={"samples": len(memory), "digest": memory.digest(), "bytes": int(memory.nbytes)},
        test_goals=evaluator.test_goals.tolist() if evaluator.test_goals is not None else None,
        splits=tracker.splits,
        bag={"path": str(bag_path), "paths": [str(b) for b in prior_bags + [bag_path]], "storage": "mcap",
             "topics": bag_topics, "sequence_gaps": st.gaps, "rejected": session.rejected(),
             "dropped": dict(recorder.dropped), "dropped_not_estimated": sorted(recorder.drops_unknown)},
        rates={t: (bag_topics[t]["count"] - 1) / s for t, s in span.items() if s > 0})

    def report_now() -> None:
        write_report(summary, out, area=area)

    return session.finish(summary, report_now if report and curve else None)
