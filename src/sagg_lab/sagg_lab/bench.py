"""``sagg bench speed``: in-process micro-actions per second against stored samples.

Costs are compared within one command (ratios against the smallest memory size), never against
numbers from another run: these machines are noisy.
"""
from __future__ import annotations

import cProfile
import io
import os
import pstats
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from sagg_common.rng import stream
from sagg_low_level.memory import SampleMemory

from sagg_bringup.inprocess.arm_params import NODES, graph_params, load_graph_config
from sagg_bringup.inprocess.experiment import InProcessRun
from sagg_bringup.graph.params_files import run_values, write_params_file
from sagg_bringup.graph.processes import NodeGroup, node_processes
from sagg_bringup.graph.setups import load_experiment_config
from .pingpong import measure


def babbling_samples(run: InProcessRun, size: int, seed: int = 0, period: int = 200):
    """``size`` samples of motor babbling: random walks of the joints from rest (steps uniform in
    ±explore_amplitude, back to rest every ``period`` steps), all walks stepped together and their
    tips computed with the simulator's batched kinematics. Cheap and representative of the samples
    a run accumulates. Returns (alpha, delta_alpha, delta_y)."""
    sim, learner = run.sim, run.learner
    rng = stream(seed, "bench_prefill")
    n = sim.n_joints
    amp = learner.p["explore_amplitude"]
    walks = -(-size // period)
    path = np.empty((period + 1, walks, n))
    path[0] = sim.rest
    for t in range(period):
        path[t + 1] = np.clip(path[t] + rng.uniform(-amp, amp, (walks, n)), sim.lower, sim.upper)
    tips = sim.tip_positions(path.reshape(-1, n)).reshape(period + 1, walks, -1)
    # walk by walk, in time order (the order a run stores them)
    alpha = path[:-1].transpose(1, 0, 2).reshape(-1, n)[:size]
    dalpha = np.diff(path, axis=0).transpose(1, 0, 2).reshape(-1, n)[:size]
    dy = np.diff(tips, axis=0).transpose(1, 0, 2).reshape(walks * period, -1)[:size]
    return alpha, dalpha, dy


def prefill(run: InProcessRun, size: int, seed: int = 0) -> None:
    """Fill the learner's memory with ``size`` babbling samples (``babbling_samples``)."""
    add = run.learner.memory.add
    for a, da, dy in zip(*babbling_samples(run, size, seed)):
        add(a, da, dy)


def _sample_bytes(mem) -> dict:
    """Bytes per stored sample, measured from the memory's arrays: ``held`` = everything the
    memory allocates (sample arrays with spare capacity, kd index, buffer, caches) / samples;
    ``data`` = the (α, Δα, Δy) rows themselves."""
    n = len(mem)
    data = (mem.alpha.nbytes + mem.delta_alpha.nbytes + mem.delta_y.nbytes) / n
    return {"held": mem.nbytes / n, "data": data}


def bench_speed(config: str | Path, dofs=(7, 15, 30), modes=("kinematic",),
                sizes=(10_000, 100_000, 1_000_000), measure: int = 2000,
                strategies=("sagg-riac", "sagg-random", "actuator-random", "actuator-riac"),
                graph: bool = True, graph_micro_actions: int = 2000, profile: int = 0,
                graph_config: str | Path = "config/arm8.yaml", repeats: int = 1,
                out=print) -> dict:
    """In-process micro-actions per second after prefilling the memory to each size, for every
    (dof, mode, strategy); the cost ratio compares each size with the smallest one of the same
    row group, in this same command. The memory of each (dof, size) is built once (samples added
    one by one, as a run does), saved as .npz and loaded (index rebuilt identically) for each
    strategy. Each row is the best (lowest cost) of ``repeats`` timed windows on fresh runs, the
    sizes interleaved. Bytes per sample are measured on the memory as built by adding the samples
    one by one (a loaded memory holds no spare capacity). With ``graph``, also the graph vs
    in-process vs bare rclpy ping-pong line (``bench_graph``). With ``profile`` > 0, the top
    functions (by own time) of an extra, untimed window of the last row: where the time goes."""


    sizes = sorted(sizes)
    rows = []
    out(f"{'dof':>4} {'mode':>10} {'strategy':>16} {'stored':>9} {'micro-actions/s':>16} "
        f"{'us/micro-action':>16} {'cost ratio':>11} {'bytes/sample held':>18} {'data':>6}")
    prof_text = ""
    with tempfile.TemporaryDirectory(prefix="sagg-speed-") as tmp:
        for dof in dofs:
            for mode in modes:
                cfgs = {st: load_experiment_config(config, {"arm.dof": dof, "arm.mode": mode,
                                                            "strategy": st}) for st in strategies}
                files, nbytes_of = {}, {}
                for size in sizes:
                    run = InProcessRun(cfgs[strategies[0]])
                    prefill(run, size)  # one add per sample, as a run stores them
                    nbytes_of[size] = _sample_bytes(run.learner.memory)
                    files[size] = Path(tmp) / f"mem-{dof}-{mode}-{size}.npz"
                    run.learner.memory.save(files[size])
                    del run
                for st in strategies:
                    best: dict[int, float] = {}
                    for rep in range(repeats):  # interleaved: a load burst hits every size alike
                        for size in sizes:
                            run = InProcessRun(cfgs[st])
                            run.learner.memory = SampleMemory.load(files[size])
                            run.step_until(50)  # warm up caches, code paths, the first growth
                            start_ma = run.learner.micro_actions
                            t0 = time.perf_counter()
                            run.step_until(start_ma + measure)
                            best[size] = min(best.get(size, float("inf")),
                                             (time.perf_counter() - t0) / measure)
                            last = (dof, mode, st, size) == (dofs[-1], modes[-1], strategies[-1],
                                                             sizes[-1])
                            if profile and last and rep == repeats - 1:
                                prof = cProfile.Profile()  # an extra, untimed window
                                prof.enable()
                                run.step_until(start_ma + 2 * measure)
                                prof.disable()
                                buf = io.StringIO()
                                pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(profile)
                                prof_text = (f"profile of {measure} more micro-actions of the last "
                                             f"row ({dof} DOF {mode} {st}, {size} stored; cProfile "
                                             f"inflates Python-call-heavy code):\n" + buf.getvalue())
                            del run
                    base = best[sizes[0]]
                    for size in sizes:
                        cost = best[size]
                        row = {"dof": dof, "mode": mode, "strategy": st, "stored": size,
                               "rate": 1 / cost, "us_per_micro_action": cost * 1e6,
                               "cost_ratio": cost / base, "bytes_per_sample": nbytes_of[size]["held"],
                               "data_bytes_per_sample": nbytes_of[size]["data"]}
                        rows.append(row)
                        out(f"{dof:>4} {mode:>10} {st:>16} {size:>9} {1 / cost:>16,.0f} "
                            f"{cost * 1e6:>16.1f} {cost / base:>11.2f} "
                            f"{nbytes_of[size]['held']:>18.0f} {nbytes_of[size]['data']:>6.0f}")
    worst = max(r["cost_ratio"] for r in rows)
    out(f"worst cost ratio (largest / smallest size, same dof, mode, strategy): {worst:.2f} "
        f"(criterion <= 2)")
    if prof_text:
        out(prof_text)
    res = {"rows": rows, "worst_cost_ratio": worst}
    if graph:
        res["graph"] = bench_graph(graph_config, graph_micro_actions, repeats=1, out=out)
    return res


def graph_rate(config: str | Path, micro_actions: int, overrides: dict | None = None,
               timeout: float = 900.0) -> float:
    """Micro-actions/s of the three node processes in lockstep, from the learner's own log line
    ("N micro-actions in T s", timed from its first command to its last observation); nothing
    else runs (no recorder, no evaluation)."""
    full = load_graph_config(config, overrides)
    params = graph_params(full, micro_actions, "lockstep")
    params["sagg_learner"]["min_sample_subscribers"] = 0  # nobody records here
    params["sagg_goal_generator"]["min_goal_subscribers"] = 0
    with tempfile.TemporaryDirectory(prefix="sagg-bench-") as tmp:
        tmp = Path(tmp)
        write_params_file(tmp / "params.yaml", params)
        nodes = NodeGroup(node_processes(NODES, tmp))
        learner_log = tmp / "learner.log"
        try:
            nodes.start(tmp / "params.yaml", run_values(params))  # (the budget: max_micro_actions)
            end = time.perf_counter() + timeout
            while time.perf_counter() < end:
                m = re.search(r"\((\d+) micro-actions in ([\d.]+) s", learner_log.read_text(errors="replace"))
                if m:
                    return int(m.group(1)) / float(m.group(2))
                nodes.check()
                time.sleep(0.05)
            raise RuntimeError(f"graph benchmark: no result within {timeout:.0f} s")
        finally:
            nodes.stop()


def inprocess_rate(config: str | Path, micro_actions: int, overrides: dict | None = None) -> float:
    run = InProcessRun(load_experiment_config(config, overrides))
    t0 = time.perf_counter()
    run.step_until(micro_actions)
    return micro_actions / (time.perf_counter() - t0)


def bench_graph(config: str | Path, micro_actions: int = 3000, repeats: int = 2,
                pingpong_count: int = 3000, overrides: dict | None = None, out=print) -> dict:
    """Graph vs in-process micro-actions/s vs a bare rclpy topic ping-pong between two processes,
    measured interleaved in this one command; the best of ``repeats`` of each (least disturbed by
    other load). Criterion: 1/graph − 1/in-process ≤ 1.5 × the bare round-trip time.

    Also the *contract floor*: the lockstep exchange of the hardware contract (a command out, a
    joint state and a task point back; raw bytes, as our nodes send them) between two processes
    that do no work at all (``pingpong --pattern lockstep``). No lockstep graph that speaks the
    contract can add less than this per micro-action, so ``floor / round trip`` is the smallest
    ratio the criterion could ever show on this machine, and ``added − floor`` is what our nodes
    themselves add. And *ideal nodes*: the same exchange with the echo side computing for the
    in-process run's whole time per micro-action (a busy loop) before it answers: nodes with no
    overhead at all doing the same work, serialized as lockstep serializes it (a little
    pessimistic: in the graph the goal generator's share runs on another core)."""


    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    out(f"load average {load:.2f} on {cores} cores" + (
        ": the machine is busy, expect the graph (three processes) to suffer more than the "
        "in-process run; best of each over the repeats is kept" if load > 0.5 * cores else ""))
    g, ip, rtt, floor, ideal = [], [], [], [], []
    for r in range(repeats):
        rtt.append(measure(count=pingpong_count)["rtt_ms"] / 1e3)
        floor.append(measure(count=pingpong_count, raw=True, pattern="lockstep")["rtt_ms"] / 1e3)
        g.append(graph_rate(config, micro_actions, overrides))
        ip.append(inprocess_rate(config, micro_actions, overrides))
        work = 1 / ip[-1]
        ideal.append(measure(count=pingpong_count, raw=True, pattern="lockstep", work=work)["rtt_ms"] / 1e3 - work)
        out(f"repeat {r + 1}: graph {g[-1]:,.0f}/s  in-process {ip[-1]:,.0f}/s  "
            f"ping-pong {1 / rtt[-1]:,.0f} round trips/s ({rtt[-1] * 1e3:.3f} ms)  "
            f"contract floor {floor[-1] * 1e3:.3f} ms  ideal nodes add {ideal[-1] * 1e3:.3f} ms")
    best_g, best_ip, best_rtt, best_floor, best_ideal = max(g), max(ip), min(rtt), min(floor), min(ideal)
    added = 1 / best_g - 1 / best_ip
    res = {"graph_rate": best_g, "inprocess_rate": best_ip, "roundtrip_s": best_rtt,
           "added_s": added, "ratio": added / best_rtt, "floor_s": best_floor,
           "floor_ratio": best_floor / best_rtt, "nodes_s": added - best_floor,
           "ideal_added_s": best_ideal, "ideal_ratio": best_ideal / best_rtt}
    out(f"best: graph {best_g:,.0f}/s, in-process {best_ip:,.0f}/s, bare round trip "
        f"{best_rtt * 1e3:.3f} ms -> the graph adds {added * 1e3:.3f} ms per micro-action = "
        f"{res['ratio']:.2f} x the round trip (target <= 1.5)")
    out(f"contract floor (command out, joint state + task point back, no work): {best_floor * 1e3:.3f} ms "
        f"= {res['floor_ratio']:.2f} x the round trip; our nodes add {res['nodes_s'] * 1e3:.3f} ms on top of it "
        f"({added / best_floor:.2f} x the floor)")
    out(f"ideal nodes (no overhead, the in-process work per micro-action computed in the lockstep exchange): "
        f"add {best_ideal * 1e3:.3f} ms per micro-action = {res['ideal_ratio']:.2f} x the round trip")
    return res
