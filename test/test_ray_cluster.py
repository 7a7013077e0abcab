"""``sagg bench compare`` and ``sagg reproduce`` on a real Ray cluster of two nodes.

The cluster is this machine twice: a head (``ray start --head``) and a second node (``ray start
--address``), each with its own temporary directory, ports and one CPU, both started from a
directory that is not the repository's. The comparison names its config relatively (a model arm:
config/arm7_urdf.yaml, its URDF beside it) from the repository, as a user would: the workers get the
files through the task, not from their directory. Same seeds, same results as the local process
pool. ``sagg reproduce`` on the same cluster is interrupted after its first finished run and
resumed: the finished runs are kept, not rerun.

Clean-up stops this cluster only (``ray stop`` would stop every Ray on the machine): each node's
``ray start`` runs in a session of its own and its daemons and workers stay in its process group,
which gets SIGTERM, then SIGKILL; a process still naming one of the cluster's temporary directories
gets SIGKILL too. ``pytest -s`` shows the commands' output (the record in docs/notes/ray-cluster.md).
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from contextlib import ExitStack
from pathlib import Path

import pytest

from installed import SAGG
from test_sweep_bundle import differences

ROOT = Path(__file__).resolve().parents[1]
RAY = Path(sys.executable).with_name("ray")  # the venv's Ray command (requirements-ray.txt)
NODE_PORTS = ("--node-manager-port", "--object-manager-port", "--dashboard-agent-listen-port",
              "--dashboard-agent-grpc-port", "--runtime-env-agent-port", "--metrics-export-port")
TINY = ["--micro-actions", "300", "--eval-every", "150", "--set", "eval.goals=10"]
CLAIM = "y50-sagg-beats-actuator"  # smoke scale: 4 strategies x 2 seeds x 100 micro-actions


def free_ports(n: int) -> list[int]:
    """``n`` distinct ports free now (the OS picks them)."""
    socks = [socket.socket() for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def group_alive(pgid: int) -> bool:
    """Whether a process of group ``pgid`` still runs (a zombie, waiting for its reaper, does not)."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()  # after "pid (comm)": state, ppid, pgrp
        except (OSError, IndexError):
            continue
        if int(fields[2]) == pgid and fields[0] != "Z":
            return True
    return False


def naming(text: str) -> list[int]:
    """Processes whose command line contains ``text``."""
    pids = []
    for d in Path("/proc").iterdir():
        try:
            if d.name.isdigit() and text.encode() in (d / "cmdline").read_bytes():
                pids.append(int(d.name))
        except OSError:
            pass
    return pids


def stop_node(pgid: int, temp_dir: str) -> None:
    """This node's processes: SIGTERM to its group, SIGKILL after 3 s (the GCS and the raylet take
    longer over a graceful stop, which a test cluster does not need), and SIGKILL to any process
    still naming its temporary directory."""
    for sig, grace in ((signal.SIGTERM, 3.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(pgid, sig)
        except ProcessLookupError:
            break
        deadline = time.monotonic() + grace
        while group_alive(pgid) and time.monotonic() < deadline:
            time.sleep(0.2)
    for pid in naming(temp_dir):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def start_node(args: list[str], temp_dir: str, cwd: str, stack: ExitStack) -> None:
    """``ray start ARGS`` in a session of its own, from ``cwd``; its stop is pushed on ``stack``."""
    ports = free_ports(len(NODE_PORTS))
    cmd = [str(RAY), "start", *args, "--num-cpus", "1", "--temp-dir", temp_dir, "--disable-usage-stats",
           "--node-ip-address", "127.0.0.1", *[x for kv in zip(NODE_PORTS, map(str, ports)) for x in kv]]
    p = subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                         start_new_session=True)
    stack.callback(stop_node, p.pid, temp_dir)
    try:
        out, _ = p.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        out, _ = p.communicate()
        pytest.fail(f"ray start did not return in 120 s:\n{out}")
    assert p.returncode == 0, f"{' '.join(cmd)}:\n{out}"


@pytest.fixture(scope="module")
def cluster():
    """The address of a 2-node Ray cluster, stopped at the end."""
    base = tempfile.mkdtemp(prefix="sagg-ray-")  # short: Ray's socket paths live under it
    with ExitStack() as stack:
        stack.callback(shutil.rmtree, base, True)
        dirs = {k: os.path.join(base, k) for k in ("head", "node2", "cwd-head", "cwd-node2")}
        for d in dirs.values():
            os.mkdir(d)
        port, dashboard = free_ports(2)
        start_node(["--head", "--port", str(port), "--include-dashboard=false", "--dashboard-port", str(dashboard)],
                   dirs["head"], dirs["cwd-head"], stack)
        start_node(["--address", f"127.0.0.1:{port}"], dirs["node2"], dirs["cwd-node2"], stack)
        yield f"127.0.0.1:{port}"


def sagg(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    """``sagg ARGS`` from the repository's root (relative config paths), output checked."""
    r = subprocess.run([str(SAGG), *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stdout + r.stderr
    return r


def nodes_of(stdout: str) -> set[str]:
    return set(re.findall(r"on Ray node ([0-9a-f]+) ", stdout))


def results(out: Path) -> dict[str, dict]:
    return {str(f.relative_to(out)): json.loads(f.read_text()) for f in sorted(out.rglob("result.json"))}


def test_compare_on_two_nodes_gives_the_local_pool_results(cluster, tmp_path):
    common = ["bench", "compare", "--config", "config/arm7_urdf.yaml", "--strategies", "sagg-riac", "sagg-random",
              "--seeds", "2", *TINY]
    r = sagg(*common, "--ray", cluster, "--out", str(tmp_path / "ray"))
    print(r.stdout)  # (shown with pytest -s: the measurement in docs/notes/ray-cluster.md)
    assert f"4 to run on Ray ({cluster})" in r.stdout and "FAILED" not in r.stdout, r.stdout
    assert len(nodes_of(r.stdout)) == 2, r.stdout  # both nodes ran runs
    sagg(*common, "--workers", "2", "--out", str(tmp_path / "local"))
    on_ray, local = results(tmp_path / "ray"), results(tmp_path / "local")
    assert len(on_ray) == 4 and on_ray.keys() == local.keys()
    for name in local:
        # (commit: the repository's HEAD when the driver wrote the result, not what the run computed)
        assert differences(on_ray[name], local[name], ignore=("commit",)) == [], name
    # the files as the driver names them
    assert on_ray[name]["config"]["sagg_sim_bridge"]["arm.model"] == str(ROOT / "config/robots/arm7.urdf")


def test_reproduce_interrupted_on_the_cluster_resumes_without_rerunning(cluster, tmp_path):
    out = tmp_path / "rep"
    cmd = [str(SAGG), "reproduce", CLAIM, "--scale", "smoke", "--ray", cluster, "--out", str(out)]
    log = tmp_path / "first.log"
    with open(log, "w") as f:
        p = subprocess.Popen(cmd, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        # the driver killed (as a crash or a lost terminal would) once its first result is on disk:
        # watched on disk, not on its output, which a loaded machine may hand over late
        end = time.monotonic() + 240
        while not results(out / "experiments/y50") and p.poll() is None and time.monotonic() < end:
            time.sleep(0.05)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        p.wait(30)
    seen = log.read_text()
    print(seen, f"(interrupted: exit status {p.returncode})")
    assert p.returncode != 0, seen
    kept = {name: (out / "experiments/y50" / name).read_bytes()
            for name in results(out / "experiments/y50")}
    assert 1 <= len(kept) < 8, seen

    r = sagg("reproduce", CLAIM, "--scale", "smoke", "--ray", cluster, "--out", str(out))
    print(r.stdout)
    assert f"resuming: {len(kept)} finished run(s) kept and skipped, {8 - len(kept)} to run on Ray" in r.stdout, \
        r.stdout
    for name, content in kept.items():
        assert (out / "experiments/y50" / name).read_bytes() == content, f"{name} was rerun"
        assert f"{name.split('/')[1]}/{name.split('/')[2]}:" not in r.stdout  # (no progress line for it)
    assert len(results(out / "experiments/y50")) == 8
    assert (out / "claims.json").exists()
