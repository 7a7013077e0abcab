"""Benchmark of SampleMemory: cost of one micro-action's (k-NN query + add) as the memory grows.

    python -m sagg_lab.memory_bench            # n = 7, 15, 30, exact and approximate (~10 min)
    python -m sagg_lab.memory_bench --help

Per size N the memory is filled to N samples (bulk, giving exactly the index state N incremental adds
would leave), then ``queries`` micro-actions are timed: neighbours(alpha_t, k) followed by add(alpha_t,
...), alpha_t continuing the same trajectory. Times are CPU time of this thread (``time.thread_time``),
so that other processes on a shared machine inflate them less than wall time would. The rebuild work of
the logarithmic method is reported amortised: a sample takes part in one block build per block size,
so rebuild/add = sum over the block sizes B * 2**i <= N of (build time of that size) / (its size),
measured on this data.

Data: "traj": alpha from seeded directed random walks of the joint angles (AR(1) velocity with
persistence 0.9, as a learner moving towards goals), successive alpha differing by ~0.03 rad per joint,
restarted exactly at a fixed rest posture every 200 samples (so the rest posture is stored many times,
exactly); "walk": the same without persistence (diffusive); "unif": alpha uniform in [-pi, pi]^n
(queries too; the hard case for any exact index in 15-30 dims).

The timed micro-actions are split in 3 consecutive windows and the median of the window means is
reported (the shared machine's load spikes otherwise dominate a mean); q.med is the per-query median.

Search modes (``--checks``): 0 = exact, c > 0 = approximate with at most c leaves per query (the
learner's ``neighbour_checks``). Both run in one command, so their times are comparable. Quality
of every ``recall_every``-th answer against brute force (untimed): recall = share of the returned
samples no farther than the true k-th nearest (exact ties are interchangeable), d.ratio = mean of
(returned k-th distance / true k-th distance), as plain (not squared) distances.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
from scipy.signal import lfilter
from scipy.spatial import cKDTree

from sagg_low_level.memory import SampleMemory, _sqdist_cols

KINDS = {"traj": 0.9, "walk": 0.0}  # persistence of the random walk per data kind

__all__ = ["default_k", "trajectory_alphas", "uniform_alphas", "bench_memory", "bench_ckdtree_forest"]


def default_k(state_dim: int) -> int:
    """Neighbours for the local Jacobian: 2 * (n + 1).

    The local linear model dy = J da (+ offset) has n (+1) unknowns per task coordinate; a least-squares
    fit from noisy micro-actions needs clear over-determination, and twice the unknowns keeps the
    neighbourhood as local as possible while doing so. It lies inside the 2n..3n range of the brief.
    """
    return 2 * (state_dim + 1)


def _rng(seed) -> np.random.Generator:
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def trajectory_alphas(n: int, count: int, rng, *, step: float = 0.03, reset_every: int = 200,
                      persistence: float = 0.0, rest: np.ndarray | None = None) -> np.ndarray:
    """(count, n) joint-angle samples from random walks restarted at a rest posture.

    Every ``reset_every`` samples the walk restarts exactly at ``rest`` (default: a slightly bent
    posture, 0.15 rad per joint, as the paper's rest position "not straight and slightly bent").
    Velocities are AR(1) with coefficient ``persistence`` in [0, 1) and per-joint std ``step``.
    """
    if count < 0 or n < 1 or reset_every < 1 or not 0.0 <= persistence < 1.0 or step <= 0:
        raise ValueError("trajectory_alphas: need n >= 1, count >= 0, reset_every >= 1, step > 0, "
                         f"0 <= persistence < 1; got n={n} count={count} reset_every={reset_every} "
                         f"step={step} persistence={persistence}")
    rng = _rng(rng)
    rest = np.full(n, 0.15) if rest is None else np.asarray(rest, dtype=np.float64)
    segs = -(-count // reset_every)
    noise = rng.normal(0.0, step * np.sqrt(1.0 - persistence**2), size=(segs, reset_every, n))
    vel = lfilter([1.0], [1.0, -persistence], noise, axis=1) if persistence else noise
    pos = np.zeros_like(vel)
    np.cumsum(vel[:, :-1], axis=1, out=pos[:, 1:])
    pos += rest
    return pos.reshape(-1, n)[:count]


def uniform_alphas(n: int, count: int, rng) -> np.ndarray:
    return _rng(rng).uniform(-np.pi, np.pi, size=(count, n))


def _data(kind: str, dim: int, count: int, rng) -> np.ndarray:
    if kind == "unif":
        return uniform_alphas(dim, count, rng)
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {sorted(KINDS) + ['unif']}, got {kind!r}")
    return trajectory_alphas(dim, count, rng, persistence=KINDS[kind])


def _memory_at(alphas: np.ndarray, outcome_dim: int, **kw) -> tuple[SampleMemory, float]:
    """Memory holding ``alphas`` (delta arrays zero) built in bulk; returns it and the build seconds."""
    n_rows, n = alphas.shape
    mem = SampleMemory(n, n, outcome_dim, capacity=max(1, n_rows), **kw)
    mem._alpha[:n_rows] = alphas
    mem._dalpha[:n_rows] = 0.0
    mem._dy[:n_rows] = 0.0
    mem._n = n_rows
    t0 = time.thread_time()
    mem._rebuild_all()
    return mem, time.thread_time() - t0


def _amortised_rebuild(mem: SampleMemory, n_rows: int, cache: dict) -> float:
    """Seconds of block building per added sample at size n_rows (sum over block sizes, see top)."""
    total, size = 0.0, mem._buf
    while size <= max(n_rows - mem._buf, 0):
        if size not in cache:
            t0 = time.thread_time()
            mem._build_block(0, size)  # written after the live blocks' slots: harmless scratch
            cache[size] = (time.thread_time() - t0) / size
            mem._refresh_roots()
        total += cache[size]
        size *= 2
    return total


def _quality(data: np.ndarray, t: int, q: np.ndarray, got: np.ndarray, k: int) -> tuple[float, float]:
    """(recall, k-th distance ratio) of one answer against brute force over data[:t]."""
    d = _sqdist_cols(np.ascontiguousarray(data[:t].T), q) if t < 200_000 else ((data[:t] - q) ** 2).sum(axis=1)
    kth = np.partition(d, k - 1)[k - 1]
    dg = d[got]
    ratio = np.sqrt(dg.max() / kth) if kth > 0 else (1.0 if dg.max() == 0 else np.inf)
    return float(np.count_nonzero(dg <= kth)) / k, float(ratio)


def bench_memory(dim: int, sizes, k: int | None = None, queries: int = 500, *, kind: str = "traj",
                 seed: int = 0, outcome_dim: int = 2, data: np.ndarray | None = None,
                 recall_every: int = 4, **memory_kwargs) -> list[dict]:
    """Time (query + add) per micro-action at each size; one dict per size, ratios against the first."""
    sizes = sorted(int(s) for s in sizes)
    k = default_k(dim) if k is None else int(k)
    rng = np.random.default_rng(seed)
    total = sizes[-1] + queries
    if data is None:
        data = _data(kind, dim, total, rng)
    da, dy = np.zeros(dim), np.zeros(outcome_dim)
    rows, build_cache = [], {}
    for n_rows in sizes:
        mem, build_s = _memory_at(data[:n_rows], outcome_dim, **memory_kwargs)
        nbytes = mem.nbytes  # before the timed adds grow the arrays (capacity doubling)
        t_query, t_add, t_wall, answers = [], [], [], []
        w0 = time.perf_counter()
        for t in range(n_rows, n_rows + queries):
            a = data[t]
            c0 = time.thread_time()
            got = mem.neighbours(a, k)
            c1 = time.thread_time()
            if recall_every and (t - n_rows) % recall_every == 0:
                answers.append((t, got))
            ns = mem._ns
            mem.add(a, da, dy)
            c2 = time.thread_time()
            t_query.append(c1 - c0)
            if mem._ns == ns:  # adds that built a block are counted by the amortised rebuild
                t_add.append(c2 - c1)
        t_wall = (time.perf_counter() - w0) / queries
        rebuild = _amortised_rebuild(mem, n_rows, build_cache)  # scribbles on mem: measured last
        hits = mem.cache_hits
        qual = np.array([_quality(data, t, data[t], got, k) for t, got in answers]).reshape(-1, 2)
        q_us = float(np.median([np.mean(w) for w in np.array_split(t_query, 3)])) * 1e6
        a_us = float(np.median([np.mean(w) for w in np.array_split(t_add, 3)])) * 1e6
        r_us = rebuild * 1e6
        rows.append(dict(
            dim=dim, k=k, kind=kind, size=n_rows, query_us=q_us, query_median_us=np.median(t_query) * 1e6,
            add_us=a_us, rebuild_us=r_us, total_us=q_us + a_us + r_us, wall_us=t_wall * 1e6,
            bytes_per_sample=nbytes / n_rows, cache_hit_rate=hits / queries, blocks=len(mem._blocks),
            bulk_build_s=build_s,
            checks=mem._checks, recall=float(qual[:, 0].mean()) if len(qual) else float("nan"),
            distance_ratio=float(qual[:, 1].mean()) if len(qual) else float("nan"),
        ))
    for row in rows:
        row["ratio"] = row["total_us"] / rows[0]["total_us"]
    return rows


def bench_ckdtree_forest(dim: int, sizes, k: int | None = None, queries: int = 300, *,
                         kind: str = "traj", seed: int = 0, buffer_size: int = 256,
                         balanced_tree: bool = True, compact_nodes: bool = True,
                         leafsize: int = 16) -> list[dict]:
    """Alternative measured for the design choice: Bentley-Saxe forest of static cKDTrees + buffer.

    Same block decomposition as SampleMemory (binary counter over buffer_size batches); a query asks
    every tree for its k nearest (distance_upper_bound = the buffer's k-th distance) and merges.
    Query cost only (its rebuild cost is of the same order as SampleMemory's). Also times one static
    cKDTree over all N samples (no inserts possible: a lower bound for any cKDTree-based design).
    """

    sizes = sorted(int(s) for s in sizes)
    k = default_k(dim) if k is None else int(k)
    rng = np.random.default_rng(seed)
    total = sizes[-1] + queries
    data = _data(kind, dim, total, rng)
    rows = []
    for n_rows in sizes:
        flushes = max(0, (n_rows - buffer_size) // buffer_size)
        trees, start = [], 0
        for bit in range(flushes.bit_length() - 1, -1, -1):
            if flushes >> bit & 1:
                size = buffer_size << bit
                trees.append((start, cKDTree(data[start:start + size], leafsize=leafsize,
                                             balanced_tree=balanced_tree, compact_nodes=compact_nodes)))
                start += size
        buf_t = np.ascontiguousarray(data[start:n_rows].T)
        static = cKDTree(data[:n_rows], leafsize=leafsize, balanced_tree=balanced_tree,
                         compact_nodes=compact_nodes)
        t_static = []
        for t in range(n_rows, n_rows + queries):
            c0 = time.thread_time()
            static.query(data[t], k)
            t_static.append(time.thread_time() - c0)
        times = []
        for t in range(n_rows, n_rows + queries):
            q = data[t]
            c0 = time.thread_time()
            bd = _sqdist_cols(buf_t, q)
            bound = np.sqrt(np.partition(bd, k - 1)[k - 1]) * (1 + 1e-9) if len(bd) >= k else np.inf
            ds, ids = [bd], [np.arange(start, n_rows)]
            for off, tree in trees:
                d, i = tree.query(q, k, distance_upper_bound=bound)
                ok = i < tree.n
                ds.append(d[ok] ** 2)
                ids.append(i[ok] + off)
            d, i = np.concatenate(ds), np.concatenate(ids)
            i[np.lexsort((i, d))[:k]]
            times.append(time.thread_time() - c0)
        rows.append(dict(dim=dim, k=k, kind=kind, size=n_rows, trees=len(trees),
                         query_us=float(np.mean(times)) * 1e6, static_query_us=float(np.mean(t_static)) * 1e6))
    for row in rows:
        row["ratio"] = row["query_us"] / rows[0]["query_us"]
    return rows


def _print_table(rows: list[dict], out=sys.stdout) -> None:
    head = (f"{'n':>3} {'k':>3} {'data':>4} {'mode':>5} {'N':>8} {'query':>8} {'q.med':>7} {'add':>6} "
            f"{'rebuild':>7} {'total':>8} {'ratio':>6} {'B/sample':>8} {'wall':>8} {'hits':>5} {'recall':>6} "
            f"{'d.ratio':>7}")
    print(head, file=out)
    for r in rows:
        mode = f"c{r['checks']}" if r.get("checks") else "exact"
        print(f"{r['dim']:>3} {r['k']:>3} {r['kind']:>4} {mode:>5} {r['size']:>8} {r['query_us']:>8.1f} "
              f"{r['query_median_us']:>7.1f} {r['add_us']:>6.1f} {r['rebuild_us']:>7.1f} {r['total_us']:>8.1f} "
              f"{r['ratio']:>6.2f} {r['bytes_per_sample']:>8.1f} {r['wall_us']:>8.1f} {r['cache_hit_rate']:>5.2f} "
              f"{r.get('recall', float('nan')):>6.3f} {r.get('distance_ratio', float('nan')):>7.4f}", file=out)
    out.flush()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--dims", default="7,15,30")
    p.add_argument("--sizes", default="10000,100000,200000,1000000")
    p.add_argument("--max-1m-dim", type=int, default=15,
                   help="largest n benchmarked at sizes above 200k (bench time)")
    p.add_argument("--k", type=int, default=None, help="neighbours (default 2n+2)")
    p.add_argument("--queries", type=int, default=400, help="timed micro-actions per size")
    p.add_argument("--kind", choices=["traj", "walk", "unif", "all"], default="all",
                   help="all = traj for every n, walk for n=7, unif at --unif-sizes")
    p.add_argument("--unif-sizes", default="10000,100000,200000")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--checks", default="0,32",
                   help="search modes, comma-separated: 0 = exact, c > 0 = approximate, c leaves")
    p.add_argument("--recall-every", type=int, default=4,
                   help="check every i-th answer against brute force (0 = never; untimed)")
    p.add_argument("--ckdtree", action="store_true", help="also time the cKDTree-forest alternative")
    args = p.parse_args(argv)
    dims = [int(x) for x in args.dims.split(",")]
    checks = [int(x) for x in args.checks.split(",")]
    print("us = CPU microseconds per micro-action; total = query + add + amortised rebuild; "
          "ratio = total / total at the smallest N; wall = wall-clock us per (query + add)")
    for kind in (["traj", "walk", "unif"] if args.kind == "all" else [args.kind]):
        sizes_all = [int(x) for x in (args.unif_sizes if kind == "unif" else args.sizes).split(",")]
        for dim in dims:
            if kind == "walk" and args.kind == "all" and dim != dims[0]:
                continue
            sizes = [s for s in sizes_all if s <= 200_000 or dim <= args.max_1m_dim]
            for c in checks:
                rows = bench_memory(dim, sizes, args.k, args.queries, kind=kind, seed=args.seed,
                                    recall_every=args.recall_every, checks=c)
                _print_table(rows)
            if args.ckdtree:
                for r in bench_ckdtree_forest(dim, sizes, args.k, min(args.queries, 300), kind=kind,
                                              seed=args.seed):
                    print(f"    alternative: cKDTree forest (n={r['dim']} N={r['size']}, {r['trees']} trees) "
                          f"query {r['query_us']:.1f} us, ratio {r['ratio']:.2f}; one static cKDTree "
                          f"(cannot take inserts) {r['static_query_us']:.1f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
