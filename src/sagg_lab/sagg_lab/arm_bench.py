"""Benchmark of ArmSim.command (micro-actions per second), ROS-free.

    python -m sagg_lab.arm_bench            # 7 and 15 DOF, both modes
    python -m sagg_lab.arm_bench 8 dynamic 2000

Each micro-action moves every joint by U(-step, step) rad from the previous target (a clipped
random walk from the rest posture, drawn before timing). Besides the command rate the result
gives the rate of the bare MuJoCo call(s) one command needs (mj_kinematics, or the mean number
of mj_step per settle), so the Python overhead shows as a ratio rather than a timed assertion.
"""
from __future__ import annotations

import math
import sys
import time

import mujoco
import numpy as np

from sagg_sim_bridge.arm import ArmSim, ArmSpec


def _targets(sim: ArmSim, n: int, step: float, rng: np.random.Generator) -> np.ndarray:
    out = np.empty((n, sim.n_joints))
    a = sim.rest.copy()
    for i in range(n):
        a = np.clip(a + rng.uniform(-step, step, sim.n_joints), sim.lower, sim.upper)
        out[i] = a
    return out


def bench_arm(dof: int, mode: str, n: int, seed: int = 0, step: float = 0.05,
              motor_noise: float = 0.0, repeats: int = 3) -> dict:
    """Time n ArmSim.command calls (best of `repeats` runs); returns micro-actions/s and context."""
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if not isinstance(repeats, int) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")
    if not step > 0:
        raise ValueError(f"step must be > 0, got {step!r}")
    spec = ArmSpec(dof=dof, mode=mode, motor_noise=motor_noise)
    sim = ArmSim(spec, seed)
    targets = _targets(sim, n, step, np.random.default_rng(seed))
    sim.reset()
    # warm-up (first calls touch fresh memory)
    for t in targets[: min(n, 20)]:
        sim.command(t)
    cmd = sim.command
    elapsed = math.inf
    steps = unsettled = 0
    for _ in range(repeats):  # best of `repeats` runs: the machine is shared, take the least disturbed
        sim.reset()
        steps = unsettled = 0
        t0 = time.perf_counter()
        if mode == "dynamic":
            for t in targets:
                cmd(t)
                steps += sim.last_settle_steps
                unsettled += not sim.last_settled
        else:
            for t in targets:
                cmd(t)
        elapsed = min(elapsed, time.perf_counter() - t0)
    rate = n / elapsed
    # bare MuJoCo cost of what one command does
    m, d = sim.model, sim.data
    reps = max(200, min(20000, n))
    per_call = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        if mode == "dynamic":
            for _ in range(reps // 10):
                mujoco.mj_step(m, d, nstep=10)
            per_call = min(per_call, (time.perf_counter() - t0) / ((reps // 10) * 10))
        else:
            for _ in range(reps):
                mujoco.mj_kinematics(m, d)
            per_call = min(per_call, (time.perf_counter() - t0) / reps)
    mean_steps = steps / n if mode == "dynamic" else 0.0
    bare = 1.0 / (per_call * mean_steps) if mode == "dynamic" else 1.0 / per_call
    return {
        "dof": dof,
        "mode": mode,
        "n": n,
        "motor_noise": motor_noise,
        "seconds": elapsed,
        "rate": rate,                      # micro-actions (command calls) per second
        "us_per_command": 1e6 / rate,
        "mean_settle_steps": mean_steps,   # dynamic only
        "unsettled": unsettled,            # dynamic: commands that hit max_settle_steps
        "bare_mujoco_rate": bare,          # commands/s if only the MuJoCo calls cost anything
        "overhead_ratio": bare / rate,     # >= 1; Python overhead factor
    }


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv:
        cases = [(int(argv[0]), argv[1], int(argv[2]) if len(argv) > 2 else 5000)]
    else:
        cases = [(7, "kinematic", 50000), (15, "kinematic", 50000), (7, "dynamic", 3000), (15, "dynamic", 3000)]
    print(f"{'dof':>4} {'mode':>10} {'n':>7} {'cmd/s':>10} {'us/cmd':>8} {'steps':>6} {'bare/s':>10} {'ratio':>6}")
    for dof, mode, n in cases:
        r = bench_arm(dof, mode, n)
        print(f"{r['dof']:>4} {r['mode']:>10} {r['n']:>7} {r['rate']:>10.0f} {r['us_per_command']:>8.2f} "
              f"{r['mean_settle_steps']:>6.1f} {r['bare_mujoco_rate']:>10.0f} {r['overhead_ratio']:>6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
