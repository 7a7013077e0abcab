"""Learning speed of the fixed-context learner, this tree against an older commit, in one
command: ``python -m sagg_lab.fixed_speed --base <commit>``.

The base commit's ``src/`` is exported with ``git archive`` into a temporary directory and run in a
subprocess whose ``PYTHONPATH`` puts it before the installed (editable) packages; this tree runs in
the same way from its own sources. Runs alternate (base, new, base, new, ...) so both see the same
machine load. Each run learns ``--queries`` experiments in-process (``SynergyRun``, no evaluation)
and reports queries per CPU second of the process (``time.process_time``, less sensitive to other
processes than wall time), queries per wall second, and the memory digest: with the same parameter
values the two must learn bit-identical memories (``--set`` applies to both, e.g. ``m=8`` = the
base's old default of m). ``--wide`` also runs every case in the task space [-2,2]² (as
``sagg bench quality``'s wide one); the load average is printed with every row.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from sagg_common.params import parse_set

from .base_tree import check_source, exported, pythonpath, repo_root

_CHILD = r"""
import json, sys, time
try:
    from sagg_bringup.graph.setups import in_process_run
except ImportError:
    try:  # a checkout from before the job sub-packages
        from sagg_bringup.setups import in_process_run
    except ImportError:  # a checkout from before the set-up registry
        from sagg_bringup.synergy_experiment import load_synergy_config, SynergyRun
        in_process_run = lambda c, o: SynergyRun(load_synergy_config(c, o))
cfg, strategy, seed, n, ov = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), json.loads(sys.argv[5])
run = in_process_run(cfg, dict(ov, context="fixed", strategy=strategy, seed=seed))
c0, w0 = time.process_time(), time.perf_counter()
run.step_until(n)
cpu, wall = time.process_time() - c0, time.perf_counter() - w0
import sagg_low_level
print(json.dumps({"cpu_rate": n / cpu, "wall_rate": n / wall, "digest": run.learner.by_theta.digest(),
                  "source": sagg_low_level.__file__}))
"""


def _run(src: Path, config: str, strategy: str, seed: int, n: int, overrides: dict) -> dict:
    env = dict(os.environ, PYTHONPATH=pythonpath(src))
    out = subprocess.run([sys.executable, "-c", _CHILD, config, strategy, str(seed), str(n), json.dumps(overrides)],
                         env=env, capture_output=True, text=True, check=True)
    res = json.loads(out.stdout.strip().splitlines()[-1])
    check_source(res["source"], src)
    return res



def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git commit of the old code")
    ap.add_argument("--config", default="config/arm7_ratio15.yaml")
    ap.add_argument("--strategies", nargs="+", default=["sagg-riac", "sagg-random"])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--queries", type=int, default=20000)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="parameter override for both (e.g. m=8 for bit-identity with the old default)")
    ap.add_argument("--wide", action="store_true", help="also in the task space [-2,2]^2")
    a = ap.parse_args(argv)
    overrides = parse_set(a.set)
    spaces = {"config": {}}
    if a.wide:
        spaces["wide"] = {"task_space.lower": [-2.0, -2.0], "task_space.upper": [2.0, 2.0]}
    repo = repo_root()
    with exported(a.base, repo) as base_src:
        print(f"base {a.base} vs this tree ({repo}), {a.config}, {a.queries} queries, overrides {overrides}, "
              f"load {os.getloadavg()[0]:.1f}")
        print("| Y | strategy | seed | base /CPU-s | new /CPU-s | ratio | base /s | new /s | ratio | same memory "
              "| load |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        tot = {"base": 0.0, "new": 0.0}
        for space, space_ov in spaces.items():
            for strategy in a.strategies:
                for seed in range(a.seeds):
                    ov = dict(overrides, **space_ov)
                    b = _run(base_src, a.config, strategy, seed, a.queries, ov)
                    n = _run(repo / "src", a.config, strategy, seed, a.queries, ov)
                    tot["base"] += a.queries / b["cpu_rate"]
                    tot["new"] += a.queries / n["cpu_rate"]
                    print(f"| {space} | {strategy} | {seed} | {b['cpu_rate']:,.0f} | {n['cpu_rate']:,.0f} | "
                          f"{n['cpu_rate'] / b['cpu_rate']:.2f} | {b['wall_rate']:,.0f} | {n['wall_rate']:,.0f} | "
                          f"{n['wall_rate'] / b['wall_rate']:.2f} | {b['digest'] == n['digest']} | "
                          f"{os.getloadavg()[0]:.1f} |", flush=True)
        print(f"whole: CPU seconds base {tot['base']:.1f}, new {tot['new']:.1f}, ratio {tot['base'] / tot['new']:.2f}; "
              f"load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
