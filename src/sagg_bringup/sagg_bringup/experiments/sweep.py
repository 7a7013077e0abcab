"""``sagg bench compare``: every (strategy, seed) experiment of a comparison, in parallel, resumable.

Layout of the output directory ``DIR``::

    DIR/compare.json                               settings fingerprint (guards resuming)
    DIR/runs/<strategy>/seed-<s>/result.json       one finished run (written atomically)
    DIR/runs/<strategy>/seed-<s>/error.txt         the traceback of a failed run
    DIR/summary.md, DIR/summary.json, DIR/curves.png

Runs execute on a local process pool (``concurrent.futures`` with the ``spawn`` context: no state
of the parent leaks into a run) or on Ray. Both get the same task: the config and every file it
references as content (:mod:`.bundle`), so a worker needs neither the caller's directory nor its
files. A worker only computes and returns its result, or its traceback, with where it ran; the
driver writes every result, so a killed driver never leaves a half-written or late result behind,
and a restart reruns exactly the runs that have no valid ``result.json``.
"""
from __future__ import annotations

import json
import multiprocessing
import os
import socket
import tempfile
import time
import traceback
from concurrent.futures import FIRST_COMPLETED, wait, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from sagg_common.journal import write_json_atomic
from sagg_common.params import STRATEGIES, ConfigError

from ..inprocess.results import code_commit
from ..graph.setups import load_experiment_config, run_experiment
from .bundle import Bundle, driver_paths, make_bundle, materialise

FINGERPRINT_FORMAT = "sagg.compare/1"


@dataclass(frozen=True)
class RunSpec:
    strategy: str
    seed: int

    @property
    def name(self) -> str:
        return f"{self.strategy}/seed-{self.seed}"


def run_dir(out: Path, spec: RunSpec) -> Path:
    return Path(out) / "runs" / spec.strategy / f"seed-{spec.seed}"


def checkpoints(micro_actions: int, eval_every: int) -> list[int]:
    """The evaluation points of a run, exactly as ``run_experiment`` evaluates them."""
    return list(range(0, micro_actions, eval_every)) + [micro_actions]


def _jsonable(obj: Any) -> Any:
    return json.loads(json.dumps(obj, allow_nan=True))


def expected_config(config: str | Path, spec: RunSpec, overrides: dict | None) -> dict:
    """The resolved three-node configuration of one run, as stored in its result.json."""
    ov = dict(overrides or {}, strategy=spec.strategy, seed=spec.seed)
    return _jsonable(load_experiment_config(config, ov))


def make_fingerprint(config: str | Path, strategies: list[str], seeds: list[int],
                     micro_actions: int, eval_every: int, overrides: dict | None) -> dict:
    """Everything that determines the runs' results. The config enters resolved (every parameter
    of every node, strategy and seed excluded), so an edit of the YAML file that changes a value
    is caught, and a cosmetic one is not."""
    base = _jsonable(load_experiment_config(config, dict(overrides or {})))
    for node in base.values():
        node.pop("strategy", None)
        node.pop("seed", None)
    return {"format": FINGERPRINT_FORMAT, "config_file": str(config), "strategies": list(strategies),
            "seeds": list(seeds), "micro_actions": int(micro_actions), "eval_every": int(eval_every),
            "overrides": _jsonable(dict(overrides or {})), "parameters": base}


# Which runs a comparison holds, not what any run computes: every run's result.json is checked
# against its own strategy, seed and settings (validate_result) and the summary reads the requested
# runs only, so a restart may add (or leave out) seeds and strategies.
RUN_SET_KEYS = ("seeds", "strategies")


def fingerprint_differences(old: dict, new: dict, ignore: tuple[str, ...] = ()) -> list[str]:
    """Names of the settings that differ (``parameters.<node>.<name>`` for node parameters),
    top-level keys in ``ignore`` left out."""
    diffs = []
    for key in sorted(set(old) | set(new)):
        if key == "config_file" or key in ignore:
            continue  # (config_file: the same settings from a moved/copied file are the same experiment)
        if key == "parameters":
            po, pn = old.get(key, {}), new.get(key, {})
            for node in sorted(set(po) | set(pn)):
                a, b = po.get(node, {}), pn.get(node, {})
                for name in sorted(set(a) | set(b)):
                    if a.get(name, "<absent>") != b.get(name, "<absent>"):
                        diffs.append(f"parameters.{node}.{name}: {a.get(name, '<absent>')!r} -> "
                                     f"{b.get(name, '<absent>')!r}")
        elif old.get(key) != new.get(key):
            diffs.append(f"{key}: {old.get(key)!r} -> {new.get(key)!r}")
    return diffs


def check_fingerprint(out: Path, fp: dict) -> bool:
    """Write ``DIR/compare.json`` on the first start; on a restart raise ConfigError naming every
    differing setting, other than the run set (RUN_SET_KEYS: more seeds or strategies extend the
    comparison, and compare.json is rewritten to the new set). Returns True when resuming."""
    path = Path(out) / "compare.json"
    if not path.exists():
        Path(out).mkdir(parents=True, exist_ok=True)
        write_json_atomic(path, fp)
        return False
    try:
        old = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: unreadable fingerprint ({exc}); use a new --out") from exc
    diffs = fingerprint_differences(old, fp, ignore=RUN_SET_KEYS)
    if diffs:
        raise ConfigError(f"--out {out} holds a comparison with different settings; differing: "
                          + "; ".join(diffs) + ". Use a new --out or the original settings.")
    if any(old.get(k) != fp.get(k) for k in RUN_SET_KEYS):
        write_json_atomic(path, fp)
    return True


def validate_result(path: Path, spec: RunSpec, micro_actions: int, eval_every: int,
                    config: dict) -> str | None:
    """None when ``path`` is the finished result of exactly this run, else why not."""
    if not path.exists():
        return "missing"
    try:
        r = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        return f"unreadable ({exc.__class__.__name__})"
    if not isinstance(r, dict) or r.get("format") != "sagg.result/1":
        return "not a sagg.result/1 file"
    if r.get("strategy") != spec.strategy or r.get("seed") != spec.seed:
        return f"is {r.get('strategy')} seed {r.get('seed')}"
    if r.get("micro_actions") != micro_actions:
        return f"has {r.get('micro_actions')} micro-actions, expected {micro_actions}"
    points = [c.get("micro_actions") for c in r.get("curve", [])]
    if points != checkpoints(micro_actions, eval_every):
        return "evaluation points differ"
    if r.get("config") != config:
        return "resolved parameters differ"
    return None


def local_where() -> str:
    """Where a local worker runs: this machine and the worker's process id."""
    return f"{socket.gethostname()} pid {os.getpid()}"


def execute_run(bundle: Bundle, strategy: str, seed: int, micro_actions: int, eval_every: int,
                overrides: dict | None, where: Callable[[], str] = local_where) -> dict:
    """One run in a worker (process pool or Ray): the bundle written to a temporary directory of
    the worker's own, the run computed there; writes nothing the driver sees. Returns
    ``{"result", "error", "where"}``: the result (its file parameters as the driver names them),
    or None and the traceback of what failed; ``where()`` says where it ran."""
    try:
        with tempfile.TemporaryDirectory(prefix="sagg-run-") as tmp:
            config, files = materialise(bundle, Path(tmp))
            result = run_experiment(config, strategy, seed, micro_actions, eval_every, None, progress=False,
                                    overrides={**(overrides or {}), **files})
        return {"result": driver_paths(result, bundle), "error": None, "where": where()}
    except Exception:  # noqa: BLE001 - any failure of the run is reported to the driver, with its traceback
        return {"result": None, "error": traceback.format_exc().strip(), "where": where()}


def ray_where() -> str:
    """Where a Ray task runs: its node's id and IP address, and the worker's process id."""
    # lazy (heavy): ray (imported already in a Ray worker)
    import ray
    return (f"Ray node {ray.get_runtime_context().get_node_id()} ({ray.util.get_node_ip_address()}) "
            f"pid {os.getpid()}")


def execute_ray_run(*args) -> dict:
    """:func:`execute_run` as a Ray task (where: the Ray node)."""
    return execute_run(*args, where=ray_where)


class _LocalPool:
    def __init__(self, workers: int):
        self.ex = ProcessPoolExecutor(max_workers=workers,
                                      mp_context=multiprocessing.get_context("spawn"))

    @staticmethod
    def share(bundle: Bundle) -> Bundle:
        """What a task gets of ``bundle`` (each task a copy of it)."""
        return bundle

    def submit(self, *args):
        return self.ex.submit(execute_run, *args)

    def wait_any(self, pending: dict) -> list:
        done, _ = wait(list(pending), return_when=FIRST_COMPLETED)
        return list(done)

    @staticmethod
    def outcome(fut) -> dict:
        """The task's outcome (:func:`execute_run`); a worker process that died: its error."""
        exc = fut.exception()
        if exc is None:
            return fut.result()
        return {"result": None, "error": "".join(traceback.format_exception(exc)).strip(),
                "where": "a local worker process (it died)"}

    def close(self) -> None:
        self.ex.shutdown(wait=True, cancel_futures=True)


class _RayPool:
    """Ray tasks; ``address`` 'local' starts a local instance with ``workers`` CPUs, anything else
    connects to that cluster. Workers need the sagg packages importable (same venv locally; on a
    cluster install them on the nodes), nothing else: each task gets the config's bundle (put in
    the object store once per comparison). The driver writes the results, so no shared file
    system is needed."""

    def __init__(self, address: str, workers: int):
        try:
            # lazy (heavy): ray
            import ray
        except ImportError as exc:
            raise ConfigError("--ray needs the optional Ray extra: `make ray` (or pip install "
                              "-r requirements-ray.txt)") from exc
        self.ray = ray
        self.started = not ray.is_initialized()
        if self.started:
            if address == "local":
                os.environ.setdefault("RAY_AUTH_MODE", "disabled")  # local, loopback only
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False,
                         configure_logging=False)
            else:
                self._connect(address)
        self.remote = ray.remote(num_cpus=1, max_retries=0)(execute_ray_run)
        self.shared: dict[str, Any] = {}

    def _connect(self, address: str) -> None:
        """Join the cluster at ``address``; ConfigError saying so when it cannot."""
        try:
            self.ray.init(address=address, log_to_driver=False, configure_logging=False)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise ConfigError(f"--ray {address}: cannot connect to a Ray cluster there ({exc}); start one "
                              "with `ray start --head` (docs/experiments.md, on a cluster)") from exc

    def share(self, bundle: Bundle):
        """The bundle in the object store, once per content: every task gets a reference."""
        if bundle.digest not in self.shared:
            self.shared[bundle.digest] = self.ray.put(bundle)
        return self.shared[bundle.digest]

    def submit(self, *args):
        return self.remote.remote(*args)

    def wait_any(self, pending: dict) -> list:
        done, _ = self.ray.wait(list(pending), num_returns=1)
        return done

    def outcome(self, ref) -> dict:
        """The task's outcome (:func:`execute_run`); a task Ray could not finish (its worker or
        node died): Ray's error, which names the worker's address."""
        try:
            return self.ray.get(ref)
        except Exception as exc:  # noqa: BLE001 - a failed task: report it, keep the others
            return {"result": None, "error": f"{exc.__class__.__name__}: {exc}",
                    "where": "a Ray worker that did not finish (see the error)"}

    def close(self) -> None:
        if self.started:
            self.ray.shutdown()


def make_pool(workers: int, ray_address: str | None = None):
    """The worker pool of :func:`run_compare`: Ray at ``ray_address``, else local processes."""
    return _RayPool(ray_address, workers) if ray_address else _LocalPool(workers)


def _fmt_seconds(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m{s % 60:02d}s" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


def run_compare(config: str | Path, strategies: list[str], seeds: int, micro_actions: int,
                eval_every: int, out: str | Path, workers: int | None = None,
                ray_address: str | None = None, overrides: dict | None = None,
                base_seed: int | None = None, out_fn: Callable[[str], None] = print,
                pool=None, on_result: Callable[[Path], None] | None = None, run: bool = True) -> dict:
    """Run every (strategy, seed) not finished yet, then write the summary; returns it.
    ``run=False``: run nothing, only summarise the runs finished so far (``sagg reproduce --no-run``).

    ``pool``: an open :func:`make_pool` pool to run on (left open; its workers stay warm for the
    next comparison, as ``sagg reproduce`` does); default: one made and closed here.
    ``on_result``: called with each new ``result.json`` once written (``sagg reproduce --archive``).

    Seeds are ``base_seed + i`` for i in 0..seeds-1; ``base_seed`` defaults to the config's
    ``seed``. Raises ConfigError for bad arguments or a fingerprint mismatch."""
    config = str(config)
    out = Path(out)
    for s in strategies:
        if s not in STRATEGIES:
            raise ConfigError(f"--strategies: unknown strategy {s!r}; allowed: {', '.join(STRATEGIES)}")
    if len(set(strategies)) != len(strategies) or not strategies:
        raise ConfigError("--strategies: give each strategy once (at least one)")
    if seeds < 1:
        raise ConfigError(f"--seeds: got {seeds}; allowed: an integer >= 1")
    if micro_actions < 1 or eval_every < 1:
        raise ConfigError("--micro-actions and --eval-every: allowed: integers >= 1")
    workers = workers or os.cpu_count() or 1
    if workers < 1:
        raise ConfigError(f"--workers: got {workers}; allowed: an integer >= 1")
    overrides = dict(overrides or {})
    for key in ("strategy", "seed"):
        if key in overrides:
            raise ConfigError(f"--set {key}=...: not allowed here; use --strategies / --base-seed")
    if base_seed is None:
        base_seed = int(load_experiment_config(config, overrides)["sagg_learner"]["seed"])
    seed_list = [base_seed + i for i in range(seeds)]
    fp = make_fingerprint(config, strategies, seed_list, micro_actions, eval_every, overrides)
    resuming = check_fingerprint(out, fp)

    # seed by seed, every strategy of a seed before the next seed: an interrupted comparison holds
    # the same seeds for every strategy, so it can already be decided on them
    specs = [RunSpec(st, s) for s in seed_list for st in strategies]
    todo = []
    valid = []  # the runs the summary is made of: finished and matching the settings
    for spec in specs:
        why = validate_result(run_dir(out, spec) / "result.json", spec, micro_actions, eval_every,
                              expected_config(config, spec, overrides))
        if why is None:
            valid.append(spec)
        else:
            if why != "missing":
                out_fn(f"{'rerun' if run else 'left out (--no-run)'} {spec.name}: existing result.json {why}")
            todo.append(spec)
    skipped = len(valid)
    total = len(specs)
    out_fn(f"compare: {len(strategies)} strategies x {seeds} seeds (seeds {seed_list[0]}.."
           f"{seed_list[-1]}) = {total} runs of {micro_actions} micro-actions; "
           + (f"resuming: {skipped} finished run(s) kept and skipped, " if resuming or skipped else "")
           + (f"{len(todo)} not run (--no-run): summarising the finished ones" if not run else
              f"{len(todo)} to run on "
              + (f"Ray ({ray_address})" if ray_address else f"{workers} local worker process(es)")))
    if not run:
        todo = []

    failures: dict[str, str] = {}
    commit = code_commit()  # the code the runs compute with (workers import the same packages)
    if todo:
        own = pool is None
        if own:
            pool = make_pool(workers, ray_address)
        t0 = time.perf_counter()
        done_now = 0
        try:
            task = pool.share(make_bundle(config, overrides))
            pending = {pool.submit(task, sp.strategy, sp.seed, micro_actions, eval_every, overrides): sp
                       for sp in todo}
            while pending:
                for fut in pool.wait_any(pending):
                    spec = pending.pop(fut)
                    outcome = pool.outcome(fut)
                    result, err, where = outcome["result"], outcome["error"], outcome["where"]
                    d = run_dir(out, spec)
                    d.mkdir(parents=True, exist_ok=True)
                    done_now += 1
                    if err is None:
                        write_json_atomic(d / "result.json", {**result, "commit": commit})
                        valid.append(spec)
                        (d / "error.txt").unlink(missing_ok=True)
                        if on_result is not None:
                            on_result(d / "result.json")
                        what = (f"final mean error {result['final_mean_error']:.3f} "
                                f"({result['learn_seconds'] + result['eval_seconds']:.1f} s, on {where})")
                    else:
                        (d / "error.txt").write_text(f"{spec.name} failed on {where}:\n{err}\n")
                        failures[spec.name] = f"{err.strip().splitlines()[-1]} (on {where})"
                        what = f"FAILED: {failures[spec.name]} (see {d / 'error.txt'})"
                    elapsed = time.perf_counter() - t0
                    # ETA from this session's runs only; runs are about equally long per strategy,
                    # and the pool keeps `workers` of them going.
                    eta = elapsed / done_now * (len(todo) - done_now)
                    out_fn(f"[{skipped + done_now}/{total}] {spec.name}: {what}; elapsed "
                           f"{_fmt_seconds(elapsed)}, ETA {_fmt_seconds(eta)}")
        finally:
            if own:
                pool.close()

    summary = write_summary(out, fp, failures, out_fn, valid)
    return summary


def write_summary(out: Path, fp: dict, failures: dict[str, str], out_fn=print,
                  specs: list[RunSpec] | None = None) -> dict:
    """summary.md, summary.json and curves.png from the finished results in ``out`` (only those
    of ``specs`` when given: the runs validated against the settings)."""
    # lazy (heavy): scipy
    from .compare import (curve_table, load_results, pairwise_table, plot_curves, summary_json,
                          summary_markdown)
    results = []
    keep = None if specs is None else set(specs)
    for st in fp["strategies"]:
        for s in fp["seeds"]:
            f = run_dir(out, RunSpec(st, s)) / "result.json"
            if f.exists() and (keep is None or RunSpec(st, s) in keep):
                results.extend(load_results([f]))
    summ = summary_json(results, fp["strategies"])
    summ["settings"] = {k: v for k, v in fp.items() if k != "parameters"}
    summ["failed_runs"] = failures
    write_json_atomic(out / "summary.json", summ)
    title = (f"{Path(fp['config_file']).stem}: {fp['micro_actions']} micro-actions, "
             f"seeds {fp['seeds'][0]}..{fp['seeds'][-1]}")
    md = [f"# {title}", "",
          f"Config `{fp['config_file']}`"
          + (f", overrides {fp['overrides']}" if fp["overrides"] else "")
          + f"; evaluation every {fp['eval_every']} micro-actions; seed i = {fp['seeds'][0]} + i.", ""]
    if failures:
        md += ["**Failed runs** (left out below): " + "; ".join(f"{k}: {v}" for k, v in failures.items()), ""]
    if results:
        md += ["## Test error (mean ± std over seeds) at each evaluation point", "",
               curve_table(summ), "", "## Final test error", "", summary_markdown(results, tests=False), "",
               "## Tests on the final test error, every pair", "", pairwise_table(summ), ""]
        plot_curves(results, out / "curves.png", title)
        md += ["![curves](curves.png)", ""]
    (out / "summary.md").write_text("\n".join(md))
    out_fn(f"wrote {out / 'summary.md'}, {out / 'summary.json'}"
           + (f", {out / 'curves.png'}" if results else "")
           + (f"; {len(failures)} run(s) failed: {', '.join(failures)}" if failures else ""))
    return summ
