"""``sagg bench riac``: ACTUATOR-RIAC micro-actions/s with the leaf table against the tree walk it
replaced, in one command, on the same seeded run, with a bit-identity check.

Two in-process runs of the same config and seed are stepped alternately, window by window (so a
burst of load on this shared machine hits both alike): ``table`` is the learner as it is
(:mod:`sagg_low_level.riac_leaves`); ``walk`` is the same learner with the action choice the table
replaced (:func:`walk_choice`, a Python walk down the region tree reading each compatible leaf's
interest). Both must produce the same samples bit for bit: the memory digests and the region trees'
split histories are compared at the end. Rates are given per wall second and per CPU second of this
process (``time.process_time``: less sensitive to other processes' load than the wall clock).
"""
from __future__ import annotations

import os
import time
import types
from pathlib import Path

import numpy as np

from sagg_bringup.inprocess.experiment import InProcessRun
from sagg_bringup.graph.setups import load_experiment_config


def walk_compatible(tree, alpha: np.ndarray, n: int) -> list:
    """The leaves of ``tree`` compatible with the context ``alpha`` (its first ``n`` coordinates),
    found as ``_riac_choice`` found them before the leaf table: descend by α at α-splits, take both
    children at Δα-splits, depth first from the right child. The reference the table is tested
    against."""
    found = []
    stack = [tree.root]
    while stack:
        r = stack.pop()
        if r.children is None:
            found.append(r)
        elif r.split_dim < n:
            stack.append(r.children[0] if alpha[r.split_dim] < r.split_value else r.children[1])
        else:
            stack.extend(r.children)
    return found


def walk_choice(self) -> np.ndarray:
    """``EvolvingContextLearner._riac_choice`` as it was before the leaf table (reference)."""
    if self.rng.random() < self.p["riac.p_random"] or len(self.riac_tree.leaves()) < 2:
        return self._random_step()
    n = self.robot.n
    alpha = np.clip(self.alpha, self.robot.lower, self.robot.upper)
    found = walk_compatible(self.riac_tree, alpha, n)
    it = np.array([r.interest for r in found])
    w = it - it.min()
    probs = np.full(len(found), 1.0 / len(found)) if w.sum() <= 0 else w / w.sum()
    region = found[int(self.rng.choice(len(found), p=probs))]
    return self.rng.uniform(region.lower[n:], region.upper[n:])


class _PlainTree:
    """Stands in for the leaf table in the reference run: points go straight to the tree."""

    def __init__(self, learner):
        self.learner = learner

    def add(self, point, value):
        return self.learner.riac_tree.add(point, value)


def use_walk(learner) -> None:
    """Switch ``learner`` (an ACTUATOR-RIAC EvolvingContextLearner) to the reference walk."""
    plain = _PlainTree(learner)
    learner._riac_choice = types.MethodType(walk_choice, learner)
    learner._riac_leaves = lambda: plain


def bench_riac(config: str | Path, micro_actions: int = 60_000, window: int = 5_000,
               overrides: dict | None = None, out=print) -> dict:
    """Step a ``walk`` and a ``table`` ACTUATOR-RIAC run of ``config`` alternately by ``window``
    micro-actions up to ``micro_actions``; print each window's rates and the table/walk ratio, then
    the bit-identity check. Returns the rows and the check."""
    ov = dict(overrides or {})
    ov["strategy"] = "actuator-riac"
    cfg = load_experiment_config(config, ov)
    runs = {"walk": InProcessRun(cfg), "table": InProcessRun(cfg)}
    use_walk(runs["walk"].learner)
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    bp = cfg["sagg_sim_bridge"]
    out(f"ACTUATOR-RIAC, {config}: {bp['arm.dof']} DOF {bp['arm.mode']}, seed {cfg['sagg_learner']['seed']}, "
        f"load average {load:.2f} on {cores} cores at start")
    out(f"{'micro-actions':>14} {'leaves':>7} {'walk /s':>9} {'table /s':>9} {'ratio':>6} "
        f"{'walk /CPU-s':>12} {'table /CPU-s':>13} {'ratio':>6}")
    rows = []
    total = {k: [0.0, 0.0] for k in runs}
    done = 0
    while done < micro_actions:
        target = min(done + window, micro_actions)
        rate = {}
        for name, run in runs.items():
            w0, c0 = time.perf_counter(), time.process_time()
            run.step_until(target)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            total[name][0] += wall
            total[name][1] += cpu
            rate[name] = ((target - done) / wall, (target - done) / max(cpu, 1e-9))
        leaves = len(runs["table"].learner.riac_tree.leaves())
        row = {"micro_actions": target, "leaves": leaves, "walk_rate": rate["walk"][0],
               "table_rate": rate["table"][0], "walk_cpu_rate": rate["walk"][1],
               "table_cpu_rate": rate["table"][1]}
        rows.append(row)
        out(f"{target:>14,} {leaves:>7} {rate['walk'][0]:>9,.0f} {rate['table'][0]:>9,.0f} "
            f"{rate['table'][0] / rate['walk'][0]:>6.2f} {rate['walk'][1]:>12,.0f} {rate['table'][1]:>13,.0f} "
            f"{rate['table'][1] / rate['walk'][1]:>6.2f}")
        done = target
    whole = {k: (micro_actions / v[0], micro_actions / v[1]) for k, v in total.items()}
    out(f"{'whole run':>14} {'':>7} {whole['walk'][0]:>9,.0f} {whole['table'][0]:>9,.0f} "
        f"{whole['table'][0] / whole['walk'][0]:>6.2f} {whole['walk'][1]:>12,.0f} {whole['table'][1]:>13,.0f} "
        f"{whole['table'][1] / whole['walk'][1]:>6.2f}")
    lw, lt = runs["walk"].learner, runs["table"].learner
    same = {"memory_digest": lw.memory.digest() == lt.memory.digest(),
            "riac_splits": lw.riac_tree.splits == lt.riac_tree.splits,
            "goal_tree_splits": runs["walk"].generator.tree.splits == runs["table"].generator.tree.splits}
    out(f"bit-identical: memory digest {'same' if same['memory_digest'] else 'DIFFERENT'} "
        f"({lt.memory.digest()[:16]}...), RIAC splits {'same' if same['riac_splits'] else 'DIFFERENT'} "
        f"({len(lt.riac_tree.splits)}), goal-tree splits {'same' if same['goal_tree_splits'] else 'DIFFERENT'}; "
        f"load average {os.getloadavg()[0]:.2f} at the end")
    return {"rows": rows, "whole": whole, "identical": same}
