"""Speed of the sagg_msgs codecs: the ones generated from the .msg files (sagg_common.msg_codecs)
and rosbags' serializer, each against the hand-written codecs they replaced, in one process.

``python -m sagg_lab.cdr_bench [--baseline REV] [--n N] [--rounds R]``

The baseline is the hand-written ``sagg_common/cdr.py`` of git revision REV (default cb9d36b, the
last commit with hand-written sagg_msgs codecs), loaded from ``git show`` into a private module.
Every candidate encodes the same values and must give the baseline's bytes (checked first: the
bags written before must still read); decoders must return the same values. Timings: R rounds of
N calls each, candidates interleaved round by round (a burst of load hits all alike), the best
round per candidate; printed as µs per call and the ratio to the baseline (> 1 = slower).
Messages as the arm run sends them: an 8-DOF Sample, a 2-D CompetenceReport, a RegionTree of 50
regions in 2-D.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from sagg_common import msg_codecs

REPO = Path(__file__).resolve().parents[3]
BASELINE_REV = "cb9d36b"


def load_baseline(rev: str):
    """The hand-written cdr module of ``rev`` as a module object (not importable by name)."""
    src = subprocess.run(["git", "-C", str(REPO), "show", f"{rev}:src/sagg_common/sagg_common/cdr.py"],
                         check=True, capture_output=True, text=True).stdout
    with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
        f.write(src)
    try:
        spec = importlib.util.spec_from_file_location(f"cdr_baseline_{rev}", f.name)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        os.unlink(f.name)
    return mod


def rosbags_store():
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    msg_dir = msg_codecs.find_msg_dir()
    for name in msg_codecs.MESSAGES:
        types.update(get_types_from_msg((msg_dir / f"{name}.msg").read_text(), f"sagg_msgs/msg/{name}"))
    store.register(types)
    return store


def cases(old, store):
    """name -> (baseline callable, generated callable, rosbags callable), all on the same values."""
    rng = np.random.default_rng(0)
    stamp = 1_700_000_000_123_456_789
    a, da, dy = rng.normal(size=8), rng.normal(size=8) * 1e-2, rng.normal(size=2)
    t, re, st = rng.normal(size=2), rng.normal(size=2), rng.normal(size=2)
    k, m = 50, 2
    ids = np.arange(k)
    lo, up = rng.normal(size=(k, m)), rng.normal(size=(k, m)) + 5.0
    interest, counts, means = rng.random(k), rng.integers(0, 50, k), -rng.random(k)
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Sample, Report = T["sagg_msgs/msg/Sample"], T["sagg_msgs/msg/CompetenceReport"]
    Region, Tree = T["sagg_msgs/msg/Region"], T["sagg_msgs/msg/RegionTree"]

    def header(frame=""):
        s, ns = divmod(stamp, 10**9)
        return Header(stamp=Time(sec=s, nanosec=ns), frame_id=frame)

    sample_raw = old.encode_sample(stamp, 7, a, da, dy)
    report_raw = old.encode_report(stamp, 3, 2, 1, t, re, st, -0.25, 1234)
    gen = msg_codecs
    return {
        "encode Sample": (
            lambda: old.encode_sample(stamp, 7, a, da, dy),
            lambda: gen.encode_sample(stamp, 7, a, da, dy),
            lambda: store.serialize_cdr(Sample(header=header(), index=7, alpha=a, delta_alpha=da, delta_y=dy),
                                        "sagg_msgs/msg/Sample")),
        "decode Sample": (
            lambda: old.decode_sample(sample_raw),
            lambda: tuple(gen.decode_sample(sample_raw)),
            lambda: (lambda s: (s.header.stamp.sec * 10**9 + s.header.stamp.nanosec, s.index, s.alpha,
                                s.delta_alpha, s.delta_y))(store.deserialize_cdr(sample_raw, "sagg_msgs/msg/Sample"))),
        "encode CompetenceReport": (
            lambda: old.encode_report(stamp, 3, 2, 1, t, re, st, -0.25, 1234),
            lambda: gen.encode_report(stamp, 3, 2, 1, t, re, st, -0.25, 1234),
            lambda: store.serialize_cdr(Report(header=header(), seq=3, goal_seq=2, kind=1, target=t, reached=re,
                                               start=st, competence=-0.25, micro_actions=1234),
                                        "sagg_msgs/msg/CompetenceReport")),
        "decode CompetenceReport": (
            lambda: (lambda r: (r.stamp, r.seq, r.kind, r.target, r.competence, r.micro_actions))(
                old.decode_report(report_raw)),
            lambda: (lambda r: (r.stamp, r.seq, r.kind, r.target, r.competence, r.micro_actions))(
                gen.decode_report(report_raw)),
            lambda: (lambda r: (r.header.stamp.sec * 10**9 + r.header.stamp.nanosec, r.seq, r.kind, r.target,
                                r.competence, r.micro_actions))(
                store.deserialize_cdr(report_raw, "sagg_msgs/msg/CompetenceReport"))),
        "encode RegionTree (50 regions)": (
            lambda: old.encode_region_tree(stamp, "task_space", 60, 59, 49, ids, lo, up, interest, counts, means),
            lambda: gen.encode_region_tree(stamp, 60, 59, 49, (ids, lo, up, interest, counts, means),
                                           frame_id="task_space"),
            lambda: store.serialize_cdr(
                Tree(header=header("task_space"), goals=60, reports=59, splits=49,
                     regions=[Region(id=int(ids[i]), lower=lo[i], upper=up[i], interest=float(interest[i]),
                                     count=int(counts[i]), mean_competence=float(means[i])) for i in range(k)]),
                "sagg_msgs/msg/RegionTree")),
    }


def same(x, y) -> bool:
    if isinstance(x, (bytes, bytearray, memoryview)) or isinstance(y, (bytes, bytearray, memoryview)):
        return bytes(x) == bytes(y)
    if isinstance(x, tuple):
        return len(x) == len(y) and all(same(a, b) for a, b in zip(x, y))
    if isinstance(x, np.ndarray) or isinstance(y, np.ndarray):
        return np.asarray(x, dtype=np.float64).tobytes() == np.asarray(y, dtype=np.float64).tobytes()
    return x == y


def timed(f, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        f()
    return (time.perf_counter() - t0) / n * 1e6


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", default=BASELINE_REV)
    ap.add_argument("--n", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=25)
    args = ap.parse_args(argv)
    old = load_baseline(args.baseline)
    store = rosbags_store()
    table = cases(old, store)
    for name, fs in table.items():
        ref = fs[0]()
        for label, f in zip(("generated", "rosbags"), fs[1:]):
            if not same(ref, f()):
                print(f"{name}: {label} differs from the baseline", file=sys.stderr)
                return 1
    print(f"load: {os.getloadavg()[0]:.2f} (1 min); baseline {args.baseline}; {args.rounds} rounds x "
          f"{args.n} calls, best round")
    print(f"{'codec':32s} {'hand µs':>8s} {'gen µs':>8s} {'gen/hand':>8s} {'rosbags µs':>10s} {'rosbags/hand':>12s}")
    worst = {"generated": 0.0, "rosbags": 0.0}
    for name, fs in table.items():
        best = [float("inf")] * 3
        for _ in range(args.rounds):
            for i, f in enumerate(fs):
                best[i] = min(best[i], timed(f, args.n))
        worst["generated"] = max(worst["generated"], best[1] / best[0])
        worst["rosbags"] = max(worst["rosbags"], best[2] / best[0])
        print(f"{name:32s} {best[0]:8.2f} {best[1]:8.2f} {best[1] / best[0]:8.2f} {best[2]:10.2f} "
              f"{best[2] / best[0]:12.2f}")
    print(f"worst ratio: generated {worst['generated']:.2f}, rosbags {worst['rosbags']:.2f}; bytes identical")
    return 0


if __name__ == "__main__":
    sys.exit(main())
