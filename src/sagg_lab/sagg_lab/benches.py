"""``sagg bench`` subcommands of the lab: each a :class:`sagg_bringup.cli.benches.Bench`, registered as
an entry point of the group ``sagg.bench`` (setup.py). Options here; the work in the module each
runs (imported when it runs: they load mujoco, ROS or scipy)."""
from __future__ import annotations

import argparse

from sagg_common.params import PAPER_STRATEGIES, STRATEGIES, parse_set
from sagg_bringup.cli.benches import Bench, positive_int

from .hostile import bench_hostile
from .soak import main_soak



def _speed_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="config/arm15.yaml")
    p.add_argument("--dof", type=positive_int, nargs="+", default=[7, 15, 30])
    p.add_argument("--modes", nargs="+", choices=["kinematic", "dynamic"], default=["kinematic"])
    p.add_argument("--sizes", type=positive_int, nargs="+", default=[10_000, 100_000, 1_000_000],
                   help="stored samples before timing (cost ratios against the smallest)")
    p.add_argument("--measure", type=positive_int, default=2000,
                   help="micro-actions timed at each size")
    p.add_argument("--strategies", nargs="+", choices=STRATEGIES, default=list(PAPER_STRATEGIES))
    p.add_argument("--graph", action=argparse.BooleanOptionalAction, default=True,
                   help="also measure graph vs in-process vs bare rclpy ping-pong (sagg bench graph)")
    p.add_argument("--graph-config", default="config/arm8.yaml")
    p.add_argument("--graph-micro-actions", type=positive_int, default=2000)
    p.add_argument("--repeats", type=positive_int, default=1,
                   help="timed windows per row on fresh runs, sizes interleaved; the best is kept")
    p.add_argument("--profile", type=int, default=0, metavar="N",
                   help="print the N functions with the most own time in the last timed window")


def _riac_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="config/arm15.yaml")
    p.add_argument("--micro-actions", type=positive_int, default=60_000)
    p.add_argument("--window", type=positive_int, default=5_000, help="micro-actions per timed window")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter override")


def _graph_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="config/arm8.yaml")
    p.add_argument("--micro-actions", type=positive_int, default=3000,
                   help="lockstep micro-actions per graph and in-process run")
    p.add_argument("--repeats", type=positive_int, default=2,
                   help="interleaved repeats of all four measurements; the best of each is kept")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter override")


def _soak_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="config/arm8.yaml")
    p.add_argument("--mode", choices=["inprocess", "graph"], nargs="+", default=["inprocess", "graph"])
    p.add_argument("--micro-actions", type=positive_int, default=None,
                    help="default: 1,000,000 in-process, 100,000 through the graph")
    p.add_argument("--every", type=positive_int, default=None, help="rows every K micro-actions "
                    "(default: micro-actions / 20)")
    p.add_argument("--out", default=None, help="directory for the graph's logs/params and soak.json "
                    "(default runs/soak-<time>)")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter override")


def _hostile_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="config/arm8.yaml")
    p.add_argument("--minutes", type=float, default=10.0, help="total fuzzing time (two phases, half each)")
    p.add_argument("--quiet", type=float, default=3.0, help="seconds watched after each case")
    p.add_argument("--out", default=None, help="directory (default runs/hostile-<time>)")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter override")


def _quality_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", default="config/arm7_ratio15.yaml")
    p.add_argument("--strategies", nargs="+", choices=STRATEGIES, default=list(PAPER_STRATEGIES))
    p.add_argument("--seeds", type=positive_int, default=5, help="number of seeds: base seed + i")
    p.add_argument("--base-seed", type=int, default=0)
    p.add_argument("--points", type=positive_int, nargs="+", default=[5000, 20000],
                    help="queries (micro-actions) at which the test error is reported")
    p.add_argument("--contexts", nargs="+", choices=["evolving", "fixed"], default=["evolving", "fixed"],
                    help="learner contexts (fixed = --set context=fixed on every run)")
    p.add_argument("--wide", type=float, nargs=4, default=[-2.0, -2.0, 2.0, 2.0],
                    metavar=("XLO", "YLO", "XHI", "YHI"), help="the second task space")
    p.add_argument("--no-analytic", action="store_true", help="skip the analytic-Jacobian reach check")
    p.add_argument("--out", help="directory for quality.json, quality.md and every result.json")
    p.add_argument("--set", action="append", metavar="NAME=VALUE", help="parameter override (every run)")


def _speed(args) -> int:
    # lazy (heavy): mujoco
    from .bench import bench_speed
    bench_speed(args.config, args.dof, args.modes, args.sizes, args.measure, args.strategies,
                graph=args.graph, graph_micro_actions=args.graph_micro_actions,
                profile=args.profile, graph_config=args.graph_config, repeats=args.repeats)
    return 0


def _riac(args) -> int:
    # lazy (heavy): mujoco
    from .riac_speed import bench_riac
    res = bench_riac(args.config, args.micro_actions, args.window, overrides=parse_set(args.set))
    return 0 if all(res["identical"].values()) else 1


def _graph(args) -> int:
    # lazy (heavy): mujoco
    from .bench import bench_graph
    bench_graph(args.config, args.micro_actions, args.repeats, overrides=parse_set(args.set))
    return 0


def _soak(args) -> int:
    return main_soak(args, parse_set(args.set))


def _hostile(args) -> int:
    res = bench_hostile(args.config, args.minutes, args.out, args.set or [], args.quiet)
    return 0 if res["ok"] else 1


def _quality(args) -> int:
    # lazy (heavy): mujoco, scipy
    from .quality import bench_quality
    bench_quality(args.config, args.strategies, args.seeds, args.points, args.contexts,
                  args.wide, parse_set(args.set), args.base_seed, args.out,
                  analytic=not args.no_analytic)
    return 0


SPEED = Bench("in-process micro-actions/s against stored samples", _speed_arguments, _speed)
RIAC = Bench("ACTUATOR-RIAC micro-actions/s: the leaf table against the tree walk it replaced, same "
             "seeded run, bit-identity checked", _riac_arguments, _riac)
GRAPH = Bench("graph vs in-process micro-actions/s vs a bare rclpy ping-pong, and the contract floor "
              "(the lockstep exchange with no work)", _graph_arguments, _graph)
SOAK = Bench("long run: RSS growth per stored sample, fds, /dev/shm (in-process and/or through the "
             "graph)", _soak_arguments, _soak)
HOSTILE = Bench("a running graph under a fuzzer publishing every hostile case (docs/safety.md) on every "
                "topic; per-case table and invariants", _hostile_arguments, _hostile)
QUALITY = Bench("test error against queries for both learner contexts and every strategy, over seeds, "
                "in the config's Y and a wide one; queries/s, mean ± std, SAGG-RIAC vs SAGG-RANDOM "
                "p-values, the analytic-Jacobian reach check", _quality_arguments, _quality)
