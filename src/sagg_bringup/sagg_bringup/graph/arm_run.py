"""What every ``sagg run`` of the evolving-context arm shares, whatever drives the arm (the simulated
bridge: :mod:`.graph`; a robot's driver: :mod:`.external`): the plan of the run directory (the
resolved parameters, params.yaml, the bag segment, a resumed run's earlier bags), the arm's
recorded streams (samples, goals, reports, regions, status) fed to the run's state, its split
tracker and its evaluation, and the summary's arm keys. Each runner adds its own parts: which
nodes it starts, on which domain, and how it evaluates.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from sagg_common.params import ConfigError

from ..bags.bag_reader import bag_messages
from ..bags.bag_recover import recover_run_bags
from ..bags.recorder import msg_class
from ..inprocess.arm_params import core_config, resolve_arm
from ..inprocess.evaluator import memory_info
from ..inprocess.results import run_overrides
from .params_files import run_bags, run_only_params, set_checkpoint_dirs, write_params_file
from .prior_source import own_prior_files
from .processes import check_domain_id, node_processes
from .resume_check import compare
from .split_tracker import SplitTracker

# the topics a resumed run reads back from its earlier bags
PRIOR_TOPICS = frozenset({"/sagg/sample", "/sagg/goal", "/sagg/competence", "/sagg/regions", "/sagg/evaluation"})


@dataclass
class ArmPlan:
    """One arm run's directory and parameters, decided before anything starts (:func:`plan_arm_run`)."""

    out: Path
    full: dict               # every node's resolved parameters (full schemas)
    spec: Any                # the config's simulated arm
    overrides: dict          # --set, --seed, --strategy as given
    params: dict             # what the nodes get (params.yaml plus the run-only values)
    params_file: Path
    config: dict             # the core parameters (summary.json's ``config``)
    micro_actions: int
    eval_every: int
    segment: int             # 1, or k for the k-th segment of a resumed run (bag<k>, logs <node>.<k>.log)
    bag_path: Path
    prior_bags: list = field(default_factory=list)   # a resumed run's earlier bags, in order
    recovered: list = field(default_factory=list)    # what recovering its unfinished bags reported
    procs: list = field(default_factory=list)        # the node processes (not started)
    t_start: float = 0.0

    @property
    def lp(self) -> dict:
        """The learner node's parameters."""
        return self.params["sagg_learner"]

    @property
    def task_box(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.lp["task_space.lower"]), np.asarray(self.lp["task_space.upper"])

    @property
    def checkpoints(self) -> list[int]:
        """The evaluation points: every ``eval_every`` micro-actions and the end."""
        return list(range(0, self.micro_actions, self.eval_every)) + [self.micro_actions]


def plan_arm_run(config_path: str | Path, micro_actions: int, out_dir: str | Path, *, nodes: dict,
                 node_params: Callable[[dict, Any, dict], dict], eval_every: int = 1000,
                 strategy: str | None = None, seed: int | None = None, overrides: dict | None = None,
                 domain_id: int | None = None, resume: bool = False) -> ArmPlan:
    """Check the options, resolve the config, pick the bag segment (``resume``: an unfinished bag of
    the run is recovered first, and the earlier bags are read back later), write params.yaml.
    ``node_params(full, spec, overrides)``: the runner's parameters for ``nodes``."""
    ov = run_overrides(micro_actions, eval_every, strategy, seed, overrides)
    check_domain_id(domain_id)
    full, spec = resolve_arm(config_path, ov)  # (the one arm_spec_from_params of the run)
    out = Path(out_dir)
    recovered = recover_run_bags(out, lambda line: print(line, file=sys.stderr, flush=True)) if resume else []
    prior_bags = run_bags(out) if resume else []
    if resume and not prior_bags:
        raise ConfigError(f"--resume: '{out}' holds no bag; allowed: the directory of a `sagg run`")
    if not resume and (out / "bag").exists():
        raise ConfigError(f"--out: '{out}' already holds a bag; allowed: a new or empty directory "
                          "(or --resume DIR to continue that run)")
    segment = len(prior_bags) + 1
    while (out / ("bag" if segment == 1 else f"bag{segment}")).exists():
        segment += 1  # (a bag after an unrecoverable one: kept, not read)
    procs = node_processes(nodes, out / "logs", segment)
    t_start = time.perf_counter()
    params = node_params(full, spec, ov)
    notes = set_checkpoint_dirs(params, out, resume) + (own_prior_files([full, params], out) if resume else [])
    for note in notes:
        print(f"sagg run: {note}", file=sys.stderr)
    params_file = out / "params.yaml"
    write_params_file(params_file, params)
    return ArmPlan(out, full, spec, ov, params, params_file, core_config(full), int(micro_actions), int(eval_every),
                   segment, out / ("bag" if segment == 1 else f"bag{segment}"), prior_bags, recovered, procs, t_start)


class ArmStreams:
    """The arm's recorded streams in one run: each sample checked (``RunState.accept_sample``) and
    handed to the evaluation (``evaluator``: an :class:`~sagg_bringup.inprocess.evaluator.Evaluator`,
    or None, then the samples are kept here for the memory digest), goals, reports and status to
    the run's state, region trees to the split tracker. A resumed run's earlier bags are replayed
    into them first (:meth:`read_prior`, :meth:`replay_prior`), and compared with the checkpoints
    (:meth:`node_extra`)."""

    def __init__(self, session, plan: ArmPlan, evaluator=None):
        self.session, self.plan, self.evaluator = session, plan, evaluator
        st = session.st
        self.st = st
        t_lower, t_upper = plan.task_box
        st.task_lower, st.task_upper = t_lower, t_upper
        self.tracker = SplitTracker(t_lower, t_upper)
        self._check = st.arm_sample_check(plan.lp, len(t_lower))
        self.samples: tuple[list, list, list] = ([], [], [])  # (without an evaluator: kept here)
        self.prior_samples = 0   # samples of the earlier segments (not in this segment's rate)
        self.resume = None       # the resume check (resume_check.compare), when resumed
        self._prior: list = []   # the earlier segments' messages (read_prior)

    def on_sample(self, m) -> bool | None:
        ok = self.st.accept_sample(m, self._check)
        if ok:
            a, da, dy = np.array(m.alpha), np.array(m.delta_alpha), np.array(m.delta_y)
            if self.evaluator is not None:
                self.evaluator.add(int(m.index), a, da, dy)
            else:
                for kept, v in zip(self.samples, (a, da, dy)):
                    kept.append(v)
        return ok

    def on_regions(self, m) -> bool:
        st = self.st
        if st.last_regions is not None and int(m.reports) < int(st.last_regions.reports):
            return True  # a resumed generator's checkpoint, older than the bags' last tree (then the same trees again)
        st.last_regions = m
        self.tracker.update([(int(r.id), r.lower, r.upper) for r in m.regions], int(m.goals))
        return True

    def handlers(self) -> dict[str, Callable]:
        st = self.st
        return {"/sagg/sample": self.on_sample, "/sagg/goal": st.on_goal, "/sagg/competence": st.on_report,
                "/sagg/regions": self.on_regions, "/sagg/status": st.on_status}

    def read_prior(self) -> dict[int, np.ndarray]:
        """A resumed run: read the earlier segments' bags (for :meth:`replay_prior`); returns their
        evaluations (micro-actions -> errors: not repeated)."""
        # lazy (heavy): ROS
        from rclpy.serialization import deserialize_message
        from sagg_msgs.msg import Evaluation
        self._prior = list(bag_messages(self.plan.prior_bags, PRIOR_TOPICS)) if self.plan.prior_bags else []
        return {int(em.micro_actions): np.array(em.errors) for em in
                (deserialize_message(bytes(raw), Evaluation) for topic, _, _, raw in self._prior
                 if topic == "/sagg/evaluation")}

    def resume_evaluation(self, make_evaluator: Callable[[list[int]], Any] | None) -> Any:
        """A resumed run's earlier segments read back (:meth:`read_prior`) and replayed
        (:meth:`replay_prior`) into the evaluation that ``make_evaluator(checkpoints to do)`` makes
        (None: no evaluation); the earlier segments' evaluations are kept in it, not repeated.
        Returns the evaluator (or None)."""
        done = self.read_prior()
        evaluator = None
        if make_evaluator is not None:
            checkpoints = self.plan.checkpoints
            evaluator = make_evaluator([c for c in checkpoints if c not in done])
            evaluator.checkpoints = sorted(set(checkpoints))
            for at, errors in sorted(done.items()):
                evaluator.errors[at] = errors
                evaluator.curve.append({"micro_actions": at, "mean_error": float(errors.mean()),
                                        "median_error": float(np.median(errors))})
            self.evaluator = evaluator
        self.replay_prior()
        return evaluator

    def replay_prior(self) -> None:
        """The earlier segments' messages through the handlers (to the evaluation set by then)."""
        if not self._prior:
            return
        # lazy (heavy): ROS
        from rclpy.serialization import deserialize_message
        handlers = self.handlers()
        for topic, msgtype, _, raw in self._prior:
            if topic in handlers:
                handlers[topic](deserialize_message(bytes(raw), msg_class(msgtype)))
        self._prior = []
        self.st.sample_t0 = self.st.sample_t1 = None  # rates: this segment only
        self.prior_samples = self.st.samples

    def node_extra(self) -> dict[str, dict]:
        """What the nodes get on their command lines: the run-only values, and for a resumed run the
        sample the learner republishes from (what the bags lack of its checkpoint, named)."""
        extra = run_only_params(self.plan.params)
        if self.plan.prior_bags:
            st, params = self.st, self.plan.params
            self.resume = compare(st.samples, st.reports, len(st.goals),
                                  params["sagg_learner"].get("checkpoint_dir", ""),
                                  params["sagg_goal_generator"].get("checkpoint_dir", ""))
            extra.setdefault("sagg_learner", {})["republish_from"] = self.resume["republish_from"]
            for line in self.resume["lines"] + [f"warning: {u}" for u in self.resume["unresolved"]]:
                print(f"--resume: {line}", file=sys.stderr, flush=True)
        return extra

    def record(self) -> None:
        """Record every topic into the session's bag through these handlers, with acknowledgements."""
        self.session.record(self.handlers())
        self.session.acknowledge(lambda: self.st.samples)  # the samples recorded and accepted, from index 0

    def received(self) -> tuple[list, list, list]:
        """The samples accepted so far, in order: (α, Δα, Δy) lists."""
        ev = self.evaluator
        return (ev.alpha, ev.delta_alpha, ev.delta_y) if ev is not None else self.samples

    def memory(self) -> dict:
        """summary.json's ``memory``: the learner's samples as the run received them (size, digest)."""
        return memory_info(*self.received())

    def summary_keys(self) -> dict:
        """The summary keys every arm run has beyond the session's."""
        plan, session = self.plan, self.session
        bag_topics = session.bag.topics()
        rec = session.recorder
        span = {t: (rec.last_ns[t] - rec.first_ns[t]) / 1e9 for t in rec.first_ns}
        bag = session.bag_summary(list(plan.prior_bags) + [plan.bag_path], self.st.gaps)
        if self.resume is not None:
            bag.update(recovered=plan.recovered, resume_check=self.resume)
        return {"eval_every": plan.eval_every, "resumed_segments": plan.segment - 1,
                "startup_seconds": session.startup_seconds(), "memory": self.memory(), "splits": self.tracker.splits,
                "bag": bag, "rates": {t: (bag_topics[t]["count"] - 1) / s for t, s in span.items() if s > 0}}
