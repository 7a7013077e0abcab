"""The ``sagg`` command line."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from sagg_common.params import ConfigError

STRATEGIES = ["sagg-riac", "sagg-random", "actuator-random", "actuator-riac"]


def parse_set(items: list[str] | None) -> dict:
    """``--set name=value`` overrides; values are parsed as YAML (numbers, lists, booleans)."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected name=value")
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ConfigError(f"--set {name}: value {value!r} is not valid YAML ({exc})") from exc
    return out


def positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {v}")
    return v


def node_schemas() -> dict:
    """Every node's full parameter schema (core parameters + node-only ones: topics, timing...)."""
    from sagg_goal_generator.node import SCHEMA as GEN
    from sagg_low_level.node import SCHEMA as LEARNER
    from sagg_sim_bridge.node import SCHEMA as BRIDGE
    return {"sagg_goal_generator": GEN, "sagg_learner": LEARNER, "sagg_sim_bridge": BRIDGE}


def params_markdown(node: str | None = None) -> str:
    from sagg_common.params import schema_markdown
    parts = []
    for name, schema in node_schemas().items():
        if node is None or node == name:
            parts.append(f"### `{name}`\n\n{schema_markdown(schema)}\n")
    return "\n".join(parts)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sagg", description="SAGG-RIAC goal babbling for ROS 2.")
    sub = p.add_subparsers(dest="command", required=True)

    e = sub.add_parser("experiment", help="run one strategy and seed in-process (no ROS)")
    e.add_argument("--config", required=True, help="experiment YAML (ROS 2 parameter-file form)")
    e.add_argument("--strategy", choices=STRATEGIES, help="overrides the config's strategy")
    e.add_argument("--seed", type=int, help="overrides the config's seed")
    e.add_argument("--micro-actions", type=positive_int, default=30_000, help="learning budget")
    e.add_argument("--eval-every", type=positive_int, default=1000,
                   help="evaluate the frozen model on the test goals every K micro-actions")
    e.add_argument("--out", required=True, help="output directory (result.json)")
    e.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override any parameter, e.g. --set arm.dof=7 (repeatable)")
    e.add_argument("--quiet", action="store_true", help="no progress display")
    e.add_argument("--report", action="store_true", help="also write report.md + figures into --out")

    r = sub.add_parser("run", help="run the ROS 2 graph (three node processes), record a bag, "
                                   "evaluate, report")
    r.add_argument("config", help="experiment YAML (ROS 2 parameter-file form)")
    r.add_argument("--micro-actions", type=positive_int, default=10_000,
                   help="learning budget (the learner stops there)")
    r.add_argument("--seed", type=int, help="overrides the config's seed")
    r.add_argument("--strategy", choices=STRATEGIES, help="overrides the config's strategy")
    r.add_argument("--out", help="output directory (default runs/<config>-<strategy>-seed<S>-<time>)")
    r.add_argument("--timing", choices=["lockstep", "realtime"], default="lockstep",
                   help="bridge timing: lockstep (deterministic) or realtime (like hardware)")
    r.add_argument("--eval-every", type=positive_int, default=1000,
                   help="evaluate the frozen model on the test goals every K micro-actions")
    r.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override any node parameter, e.g. --set arm.dof=7 (repeatable)")
    r.add_argument("--domain-id", type=int, help="ROS_DOMAIN_ID (default: a random private one)")
    r.add_argument("--quiet", action="store_true", help="no progress display")

    pp = sub.add_parser("params", help="print every node parameter (name, type, default, range, "
                                       "description) as Markdown tables")
    pp.add_argument("--node", choices=["sagg_goal_generator", "sagg_learner", "sagg_sim_bridge"],
                    help="only this node")

    b = sub.add_parser("bench", help="benchmarks")
    bsub = b.add_subparsers(dest="bench", required=True)
    s = bsub.add_parser("speed", help="in-process micro-actions/s against stored samples")
    s.add_argument("--config", default="config/arm15.yaml")
    s.add_argument("--dof", type=positive_int, nargs="+", default=[7, 15])
    s.add_argument("--modes", nargs="+", choices=["kinematic", "dynamic"],
                   default=["kinematic", "dynamic"])
    s.add_argument("--sizes", type=positive_int, nargs="+", default=[10_000, 200_000])
    s.add_argument("--measure", type=positive_int, default=2000,
                   help="micro-actions timed at each size")
    s.add_argument("--strategy", choices=STRATEGIES, default="sagg-riac")
    t = bsub.add_parser("table", help="compare strategies from result.json files (Markdown table "
                                      "and Mann-Whitney / Welch tests)")
    t.add_argument("results", nargs="+", help="directories searched for result.json, or files")
    t.add_argument("--plot", metavar="PNG", help="also draw the curves (mean ± std over seeds)")
    t.add_argument("--title", default="", help="plot title")
    return p


def _run(args) -> int:
    import time

    from .graph import GraphError, run_graph
    out = args.out
    if out is None:
        seed = "" if args.seed is None else f"-seed{args.seed}"
        strategy = "" if args.strategy is None else f"-{args.strategy}"
        out = Path("runs") / f"{Path(args.config).stem}{strategy}{seed}-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        s = run_graph(args.config, args.micro_actions, out, seed=args.seed, strategy=args.strategy,
                      timing=args.timing, eval_every=args.eval_every, overrides=parse_set(args.set),
                      progress=not args.quiet, domain_id=args.domain_id)
    except GraphError as exc:
        print(f"sagg: error: {exc}\nsagg: partial results in {out}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt:
        print(f"\nsagg: interrupted; bag closed, partial results in {out}", file=sys.stderr)
        return 130
    print(f"{s['strategy']} seed {s['seed']} (graph, {s['timing']}): final mean test error "
          f"{s['final_mean_error']:.3f} (median {s['final_median_error']:.3f}) after {s['micro_actions']} "
          f"micro-actions at {s['micro_actions_per_second']:,.0f}/s; wall {s['wall_seconds']:.1f} s; "
          f"{len(s['goals'])} goals, {len(s['regions'])} regions, "
          f"{sum(t['count'] for t in s['bag']['topics'].values()):,} messages recorded\n"
          f"-> {Path(out) / 'summary.json'}, {Path(out) / 'report.md'}, {s['bag']['path']}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "experiment":
            from .experiment import run_experiment
            res = run_experiment(args.config, args.strategy, args.seed, args.micro_actions,
                                 args.eval_every, args.out, progress=not args.quiet,
                                 overrides=parse_set(args.set))
            print(f"{res['strategy']} seed {res['seed']}: final mean test error "
                  f"{res['final_mean_error']:.3f} (median {res['final_median_error']:.3f}) after "
                  f"{res['micro_actions']} micro-actions at {res['micro_actions_per_second']:,.0f}/s; "
                  f"{len(res['goals'])} goals, {len(res['regions'])} regions -> "
                  f"{Path(args.out) / 'result.json'}")
            if args.report:
                from .report import write_report
                print(f"report: {write_report(res, args.out)}")
            return 0
        if args.command == "run":
            return _run(args)
        if args.command == "params":
            print(params_markdown(args.node))
            return 0
        if args.command == "bench" and args.bench == "table":
            from .compare import load_results, summary_markdown
            results = load_results(args.results)
            if not results:
                raise ConfigError(f"no result.json found under {', '.join(args.results)}")
            print(summary_markdown(results))
            if args.plot:
                from .compare import plot_curves
                plot_curves(results, args.plot, args.title)
            return 0
        if args.command == "bench" and args.bench == "speed":
            from .bench import bench_speed
            bench_speed(args.config, args.dof, args.modes, args.sizes, args.measure, args.strategy)
            return 0
    except ConfigError as exc:
        print(f"sagg: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("sagg: interrupted", file=sys.stderr)
        return 130
    return 1


if __name__ == "__main__":
    sys.exit(main())
