"""What a prior from simulation is worth on an arm that differs from its model: robot error against
robot micro-actions with and without the prior, for calibration gaps 0, 1 and 2 times the default
test gap (sagg_sim_bridge/calibration.py). The simulated arm with the gap stands for the robot.

Per arm and seed s: a nominal simulated run of ``--prior-micro-actions`` (seed 100 + s) saved as a
model; then robot runs of seed s on the calibrated arm: without a prior, with it, and with it and its
region tree (the default gap only). Every run is the product's in-process experiment (graph runs
equal it); the evaluation is the run's own, on the calibrated arm. Output: ``OUT/prior_gap.json``
and a markdown table on stdout (mean ± std over seeds, Mann-Whitney and Welch per point).

    python -m sagg_lab.prior_gap --out DIR [--seeds 5] [--arms arm7_urdf arm6_mjcf]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from sagg_bringup.experiments.compare import pairwise_tests
from sagg_bringup.inprocess.experiment import load_arm_config, run_arm_experiment
from sagg_sim_bridge.arms import arm_spec_from_params
from sagg_sim_bridge.calibration import test_gap

POINTS = (0, 250, 500, 1000, 2000)
GAPS = (0.0, 1.0, 2.0)


def _errors(result: dict) -> dict[int, float]:
    return {int(c["micro_actions"]): float(c["mean_error"]) for c in result["curve"]}


def _gap_overrides(n: int, factor: float) -> dict:
    gap = test_gap(n, factor)
    return {"arm.calibration.length_scale": gap.length_scale, "arm.calibration.joint_offsets": list(gap.joint_offsets)}


def run_arm(config: str, seeds: int, prior_ma: int, out: Path, gaps=GAPS, regions: bool = True) -> dict:
    """Every run of one arm; returns {variant: {gap: [per-seed {point: error}]}}."""
    n = len(arm_spec_from_params(load_arm_config(config)["sagg_sim_bridge"]).joint_names())
    runs: dict = {}
    name = Path(config).stem
    for s in range(seeds):
        prior_dir = out / name / f"prior-seed{100 + s}"
        run_arm_experiment(config, None, 100 + s, prior_ma, prior_ma, prior_dir, progress=False, save_model=True)
        variants = [("none", g, {}) for g in gaps] + [("prior", g, {"prior.memory": str(prior_dir / "memory.npz")})
                                                      for g in gaps]
        if regions:
                variants.append(("prior+regions", 1.0, {"prior.memory": str(prior_dir / "memory.npz"),
                                                    "prior.regions": str(prior_dir / "regions.npz")}))
        for variant, gap, ov in variants:
            res = run_arm_experiment(config, None, s, max(POINTS), 250, out / name / f"{variant}-gap{gap:g}-seed{s}",
                                     progress=False, overrides={**_gap_overrides(n, gap), **ov})
            runs.setdefault(variant, {}).setdefault(gap, []).append(_errors(res))
            print(f"{name} seed {s} {variant} gap {gap:g}: " +
                  ", ".join(f"{p} {res_e:.4f}" for p, res_e in _errors(res).items() if p in POINTS), flush=True)
    return runs


def table(name: str, runs: dict, gaps=GAPS) -> str:
    """Markdown: per gap, per point, mean ± std of the no-prior and prior runs, and the tests."""
    lines = [f"### {name}", "", "| gap | micro-actions | no prior | prior | prior + regions | MW p | Welch p |",
             "|---|---|---|---|---|---|---|"]
    for gap in gaps:
        for p in POINTS:
            a = [r[p] for r in runs["none"][gap]]
            b = [r[p] for r in runs["prior"][gap]]
            c = [r[p] for r in runs["prior+regions"][gap]] if gap in runs.get("prior+regions", {}) else []
            t = pairwise_tests(b, a)
            cell = f"{np.mean(c):.4f} ± {np.std(c):.4f}" if c else ""
            lines.append(f"| {gap:g} | {p} | {np.mean(a):.4f} ± {np.std(a):.4f} | {np.mean(b):.4f} ± {np.std(b):.4f} "
                         f"| {cell} | {t['mannwhitney_p']:.3g} | {t['welch_p']:.3g} |")
    for gap in gaps:
        target = np.mean([r[2000] for r in runs["none"][gap]])
        first = next((p for p in POINTS if np.mean([r[p] for r in runs["prior"][gap]]) <= target), None)
        lines.append(f"\ngap {gap:g}: the no-prior 2,000 error {target:.4f} is reached with the prior at "
                     f"{first if first is not None else 'more than 2000'} robot micro-actions")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.prior_gap", description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--prior-micro-actions", type=int, default=20_000)
    ap.add_argument("--arms", nargs="+", default=["arm7_urdf", "arm6_mjcf"])
    ap.add_argument("--gaps", nargs="+", type=float, default=list(GAPS), help="multiples of the default test gap")
    ap.add_argument("--no-regions", action="store_true", help="skip the runs with the prior's region tree")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    every = {}
    for arm in args.arms:
        runs = run_arm(f"config/{arm}.yaml", args.seeds, args.prior_micro_actions, out, args.gaps,
                       not args.no_regions)
        every[arm] = {v: {str(g): r for g, r in gaps.items()} for v, gaps in runs.items()}
        print(table(arm, runs, args.gaps), flush=True)
    (out / "prior_gap.json").write_text(json.dumps(every, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
