"""The floor of each part of a micro-action, measured alone::

    python -m sagg_lab.floors --config config/arm7_ratio15.yaml --micro-actions 20000 [--repeat 3000]

One in-process run learns to ``--micro-actions``; then each part of a micro-action (an experiment
in the fixed context) is called alone, ``--repeat`` times in a tight loop on the run's own state (its memory,
tree and arm; best of 3 batches, CPU seconds of this process), so that the distance between what a
part costs inside the learning loop (``python -m sagg_lab.time_parts``) and what it costs at the
least is visible:

* the arm's forward kinematics (one ``command`` of the simulator: MuJoCo kinematics + clipping);
* one neighbour search (``memory.neighbours``, k of the learner, at the memory's size);
* one least-squares Jacobian and one reaching step (the compiled routines, at this k, n, m);
* one point into the goal generator's region tree (``GoalGenerator.report`` of a reached point;
  the tree grows by the repeats, a split included when one falls due);
* one sample into the memory (``SampleMemory.add``, index builds included when one falls due);
* one request/answer of the learner's coroutine protocol (a generator ``send`` and ``yield``,
  nothing else: the floor of the protocol).

In the fixed context (``--set context=fixed``, or a synergy set-up): one experiment (the set-up's
``execute``), the outcome search (the l nearest outcomes of a goal), the θ searches (the m nearest
θ of each of the l), the least-spread set, the local inverse (compiled least squares and
pseudo-inverse), one goal choice (``GoalGenerator.next_goal``), a tree point and a memory add.

The parts that mutate (tree, memory) run last, on the run's state, which is not learned further.
Prints one table (µs per call) and the load average.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from sagg_common.params import parse_set
from sagg_common.report_kinds import KIND_REACHED
from sagg_low_level import compiled
from sagg_low_level.local_model import desired_displacement

from sagg_low_level.fixed_context import least_spread_set, local_inverse

from sagg_bringup.graph.setups import in_process_run
from sagg_bringup.inprocess.experiment import InProcessRun


def best_of(fn, repeat: int, batches: int = 3) -> float:
    """Least CPU seconds per call of ``fn()`` over ``batches`` batches of ``repeat`` calls."""
    best = float("inf")
    for _ in range(batches):
        t = time.process_time()
        for _ in range(repeat):
            fn()
        best = min(best, (time.process_time() - t) / repeat)
    return best


def floors(run: InProcessRun, repeat: int) -> list[tuple[str, float]]:
    learner, sim, gen, mem = run.learner, run.sim, run.generator, run.learner.memory
    alpha, y = learner.alpha.copy(), learner.y.copy()
    target = np.clip(alpha + 0.01, learner.robot.lower, learner.robot.upper)
    idx = mem.neighbours(alpha, learner.k)
    jac = compiled.jacobian(mem.delta_alpha, mem.delta_y, idx, learner.p["jacobian_rcond"])
    dy = desired_displacement(y, y + 1.0, learner.v)
    lo, up, rcond, damping = learner.robot.lower, learner.robot.upper, learner.p["pinv_rcond"], learner.damping
    clamp = learner.p["reach_limits"] == "clamp"

    def protocol():
        while True:
            yield None

    coro = protocol()
    next(coro)
    rows = [
        ("forward kinematics (simulator command)", best_of(lambda: sim.command(target), repeat)),
        (f"neighbour search (k {learner.k}, {len(mem)} samples)",
         best_of(lambda: mem.neighbours(alpha, learner.k), repeat)),
        (f"least-squares Jacobian ({len(idx)} x {jac.shape[1]}, m {jac.shape[0]})",
         best_of(lambda: compiled.jacobian(mem.delta_alpha, mem.delta_y, idx, learner.p["jacobian_rcond"]), repeat)),
        ("reaching step", best_of(lambda: compiled.reach_step(jac, dy, alpha, lo, up, rcond, damping, clamp), repeat)),
        ("coroutine request/answer", best_of(lambda: coro.send(None), repeat)),
    ]
    rng = np.random.default_rng(0)
    pts = y + rng.normal(0.0, 0.01, (3 * repeat * 3, len(y)))
    it = iter(pts)
    rows.append(("region tree point (GoalGenerator.report)",
                 best_of(lambda: gen.report(KIND_REACHED, next(it), 0.0), repeat)))
    da, zero = np.full(len(alpha), 1e-3), np.zeros(len(y))
    rows.append(("memory add", best_of(lambda: mem.add(alpha, da, zero), repeat)))
    return rows


def fixed_floors(run, repeat: int) -> list[tuple[str, float]]:
    """The parts of a fixed-context experiment alone (see the module docstring)."""
    learner, gen = run.learner, run.generator
    tn, ys = learner.by_theta.alpha, learner.by_y.alpha
    g = learner.by_y.alpha[len(learner) // 2] + 1e-3   # a goal in the memory's (rescaled) outcome units
    goal = g * learner.scale                            # ... and in task units
    seeds = learner.y_index.query(g[None], learner.l_nb)[0]
    sets = learner.theta_index.query(tn[seeds], learner.m_nb)
    best = sets[least_spread_set(sets, tn)]
    theta = learner.denorm_theta(tn[best[0]])
    p = learner.p
    rows = [
        ("experiment (the set-up's execute)", best_of(lambda: run.setup.execute(theta), repeat)),
        (f"outcome search (l {learner.l_nb}, {len(learner)} samples)",
         best_of(lambda: learner.y_index.query(g[None], learner.l_nb), repeat)),
        (f"θ searches (m {learner.m_nb} of each of the l, {tn.shape[1]}-D)",
         best_of(lambda: learner.theta_index.query(tn[seeds], learner.m_nb), repeat)),
        ("least-spread set", best_of(lambda: least_spread_set(sets, tn), repeat)),
        ("local inverse (compiled least squares + pseudo-inverse)",
         best_of(lambda: local_inverse(tn[best], ys[best], g, p["jacobian_rcond"], p["pinv_rcond"]), repeat)),
        ("goal choice (GoalGenerator.next_goal)", best_of(gen.next_goal, repeat)),
    ]
    rng = np.random.default_rng(0)
    pts = goal + rng.normal(0.0, 0.01, (3 * repeat * 3, len(goal)))
    it = iter(pts)
    rows.append(("region tree point (GoalGenerator.report)",
                 best_of(lambda: gen.report(KIND_REACHED, next(it), -0.5), repeat)))
    y0 = learner.by_y.delta_y[0].copy()   # an outcome in task units (the table keeps it there)
    rows.append(("memory add (both tables)", best_of(lambda: learner.add_sample(theta, y0), repeat)))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.floors", description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="config/arm7_ratio15.yaml")
    ap.add_argument("--strategy", default="sagg-riac")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--micro-actions", type=int, default=20000)
    ap.add_argument("--repeat", type=int, default=3000)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args(argv)
    run = in_process_run(a.config, dict(parse_set(a.set), strategy=a.strategy, seed=a.seed))
    run.step_until(a.micro_actions)
    print(f"{a.config} {a.strategy} seed {a.seed} at {a.micro_actions} micro-actions, {a.repeat} calls a batch")
    print("| part, alone | µs per call |")
    print("|---|---:|")
    parts = floors(run, a.repeat) if isinstance(run, InProcessRun) else fixed_floors(run, a.repeat)
    for label, s in parts:
        print(f"| {label} | {s * 1e6:.2f} |")
    print("load average (1, 5, 15 min): " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
