"""sagg against the peer implementation (explauto 1.4) on the same arm, the same test goals, in one command::

    python -m sagg_lab.peer --peer-python /path/to/peer-venv/bin/python \\
        [--config config/arm7_ratio15.yaml] [--seeds 3] [--points 5000 20000] [--out DIR]

The peer's published numbers come from another machine, and speeds measured on two machines do
not compare. Here, per task space (the config's and [-2,2]²) and seed, the peer
(nearest-neighbour goal babbling, its 'tree' and 'random' interest models; lab/peer_explauto.py run
under ``--peer-python``) and sagg's SAGG-RIAC in both contexts (``sagg experiment``'s in-process
run) learn one after the other, noise-free; the table gives the mean test error at each point
(mean ± std over seeds, the same 100 test goals for all) and the learning rate (queries = forward
queries = micro-actions per wall second, evaluation excluded), with each rate's ratio to the peer's
tree in the same command. Before learning, the peer's forward kinematics is checked against
sagg's arm on random postures (the largest tip difference is printed; above 1e-9 the command stops).

The peer's venv (explauto 1.4 needs setuptools < 58 to install and NumPy 1.x)::

    python3.11 -m venv /tmp/peervenv
    /tmp/peervenv/bin/pip install "setuptools<58" wheel "numpy<2" "scipy<1.14" "scikit-learn<1.6" matplotlib
    /tmp/peervenv/bin/pip install --no-build-isolation --no-deps explauto==1.4.0

The peer's evaluation is its own one-shot reach (the inverse prediction of the goal, one forward
query); sagg's is its own (closed-loop reaching from rest in the evolving context, one experiment in
the fixed one), as each would be used.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from sagg_common.params import ConfigError
from sagg_common.rng import stream
from sagg_sim_bridge.arm import ArmSim, reachable_area, test_goals
from sagg_sim_bridge.params import arm_spec_from_params

from sagg_bringup.graph.setups import load_experiment_config, run_experiment
from .quality import context_overrides

PEER_SCRIPT = Path(__file__).with_name("peer_explauto.py")
INTERESTS = ("tree", "random")
CONTEXTS = ("evolving", "fixed")


def arm_of(config: str | Path, overrides: dict) -> tuple:
    """(arm spec, learner parameters) of ``config``; ConfigError unless the peer's arm can be the
    same: planar, every joint (base included) within the same symmetric limit."""
    c = load_experiment_config(config, overrides)
    spec = arm_spec_from_params(c["sagg_sim_bridge"])
    if spec.base_limit != spec.joint_limit:
        raise ConfigError(f"the peer's arm has one joint limit for every joint; {config} has base_limit "
                          f"{spec.base_limit} and joint_limit {spec.joint_limit}")
    return spec, c["sagg_learner"]


def run_peer(python: str, spec, lower, upper, goals, points, seed: int, interest: str, angles) -> dict:
    """One peer run (lab/peer_explauto.py under ``python``): errors at ``points``, queries/s, the
    tips of ``angles``."""
    job = {"dofs": spec.dof, "joint_limit": spec.joint_limit, "length_ratio": spec.link_ratio,
           "s_mins": list(lower), "s_maxs": list(upper), "points": list(points), "seed": seed,
           "interest": interest, "test_goals": np.asarray(goals).tolist(), "check_angles": angles.tolist()}
    r = subprocess.run([python, str(PEER_SCRIPT)], input=json.dumps(job), capture_output=True, text=True,
                       env={**os.environ, "MPLBACKEND": "Agg"})
    if r.returncode != 0:
        raise RuntimeError(f"the peer failed ({python} {PEER_SCRIPT}):\n{r.stderr[-2000:]}")
    return json.loads(r.stdout)


def stats(values) -> str:
    v = np.asarray(values, dtype=float)
    return f"{v.mean():.4f} ± {v.std(ddof=1) if len(v) > 1 else 0.0:.4f}"


def compare(config: str, python: str, seeds: int, points, wide, out_dir: Path | None, out=print) -> dict:
    """Run everything (module docstring); print and return {space: {column: [per-seed results]}}."""
    points = sorted(int(p) for p in points)
    spec, lp = arm_of(config, {})
    if not spec.link_ratio:
        raise ConfigError(f"{config}: the peer's links decrease by a ratio; set arm.link_ratio")
    sim = ArmSim(spec, seed=0)
    angles = stream(0, "peer_check").uniform(sim.lower, sim.upper, size=(50, spec.dof))
    spaces = {"config": (list(lp["task_space.lower"]), list(lp["task_space.upper"])),
              "wide": (list(wide[:2]), list(wide[2:]))}
    eval_every = math.gcd(*points)
    out(f"peer comparison: {config}, {seeds} seeds, points {points}, load average "
        f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    results: dict = {}
    for space, (lo, hi) in spaces.items():
        lower, upper = np.asarray(lo, float), np.asarray(hi, float)
        goals = test_goals(spec, lower, upper, n=lp["eval.goals"], seed=lp["eval.seed"],
                           area=reachable_area(spec, lower, upper, seed=lp["eval.seed"]))
        cols = results[space] = {}
        for seed in range(seeds):
            for interest in INTERESTS:
                r = run_peer(python, spec, lo, hi, goals, points, seed, interest, angles)
                gap = float(np.abs(np.asarray(r.pop("check_tips")) - sim.tip_positions(angles)).max())
                if gap > 1e-9:
                    raise RuntimeError(f"the peer's arm is not sagg's: tips differ by up to {gap:g}")
                cols.setdefault(f"peer {interest}", []).append(r)
                out(f"  {space:6} seed {seed} peer {interest:6}: " + ", ".join(
                    f"{p}: {r['errors'][str(p)]:.4f}" for p in points)
                    + f"; {r['queries_per_second']:,.0f} queries/s (kinematics checked: {gap:.1e})")
            for context in CONTEXTS:
                ov = {**context_overrides(context, {}), "task_space.lower": lo, "task_space.upper": hi}
                d = None if out_dir is None else out_dir / space / context / f"seed-{seed}"
                res = run_experiment(config, "sagg-riac", seed, points[-1], eval_every, d, progress=False,
                                     overrides=ov)
                errs = {str(c["micro_actions"]): c["mean_error"] for c in res["curve"]}
                r = {"errors": {str(p): errs[str(p)] for p in points},
                     "queries_per_second": res["micro_actions_per_second"]}
                cols.setdefault(f"sagg-riac {context}", []).append(r)
                out(f"  {space:6} seed {seed} sagg-riac {context:8}: " + ", ".join(
                    f"{p}: {r['errors'][str(p)]:.4f}" for p in points)
                    + f"; {r['queries_per_second']:,.0f} queries/s")
    out(table(results, points))
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "peer.json").write_text(json.dumps(results, indent=1))
        (out_dir / "peer.md").write_text(table(results, points) + "\n")
    return results


def table(results: dict, points) -> str:
    lines = []
    for space, cols in results.items():
        names = list(cols)
        tree = np.mean([r["queries_per_second"] for r in cols["peer tree"]])
        lines += ["", f"Y = {space}: mean test error (mean ± std over seeds), learning rate", "",
                  "| | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for p in points:
            lines.append(f"| {p} queries | " + " | ".join(stats([r["errors"][str(p)] for r in cols[n]])
                                                        for n in names) + " |")
        rates = [np.mean([r["queries_per_second"] for r in cols[n]]) for n in names]
        lines.append("| queries/s | " + " | ".join(f"{q:,.0f}" for q in rates) + " |")
        lines.append("| rate / peer tree's | " + " | ".join(f"{q / tree:.2f}" for q in rates) + " |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.peer", description=__doc__.split("\n\n")[0])
    ap.add_argument("--peer-python", required=True, help="the interpreter of a venv with explauto 1.4")
    ap.add_argument("--config", default="config/arm7_ratio15.yaml")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--points", type=int, nargs="+", default=[5000, 20000])
    ap.add_argument("--wide", type=float, nargs=4, default=[-2.0, -2.0, 2.0, 2.0], metavar=("XLO", "YLO", "XHI", "YHI"))
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    compare(a.config, a.peer_python, a.seeds, a.points, a.wide, a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
