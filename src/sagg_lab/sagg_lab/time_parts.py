"""Where the CPU time of a learning window, or of one evaluation, goes::

    python -m sagg_lab.time_parts --config config/arm15.yaml --strategy actuator-riac \\
        --start 180000 --stop 200000 [--eval] [--set NAME=VALUE]

One in-process run is learned to ``--start``. Then, without ``--eval``, the learning from
``--start`` to ``--stop`` is timed twice: the first half as is (the rate), the second half with the
main parts wrapped in CPU-time counters (``time.process_time``; the wrappers add a little); with
``--eval``, the run is learned to ``--stop`` and its batched evaluation on the config's test goals is
timed with the counters (best of 3; evolving-context arms only). A fixed-context run (``--set
context=fixed``, or a synergy set-up) counts experiments instead of micro-actions, with its own
parts (Alg. 4's searches, the least-spread set, the local inverse, the exploration noise, ...).
Parts nest (a region tree's split is inside its ``add``, the RIAC compatible leaves inside the RIAC
action choice): the shares do not sum to 100 %.
"""
from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict

import numpy as np

from sagg_common import regions
from sagg_common.params import parse_set
from sagg_low_level import fixed_context, learner as learner_mod, memory, memory_search, reach_batch, riac_leaves
from sagg_low_level.stored_knn import StoredKnn
from sagg_low_level.tree_knn import TreeKnn
from sagg_low_level.evaluate import evaluate_batch
from sagg_sim_bridge.arm import ArmSim, test_goals

from sagg_bringup.inprocess.arm_eval import eval_arms
from sagg_bringup.inprocess.experiment import InProcessRun, cached_reachable_area
from sagg_bringup.graph.setups import in_process_run


class Counters:
    """CPU seconds and calls per label, of the functions :meth:`wrap` replaced (until
    :meth:`restore`)."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._wrapped: list[tuple[object, str, object, bool]] = []

    def wrap(self, owner, name: str, label: str) -> None:
        f = getattr(owner, name)
        self._wrapped.append((owner, name, f, name in vars(owner)))
        setattr(owner, name, self._timed(f, label))

    def _timed(self, f, label: str):
        """``f``, its calls timed (process time) and counted under ``label``."""
        def timed(*args, **kwargs):
            t = time.process_time()
            try:
                return f(*args, **kwargs)
            finally:
                self.seconds[label] += time.process_time() - t
                self.calls[label] += 1
        return timed

    def wrap_factory(self, owner, name: str, label: str) -> None:
        """Like :meth:`wrap` for a function that returns a function (e.g. a competence toward one
        goal): the calls of what it returns are timed under ``label``."""
        make = getattr(owner, name)
        self._wrapped.append((owner, name, make, name in vars(owner)))

        def timed_factory(*args, **kwargs):
            return self._timed(make(*args, **kwargs), label)

        setattr(owner, name, timed_factory)

    def clear(self) -> None:
        self.seconds.clear()
        self.calls.clear()

    def restore(self) -> None:
        """Put the wrapped functions back (the last wrapped first)."""
        for owner, name, f, own in reversed(self._wrapped):
            if own:
                setattr(owner, name, f)
            else:  # it was inherited (or a class attribute seen through an instance)
                delattr(owner, name)
        self._wrapped.clear()


def goal_side_parts(c: Counters, run) -> None:
    """The goal generator's parts, the same in both contexts: its region trees (the goal tree, and
    ACTUATOR-RIAC's tree, which also goes through ``RegionTree.add``) and its goal choice."""
    c.wrap(regions.RegionTree, "add", "region tree add (goal tree and RIAC tree)")
    c.wrap(regions.RegionTree, "_split", "region tree splits (inside region tree add)")
    c.wrap(regions.RegionTree, "interests", "goal tree interests (goal choice)")
    c.wrap(run.generator, "next_goal", "goal generator next_goal")


def learning_parts(c: Counters, run: InProcessRun) -> None:
    c.wrap(memory_search.KnnSearch, "_knn_approx", "neighbour search (approximate)")
    c.wrap(learner_mod, "jacobian", "least squares (local Jacobian, compiled)")
    c.wrap(learner_mod, "reach_step", "reaching step (pinv / damped / clamped, compiled)")
    c.wrap(learner_mod, "desired_displacement", "desired displacement")
    c.wrap(learner_mod, "safe_target", "safe target (step bound, limits)")
    c.wrap_factory(learner_mod.EvolvingContextLearner, "competence_toward", "competence")
    c.wrap(learner_mod.EvolvingContextLearner, "_report", "report to the goal generator (incl. its tree add)")
    c.wrap(memory.SampleMemory, "add", "memory add (incl. index builds)")
    c.wrap(riac_leaves.RiacLeaves, "compatible", "RIAC compatible leaves")
    c.wrap(run.learner, "_riac_choice", "RIAC action choice (incl. compatible)")
    c.wrap(run.sim, "command", "simulator")
    goal_side_parts(c, run)


def fixed_parts(c: Counters, run) -> None:
    """The parts of a fixed-context run (Alg. 1 + Alg. 4, fixed_context.FixedContextLearner)."""
    learner = run.learner
    c.wrap(learner.y_index, "query", "outcome searches (l nearest of a goal, closest y)")
    c.wrap(StoredKnn, "query", "θ searches (the l seeds' m nearest θ, Alg. 4)")
    c.wrap(TreeKnn, "_update", "search index upkeep (tree rebuilds, recent samples)")
    c.wrap(fixed_context, "least_spread_set", "least-spread set (Sec. 4.4.1)")
    c.wrap(fixed_context, "local_inverse", "local inverse (least squares + pinv, compiled)")
    c.wrap(fixed_context, "exploration_theta", "exploration noise (Sec. 4.4.2)")
    c.wrap_factory(fixed_context.FixedContextLearner, "competence_toward", "competence")
    c.wrap(fixed_context.FixedContextLearner, "distance", "distances to the goal")
    c.wrap(fixed_context.FixedContextLearner, "_report", "report to the goal generator (incl. its tree add)")
    c.wrap(fixed_context.FixedContextLearner, "add_sample", "memory add (both tables)")
    c.wrap(run.setup, "execute", "the experiment (synergy command, simulator)")
    goal_side_parts(c, run)


def eval_parts(c: Counters) -> None:
    c.wrap(reach_batch, "neighbours_many", "neighbour search (batched)")
    c.wrap(reach_batch, "jacobians", "least squares (one per distinct set)")
    c.wrap(reach_batch, "compiled_steps", "reaching steps (compiled)")
    c.wrap(ArmSim, "command", "robot commands")



def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sagg_lab.time_parts", description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default="config/arm15.yaml")
    ap.add_argument("--strategy", default="sagg-riac")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--start", type=int, default=0)
    ap.add_argument("--stop", type=int, default=5000)
    ap.add_argument("--eval", action="store_true", help="time one evaluation at --stop instead of learning")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args(argv)
    ov = parse_set(a.set)
    run = in_process_run(a.config, dict(ov, strategy=a.strategy, seed=a.seed))
    if a.eval and not isinstance(run, InProcessRun):
        ap.error("--eval times the evolving-context arm's evaluation (InProcessRun)")
    c = Counters()
    run.step_until(a.start)
    try:
        seconds, calls, total, unit, per = _measure(a, run, c)
    finally:
        c.restore()
    print(f"| part | CPU s | share | {per} | calls |")
    print("|---|---|---|---|---|")
    for label, s in sorted(seconds.items(), key=lambda kv: -kv[1]):
        print(f"| {label} | {s:.3f} | {100 * s / total:.1f} % | {s / unit:.2f} | {calls[label]} |")
    print("load average (1, 5, 15 min): " + ", ".join(f"{x:.2f}" for x in os.getloadavg()))
    return 0


def _measure(a, run, c: Counters):
    """Time the learning window or the evaluation of ``a`` (see the module docstring)."""
    if a.eval:
        t = time.process_time()
        run.step_until(a.stop)
        learn = time.process_time() - t
        lp = run.config["sagg_learner"]
        lower, upper = np.asarray(lp["task_space.lower"]), np.asarray(lp["task_space.upper"])
        area = cached_reachable_area(run.spec, lower, upper, lp["eval.seed"])
        goals = test_goals(run.spec, lower, upper, n=lp["eval.goals"], seed=lp["eval.seed"], area=area)
        eval_arms(run.spec, run.seed, len(goals))
        eval_parts(c)
        best = None
        for _ in range(3):
            c.clear()
            t = time.process_time()
            evaluate_batch(run.learner, eval_arms(run.spec, run.seed, len(goals)), goals)
            total = time.process_time() - t
            if best is None or total < best[0]:
                best = (total, dict(c.seconds), dict(c.calls))
        total, seconds, calls = best
        print(f"{a.config} {a.strategy} seed {a.seed}: learning {a.start}-{a.stop} {learn:.2f} CPU-s; one evaluation "
              f"{total:.2f} CPU-s = {total / learn:.2f} x that learning (best of 3)")
        unit, per = learn, "x learning"
    else:
        half = a.start + (a.stop - a.start) // 2
        t = time.process_time()
        run.step_until(half)
        plain = time.process_time() - t
        evolving = isinstance(run, InProcessRun)
        (learning_parts if evolving else fixed_parts)(c, run)
        t = time.process_time()
        run.step_until(a.stop)
        total = time.process_time() - t
        seconds, calls = c.seconds, c.calls
        n = a.stop - half
        what = "micro-action" if evolving else "experiment"
        print(f"{a.config} {a.strategy} seed {a.seed}: {a.start}-{half} {(half - a.start) / plain:,.0f} {what}s "
              f"per CPU-s; {half}-{a.stop} with counters {total:.2f} CPU-s")
        unit, per = n / 1e6, f"us per {what}"
    return seconds, calls, total, unit, per


if __name__ == "__main__":
    raise SystemExit(main())
