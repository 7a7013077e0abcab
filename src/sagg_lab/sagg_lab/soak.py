"""``sagg bench soak``: long runs checking that memory grows only with the stored samples and that
no file descriptors or shared-memory segments leak.

Two modes, each printing a table of (micro-actions, stored samples, RSS, bytes of the sample
memory, open fds) every ``--every`` micro-actions and a verdict block:

- ``inprocess``: :class:`~sagg_bringup.inprocess.experiment.InProcessRun` stepped to N micro-actions in this
  process (no ROS). RSS / fds are this process's (``/proc/self``).
- ``graph``: the three node processes (the same console scripts and parameter file as ``sagg run``,
  lockstep), N micro-actions; progress read from ``/sagg/status`` by a small node in this process;
  RSS / fds of every node process from ``/proc/<pid>``. No recorder and no evaluator (``sagg run``'s
  own bookkeeping is not what is soaked here): the learner does not wait for sample subscribers.
  Checkpoints and journals are on, as in ``sagg run`` (``OUT/graph/checkpoint``).

Reported numbers:

- bytes per stored sample: ``SampleMemory.nbytes / samples`` (allocated capacity and index
  included; in-process only) and the RSS growth per stored sample: least-squares slope of RSS
  against samples over the second half of the rows (after start-up allocations);
- open fds at the first and the last row (per process) and ``/dev/shm`` entries before the start
  and after the end. For the graph, also the /dev/shm files the nodes had mapped
  (``/proc/<pid>/maps``) that still exist after they stopped, and of those the ones created during
  the run (absent before it): a leak of ours, unlike the global count, which other processes on the
  machine change too (Fast DDS's shared ``fastrtps_port*`` segments outlive every participant by
  design and are reused).
"""
from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sagg_common.journal import write_json_atomic
from sagg_common.ros_params import reliable

from sagg_bringup.inprocess.arm_params import NODES, graph_params, load_graph_config
from sagg_bringup.graph.params_files import run_values, set_checkpoint_dirs, write_params_file
from sagg_bringup.graph.processes import GraphError, NodeGroup, node_processes


def rss_bytes(pid: int | str = "self") -> int:
    """Resident set size of a process (``VmRSS`` of ``/proc/<pid>/status``), bytes; 0 if gone."""
    try:
        with open(f"/proc/{pid}/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


def open_fds(pid: int | str = "self") -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return -1


def shm_entries() -> set[str]:
    try:
        return set(os.listdir("/dev/shm"))
    except OSError:
        return set()


def mapped_shm(pid: int | str) -> set[str]:
    """Names of the /dev/shm files a process has mapped."""
    out = set()
    try:
        with open(f"/proc/{pid}/maps") as fh:
            for line in fh:
                i = line.find("/dev/shm/")
                if i >= 0:
                    out.add(line[i + len("/dev/shm/"):].strip().split(" ")[0])
    except OSError:
        pass
    return out


def growth_per_sample(rows: list[dict], key: str) -> float:
    """Least-squares slope of ``row[key]`` against ``row['samples']`` over the second half of the
    rows (bytes per stored sample); NaN with fewer than 3 rows there."""
    half = rows[len(rows) // 2:]
    if len(half) < 3:
        return float("nan")
    x = np.array([r["samples"] for r in half], float)
    y = np.array([r[key] for r in half], float)
    if np.ptp(x) == 0:
        return float("nan")
    return float(np.polyfit(x, y, 1)[0])


def _mb(b: float) -> str:
    return f"{b / 2**20:9.1f}"


def soak_inprocess(config: str | Path, micro_actions: int, every: int,
                   overrides: dict[str, Any] | None = None, out: Callable[[str], None] = print) -> dict:
    """In-process soak; returns the rows and the verdict numbers."""
    # lazy (heavy): mujoco
    from sagg_bringup.inprocess.experiment import InProcessRun
    from sagg_bringup.graph.setups import load_experiment_config

    shm0 = shm_entries()
    fd0 = open_fds()
    run = InProcessRun(load_experiment_config(config, overrides or {}))
    mem = run.learner.memory
    raw = 8 * (mem.state_dim + mem.action_dim + mem.outcome_dim)
    out(f"in-process soak: {config}, {micro_actions:,} micro-actions; raw sample payload {raw} bytes")
    out(f"{'micro-actions':>13} {'samples':>9} {'RSS MiB':>9} {'memory MiB':>10} {'B/sample':>9} "
        f"{'fds':>4} {'micro-actions/s':>15}")
    rows = []
    t0 = time.perf_counter()
    last = (0, t0)
    for target in list(range(every, micro_actions, every)) + [micro_actions]:
        run.step_until(target)
        now = time.perf_counter()
        row = {"micro_actions": run.learner.micro_actions, "samples": len(mem), "rss": rss_bytes(),
               "memory_bytes": mem.nbytes, "fds": open_fds(),
               "rate": (target - last[0]) / max(now - last[1], 1e-9)}
        last = (target, now)
        rows.append(row)
        out(f"{row['micro_actions']:>13,} {row['samples']:>9,} {_mb(row['rss'])} {_mb(row['memory_bytes']):>10} "
            f"{row['memory_bytes'] / max(1, row['samples']):>9.1f} {row['fds']:>4} {row['rate']:>15,.0f}")
    mapped = mapped_shm(os.getpid())  # (no ROS in-process: expected none)
    del run, mem
    shm1 = shm_entries()
    res = {
        "mode": "inprocess", "config": str(config), "micro_actions": micro_actions,
        "seconds": time.perf_counter() - t0, "raw_sample_bytes": raw, "rows": rows,
        "memory_bytes_per_sample": rows[-1]["memory_bytes"] / max(1, rows[-1]["samples"]),
        "rss_growth_per_sample": growth_per_sample(rows, "rss"),
        "fds_start": fd0, "fds_end": open_fds(),
        "shm_before": len(shm0), "shm_after": len(shm1),
        "shm_new": sorted(shm1 - shm0), "shm_mapped_by_this_process": sorted(mapped),
    }
    out(f"bytes per stored sample: memory {res['memory_bytes_per_sample']:.1f} (raw payload {raw}); "
        f"RSS growth {res['rss_growth_per_sample']:.1f} B/sample (second half); "
        f"fds {fd0} -> {res['fds_end']}; /dev/shm entries {len(shm0)} -> {len(shm1)} "
        f"(new: {len(res['shm_new'])}, machine-wide; mapped by this process: {len(mapped)}); "
        f"{res['seconds']:.0f} s")
    return res


def soak_graph(config: str | Path, micro_actions: int, every: int, out_dir: str | Path,
               overrides: dict[str, Any] | None = None, stall_timeout: float = 120.0,
               out: Callable[[str], None] = print) -> dict:
    """Graph soak: the three nodes for ``micro_actions`` micro-actions (lockstep)."""

    full = load_graph_config(config, overrides or {})
    params = graph_params(full, micro_actions, "lockstep")
    # nobody records here: the nodes must not wait for a recorder
    params["sagg_learner"]["min_sample_subscribers"] = 0
    params["sagg_goal_generator"]["min_goal_subscribers"] = 0
    outp = Path(out_dir)
    (outp / "logs").mkdir(parents=True, exist_ok=True)
    # checkpoints and write-ahead journals on, as in `sagg run` (into OUT/checkpoint)
    set_checkpoint_dirs(params, outp)
    params_file = outp / "params.yaml"
    write_params_file(params_file, params)
    nodes = NodeGroup(node_processes(NODES, outp / "logs"))
    procs, domain = nodes.procs, nodes.domain
    shm0 = shm_entries()
    # lazy (heavy): ROS
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    from sagg_msgs.msg import LearnerStatus


    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain, signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node("sagg_soak", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    status: dict = {}

    def on_status(m) -> None:
        status.update(micro_actions=int(m.micro_actions), samples=int(m.samples), paused=m.paused,
                      reason=m.pause_reason, rate=float(m.micro_actions_per_second))

    node.create_subscription(LearnerStatus, "/sagg/status", on_status, reliable(10))
    names = [p.name.replace("sagg_", "") for p in procs]
    out(f"graph soak: {config}, {micro_actions:,} micro-actions (lockstep), domain {domain}")
    out(f"{'micro-actions':>13} {'samples':>9} " + " ".join(f"{n + ' RSS MiB':>22} {'fds':>4}" for n in names)
        + f" {'micro-actions/s':>15}")
    rows: list[dict] = []
    mapped: set[str] = set()
    t0 = time.perf_counter()
    next_row = every
    error = None
    fds0: dict[str, int] = {}
    try:
        nodes.start(params_file, run_values(params))  # (checkpoint_dir, budget: not in params.yaml)
        last = (0, time.monotonic())
        while True:
            ex.spin_once(timeout_sec=0.1)
            nodes.check()
            for p in procs:
                if p.name not in fds0 and status:
                    fds0[p.name] = open_fds(p.popen.pid)
            done = status.get("micro_actions", 0)
            if done != last[0]:
                last = (done, time.monotonic())
            elif time.monotonic() - last[1] > stall_timeout:
                raise GraphError(f"no progress for {stall_timeout:.0f} s at {done} micro-actions")
            if done >= next_row or done >= micro_actions:
                row = {"micro_actions": done, "samples": status.get("samples", 0), "rate": status.get("rate", 0.0)}
                for p in procs:
                    row[f"{p.name}.rss"] = rss_bytes(p.popen.pid)
                    row[f"{p.name}.fds"] = open_fds(p.popen.pid)
                    mapped |= mapped_shm(p.popen.pid)
                rows.append(row)
                out(f"{done:>13,} {row['samples']:>9,} "
                    + " ".join(f"{_mb(row[p.name + '.rss']):>22} {row[p.name + '.fds']:>4}" for p in procs)
                    + f" {row['rate']:>15,.0f}")
                while next_row <= done:
                    next_row += every
                if done >= micro_actions:
                    break
    except GraphError as exc:
        error = str(exc)
    finally:
        nodes.stop()
        ex.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    time.sleep(0.5)
    shm1 = shm_entries()
    res = {"mode": "graph", "config": str(config), "micro_actions": micro_actions, "error": error,
           "seconds": time.perf_counter() - t0, "rows": rows,
           "exit_codes": {p.name: p.exit_code for p in procs},
           "rss_growth_per_sample": {p.name: growth_per_sample(rows, f"{p.name}.rss") for p in procs},
           "fds_first_row": {p.name: rows[0][f"{p.name}.fds"] for p in procs} if rows else {},
           "fds_last_row": {p.name: rows[-1][f"{p.name}.fds"] for p in procs} if rows else {},
           "fds_at_start": fds0,
           "shm_before": len(shm0), "shm_after": len(shm1),
           "shm_mapped_by_nodes": len(mapped), "shm_mapped_left_after_stop": sorted(mapped & shm1),
           # created during the run (absent before), mapped by a node, still there: our leak
           "shm_leaked": sorted((mapped & shm1) - shm0)}
    for p in procs:
        out(f"{p.name}: RSS growth {res['rss_growth_per_sample'][p.name]:.1f} B/sample (second half); "
            f"fds at start {fds0.get(p.name)}, first row {res['fds_first_row'].get(p.name)}, "
            f"last row {res['fds_last_row'].get(p.name)}; exit code {p.exit_code}")
    out(f"/dev/shm entries {len(shm0)} -> {len(shm1)} (machine-wide); files mapped by the nodes: "
        f"{len(mapped)}, still present after they stopped: {len(res['shm_mapped_left_after_stop'])}, of "
        f"which created during the run (leaked): {len(res['shm_leaked'])}; "
        f"{res['seconds']:.0f} s" + (f"; ERROR: {error}" if error else ""))
    return res


def main_soak(args, overrides: dict) -> int:
    """``sagg bench soak``: runs the modes asked for, writes ``OUT/soak.json``."""

    out = Path(args.out or f"runs/soak-{time.strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for mode in args.mode:
        n = args.micro_actions or (1_000_000 if mode == "inprocess" else 100_000)
        every = args.every or max(1, n // 20)
        if mode == "inprocess":
            results[mode] = soak_inprocess(args.config, n, every, overrides)
        else:
            results[mode] = soak_graph(args.config, n, every, out / "graph", overrides)
        write_json_atomic(out / "soak.json", results)
    print(f"-> {out / 'soak.json'}")
    return 1 if any(r.get("error") for r in results.values()) else 0
