"""``sagg bench speed``: in-process micro-actions per second against stored samples.

Costs are compared within one command (ratios against the smallest memory size), never against
numbers from another run: these machines are noisy.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from sagg_common.rng import stream

from .experiment import InProcessRun, load_experiment_config


def prefill(run: InProcessRun, size: int, seed: int = 0) -> None:
    """Fill the learner's memory with ``size`` samples of motor babbling (a random walk of the
    joints around rest with periodic returns), computed with the simulator's batched kinematics.
    Cheap and representative of the samples a run accumulates."""
    sim, learner = run.sim, run.learner
    rng = stream(seed, "bench_prefill")
    n = sim.n_joints
    amp = learner.p["explore_amplitude"]
    period = 200
    done = 0
    while done < size:
        steps = min(period, size - done)
        walk = np.empty((steps + 1, n))
        walk[0] = sim.rest
        for t in range(steps):
            walk[t + 1] = np.clip(walk[t] + rng.uniform(-amp, amp, n), sim.lower, sim.upper)
        tips = sim.tip_positions(walk)
        da, dy = np.diff(walk, axis=0), np.diff(tips, axis=0)
        for t in range(steps):
            learner.memory.add(walk[t], da[t], dy[t])
        done += steps


def bench_speed(config: str | Path, dofs=(7, 15), modes=("kinematic", "dynamic"),
                sizes=(10_000, 200_000), measure: int = 2000, strategy: str = "sagg-riac",
                out=print) -> list[dict]:
    """Micro-actions per second after prefilling the memory to each size; prints a table."""
    rows = []
    out(f"{'dof':>4} {'mode':>10} {'stored':>9} {'micro-actions/s':>16} {'us/micro-action':>16} "
        f"{'cost ratio':>11}")
    for dof in dofs:
        for mode in modes:
            base = None
            for size in sizes:
                cfg = load_experiment_config(config, {"arm.dof": dof, "arm.mode": mode,
                                                      "strategy": strategy})
                run = InProcessRun(cfg)
                prefill(run, size)
                run.step_until(50)  # warm up caches and code paths
                start_ma = run.learner.micro_actions
                t0 = time.perf_counter()
                run.step_until(start_ma + measure)
                dt = time.perf_counter() - t0
                rate = measure / dt
                cost = dt / measure
                base = base or cost
                row = {"dof": dof, "mode": mode, "stored": size, "rate": rate,
                       "us_per_micro_action": cost * 1e6, "cost_ratio": cost / base}
                rows.append(row)
                out(f"{dof:>4} {mode:>10} {size:>9} {rate:>16,.0f} {cost * 1e6:>16.1f} "
                    f"{cost / base:>11.2f}")
    return rows


def graph_rate(config: str | Path, micro_actions: int, overrides: dict | None = None,
               timeout: float = 900.0) -> float:
    """Micro-actions/s of the three node processes in lockstep, from the learner's own log line
    ("N micro-actions in T s", timed from its first command to its last observation); nothing
    else runs (no recorder, no evaluation)."""
    import os
    import re
    import tempfile

    from .graph import (NODES, NodeProcess, find_node_executable, graph_params, load_graph_config,
                        pick_domain_id, stop_processes, write_params_file)

    full = load_graph_config(config, overrides)
    params = graph_params(full, micro_actions, "lockstep")
    params["sagg_learner"]["min_sample_subscribers"] = 0  # nobody records here
    params["sagg_goal_generator"]["min_goal_subscribers"] = 0
    with tempfile.TemporaryDirectory(prefix="sagg-bench-") as tmp:
        tmp = Path(tmp)
        write_params_file(tmp / "params.yaml", params)
        env = dict(os.environ, ROS_DOMAIN_ID=str(pick_domain_id()),
                   ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1")
        procs = [NodeProcess(name, find_node_executable(module.split(".")[0], script),
                             tmp / f"{script}.log") for name, (module, script) in NODES.items()]
        learner_log = tmp / "learner.log"
        try:
            for p in procs:
                p.start(tmp / "params.yaml", env)
            end = time.perf_counter() + timeout
            while time.perf_counter() < end:
                m = re.search(r"\((\d+) micro-actions in ([\d.]+) s", learner_log.read_text(errors="replace"))
                if m:
                    return int(m.group(1)) / float(m.group(2))
                for p in procs:
                    if p.poll() is not None:
                        raise RuntimeError(f"node {p.name} exited with {p.exit_code}: {p.log_tail()}")
                time.sleep(0.05)
            raise RuntimeError(f"graph benchmark: no result within {timeout:.0f} s")
        finally:
            stop_processes(procs)


def inprocess_rate(config: str | Path, micro_actions: int, overrides: dict | None = None) -> float:
    run = InProcessRun(load_experiment_config(config, overrides))
    t0 = time.perf_counter()
    run.step_until(micro_actions)
    return micro_actions / (time.perf_counter() - t0)


def bench_graph(config: str | Path, micro_actions: int = 3000, repeats: int = 2,
                pingpong_count: int = 3000, overrides: dict | None = None, out=print) -> dict:
    """Graph vs in-process micro-actions/s vs a bare rclpy topic ping-pong between two processes,
    measured interleaved in this one command; the best of ``repeats`` of each (least disturbed by
    other load). Criterion (issue): 1/graph − 1/in-process ≤ 1.5 × the bare round-trip time."""
    from .pingpong import measure

    g, ip, rtt = [], [], []
    for r in range(repeats):
        rtt.append(measure(count=pingpong_count)["rtt_ms"] / 1e3)
        g.append(graph_rate(config, micro_actions, overrides))
        ip.append(inprocess_rate(config, micro_actions, overrides))
        out(f"repeat {r + 1}: graph {g[-1]:,.0f}/s  in-process {ip[-1]:,.0f}/s  "
            f"ping-pong {1 / rtt[-1]:,.0f} round trips/s ({rtt[-1] * 1e3:.3f} ms)")
    best_g, best_ip, best_rtt = max(g), max(ip), min(rtt)
    added = 1 / best_g - 1 / best_ip
    res = {"graph_rate": best_g, "inprocess_rate": best_ip, "roundtrip_s": best_rtt,
           "added_s": added, "ratio": added / best_rtt}
    out(f"best: graph {best_g:,.0f}/s, in-process {best_ip:,.0f}/s, bare round trip "
        f"{best_rtt * 1e3:.3f} ms -> the graph adds {added * 1e3:.3f} ms per micro-action = "
        f"{res['ratio']:.2f} x the round trip (target <= 1.5)")
    return res
