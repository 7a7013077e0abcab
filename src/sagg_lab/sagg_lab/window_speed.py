"""Learning speed by window, an older commit against this tree, in one command, with a bit-identity
check::

    python -m sagg_lab.window_speed --base <commit> --config config/arm15.yaml \\
        --strategies actuator-riac sagg-riac --micro-actions 200000 --window 20000 [--set NAME=VALUE]

Per strategy, two child processes learn the same seeded in-process run (any set-up, either context:
``--set context=fixed``), one from the base commit's sources (``git archive``), one from this tree's,
each importing its own sources first (checked). They are stepped alternately window by window (base,
new, base, new, ...: a burst of load on this shared machine hits both alike), learning only, no
evaluation. Per window: micro-actions (experiments in the fixed context) per wall second and per CPU
second of each child (``time.process_time``, less sensitive to other processes' load), and the
new/base ratios. At the end the memory digests (``memory`` or ``by_theta``), a digest of every goal
and the region counts must be equal.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from sagg_common.params import parse_set

from .base_tree import check_source, exported, pythonpath, repo_root

_CHILD = r"""
import hashlib, json, sys, time
import numpy as np
try:
    from sagg_bringup.graph.setups import in_process_run
except ImportError:  # a checkout from before the job sub-packages
    from sagg_bringup.setups import in_process_run
cfg, ov = sys.argv[1], json.loads(sys.argv[2])
run = in_process_run(cfg, ov)
import sagg_low_level
print(json.dumps({"source": sagg_low_level.__file__}), flush=True)
for line in sys.stdin:
    cmd = line.strip()
    if cmd == "end":
        learner = run.learner
        mem = learner.memory if getattr(learner, "memory", None) is not None else learner.by_theta
        goals = np.array([g.position for g in run.generator.goals], dtype=float)
        riac = getattr(learner, "riac_tree", None)
        print(json.dumps({"memory": mem.digest(), "samples": len(mem),
                          "goals": hashlib.sha256(goals.tobytes()).hexdigest()[:16], "n_goals": len(goals),
                          "goal_leaves": len(run.generator.tree.leaves()),
                          "riac_leaves": len(riac.leaves()) if riac is not None else 0}), flush=True)
        break
    c0, w0 = time.process_time(), time.perf_counter()
    run.step_until(int(cmd))
    riac = getattr(run.learner, "riac_tree", None)
    print(json.dumps({"cpu": time.process_time() - c0, "wall": time.perf_counter() - w0,
                      "leaves": len(riac.leaves()) if riac is not None else len(run.generator.tree.leaves())}),
          flush=True)
"""


class _Child:
    """One learning run in a subprocess importing ``src`` first."""

    def __init__(self, src: Path, config: str, overrides: dict):
        env = dict(os.environ, PYTHONPATH=pythonpath(src))
        self.proc = subprocess.Popen([sys.executable, "-c", _CHILD, config, json.dumps(overrides)], env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        check_source(self._read()["source"], src)

    def _read(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"child {self.proc.args[:2]} ended (exit code {self.proc.wait()})")
        return json.loads(line)

    def ask(self, cmd: str) -> dict:
        self.proc.stdin.write(cmd + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> dict:
        out = self.ask("end")
        self.proc.stdin.close()
        self.proc.wait()
        return out



def compare(base_src: Path, new_src: Path, config: str, overrides: dict, micro_actions: int, window: int,
            out=print, new_overrides: dict | None = None) -> dict:
    """Step a base and a new child alternately by ``window`` up to ``micro_actions``; print each
    window's rates and ratios and the bit-identity check. Returns the rows and the check.
    ``new_overrides``: more overrides for the new child only (a parameter's A/B on one tree; the
    check then says whether the parameter changes the run)."""
    kids = {"base": _Child(base_src, config, overrides),
            "new": _Child(new_src, config, dict(overrides, **(new_overrides or {})))}
    out("| micro-actions | leaves | base /s | new /s | ratio | base /CPU-s | new /CPU-s | ratio |")
    out("|---|---|---|---|---|---|---|---|")
    rows, tot, done = [], {k: [0.0, 0.0] for k in kids}, 0
    while done < micro_actions:
        target = min(done + window, micro_actions)
        r = {name: kid.ask(str(target)) for name, kid in kids.items()}
        n = target - done
        for name in kids:
            tot[name][0] += r[name]["wall"]
            tot[name][1] += r[name]["cpu"]
        b, w = r["base"], r["new"]
        row = {"micro_actions": target, "leaves": w["leaves"], "base_rate": n / b["wall"], "new_rate": n / w["wall"],
               "base_cpu_rate": n / max(b["cpu"], 1e-9), "new_cpu_rate": n / max(w["cpu"], 1e-9)}
        rows.append(row)
        out(f"| {target:,} | {w['leaves']} | {row['base_rate']:,.0f} | {row['new_rate']:,.0f} | "
            f"{row['new_rate'] / row['base_rate']:.2f} | {row['base_cpu_rate']:,.0f} | {row['new_cpu_rate']:,.0f} | "
            f"{row['new_cpu_rate'] / row['base_cpu_rate']:.2f} |")
        done = target
    whole = {k: (micro_actions / v[0], micro_actions / v[1], v[1]) for k, v in tot.items()}
    out(f"| whole run | | {whole['base'][0]:,.0f} | {whole['new'][0]:,.0f} | "
        f"{whole['new'][0] / whole['base'][0]:.2f} | "
        f"{whole['base'][1]:,.0f} | {whole['new'][1]:,.0f} | {whole['new'][1] / whole['base'][1]:.2f} |")
    cpu_ratios = sorted(r["new_cpu_rate"] / r["base_cpu_rate"] for r in rows)
    out("median of the windows' new/base ratios: "
        f"{float(np.median([r['new_rate'] / r['base_rate'] for r in rows])):.2f} "
        f"(wall), {float(np.median(cpu_ratios)):.2f} (CPU); windows where new is faster (CPU): "
        f"{sum(x > 1 for x in cpu_ratios)} of {len(cpu_ratios)}")
    ends = {name: kid.close() for name, kid in kids.items()}
    same = ends["base"] == ends["new"]
    out(f"CPU seconds: base {whole['base'][2]:.1f}, new {whole['new'][2]:.1f}; bit-identical: "
        f"{'yes' if same else 'NO'} (memory {ends['new']['memory'][:16]}..., {ends['new']['samples']} samples, "
        f"goals {ends['new']['goals']} ({ends['new']['n_goals']}), goal-tree leaves {ends['new']['goal_leaves']}, "
        f"RIAC leaves {ends['new']['riac_leaves']}" + ("" if same else f"; base {ends['base']}") + ")")
    return {"rows": rows, "whole": whole, "identical": same, "ends": ends}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.window_speed",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", required=True, help="git commit of the old code")
    ap.add_argument("--config", default="config/arm15.yaml")
    ap.add_argument("--strategies", nargs="+", default=["actuator-riac"])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--micro-actions", type=int, default=20000)
    ap.add_argument("--window", type=int, default=5000)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                    help="parameter override for both runs (e.g. context=fixed)")
    ap.add_argument("--set-new", action="append", default=[], metavar="NAME=VALUE",
                    help="parameter override for the new run only (with --base HEAD: a parameter's A/B)")
    a = ap.parse_args(argv)
    overrides, new_overrides = parse_set(a.set), parse_set(a.set_new)
    repo = repo_root()
    identical = True
    with exported(a.base, repo) as base_src:
        for strategy in a.strategies:
            print(f"\n{strategy}, {a.config}, seed {a.seed}, overrides {overrides}: base {a.base} vs this tree "
                  f"({repo}); load average {', '.join(f'{x:.2f}' for x in os.getloadavg())} at start")
            res = compare(base_src, repo / "src", a.config, dict(overrides, strategy=strategy, seed=a.seed),
                          a.micro_actions, a.window, new_overrides=new_overrides)
            identical = identical and res["identical"]
            print(f"load average {', '.join(f'{x:.2f}' for x in os.getloadavg())} at end")
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
