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
