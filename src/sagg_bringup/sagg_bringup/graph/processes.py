"""The node processes of a graph run: finding a node's executable, starting it on a parameter file
with its log, stopping (SIGINT, then SIGKILL), and picking a private ``ROS_DOMAIN_ID``."""
from __future__ import annotations

import ctypes
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sagg_common.params import ConfigError

# Seconds to wait for the nodes to exit after SIGINT before SIGKILL (docs/architecture.md: nodes sometimes
# ignore SIGINT under load). A node's own shutdown includes up to 1 s of flushing its publishers
# (ros_params.flush_publishers), and all of it takes longer on a loaded machine: the wait leaves room.
STOP_TIMEOUT = 10.0


class GraphError(RuntimeError):
    """The graph failed (a node died, stalled, ...); ``code`` is the exit code to return."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code


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


class NodeGroup:
    """The node processes of one graph on one ROS domain (``domain_id``, or a private random one:
    :func:`pick_domain_id`) with localhost discovery unless ``localhost`` is False (an external
    driver may run on another host: the environment's range then); this process joins the same
    discovery range (the rmw reads it at init). Used by ``sagg run`` (:class:`~sagg_bringup.graph.session.GraphSession`)
    and the lab's graph benchmark and soak, so every graph starts and stops its nodes one way."""

    def __init__(self, procs: list[NodeProcess], domain_id: int | None = None, localhost: bool = True):
        self.procs = procs
        self.domain = pick_domain_id() if domain_id is None else domain_id
        self.env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain), PYTHONUNBUFFERED="1")
        if localhost:
            self.env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

    def start(self, params_file: Path, extra: dict[str, dict] | None = None) -> None:
        """Start every node on ``params_file``, plus ``extra[node name]`` as ``-p`` parameters."""
        for p in self.procs:
            p.start(params_file, self.env, (extra or {}).get(p.name))

    def check(self, may_exit: bool = False) -> None:
        """GraphError naming the first node that exited (with its log's tail); with ``may_exit``,
        a node that exited 0 is fine (the learner is done)."""
        for p in self.procs:
            code = p.poll()
            if code is not None and not (may_exit and code == 0):
                raise GraphError(f"node {p.name} exited with code {code} (log {p.log_path}):\n"
                                 f"{p.log_tail()}", code=2 if code == 2 else 1)

    def stop(self, timeout: float = STOP_TIMEOUT) -> None:
        """SIGINT to every running node, SIGKILL after ``timeout`` s."""
        stop_processes(self.procs, timeout)
