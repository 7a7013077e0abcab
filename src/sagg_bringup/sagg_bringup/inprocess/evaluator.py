"""The evaluation process of an evolving-context arm run (``sagg run``; ``sagg relearn`` uses its
set-up): the memory rebuilt from ``/sagg/sample`` and the frozen model evaluated on its own
simulator, exactly as :meth:`~sagg_bringup.inprocess.experiment.InProcessRun.evaluate`."""
from __future__ import annotations

import multiprocessing
import os
import queue
import signal
import threading
import time

import numpy as np

from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame
from sagg_low_level.learner import EvolvingContextLearner, Robot
from sagg_low_level.memory import SampleMemory

# Niceness of the evaluation process: a mild preference for the graph (the nodes, and this
# process's DDS threads receiving the recorded topics). The evaluation is a separate process: in a
# thread of this process at normal priority it makes the recorder lose bursts of /<controller>/commands
# messages on a small machine (GIL + CPU contention; the learner's writer keeps only 10). A high
# niceness starves the evaluation on a busy machine (the live test error then lags far behind).
EVAL_NICE = 5


def evaluation_setup(learner_params: dict, spec, memory=None):
    """``(area, test_goals, learner)`` of a run's evaluation on the arm ``spec``, as
    ``run_experiment`` computes them (``test_goals(spec, Y, n=eval.goals, seed=eval.seed)``); the
    learner (empty memory, or ``memory``) is built exactly as the learner node builds its own
    (same neighbour search). Used by ``sagg run``'s evaluator, ``sagg relearn`` and ``sagg reach``."""
    # lazy (heavy): mujoco
    from sagg_sim_bridge.arms import arm_reachable_area, arm_scene_checker, arm_test_goals
    lp = learner_params
    area = arm_reachable_area(spec, lp["task_space.lower"], lp["task_space.upper"], seed=lp["eval.seed"])
    goals = arm_test_goals(spec, lp["task_space.lower"], lp["task_space.upper"], n=lp["eval.goals"],
                           seed=lp["eval.seed"], area=area)
    lower, upper = spec.limits()
    robot = Robot(spec.joint_names(), lower, upper, spec.rest_posture())
    learner = EvolvingContextLearner(lp, robot, len(lp["task_space.lower"]), memory=memory)
    learner.scene = arm_scene_checker(spec)  # (its reaches meet the scene as the learner node's do)
    return area, goals, learner


def evaluate_frozen(learner, spec, learner_params: dict, goals: np.ndarray) -> np.ndarray:
    """Test errors of the frozen model, as ``InProcessRun.evaluate`` (``arm_eval.evaluate_arm``)."""
    # lazy (heavy): mujoco
    from .arm_eval import evaluate_arm
    return evaluate_arm(learner, spec, learner_params["seed"], goals)


def _exit_with_parent() -> None:
    """In the evaluation process: a daemon thread that ends the process as soon as the process that
    started it has died. `sagg run` stops it with a message; a `sagg run` killed with SIGKILL (the
    OOM killer, ``kill -9``, a caller's timeout) cannot, and the queues never close (this process
    holds both ends of them): without this it would wait for ever, holding its memory."""
    parent = multiprocessing.parent_process()
    if parent is None:
        return

    def watch() -> None:
        parent.join()
        os._exit(0)

    threading.Thread(target=watch, name="sagg-evaluator-parent", daemon=True).start()


def _eval_worker(inbox, outbox, learner_params: dict, spec, checkpoints: list[int],
                 nice: int) -> None:
    """Evaluation process: computes the reachable area and the test goals (as ``run_experiment``
    does: ``test_goals(spec, Y, n=eval.goals, seed=eval.seed)``), then rebuilds the memory from the
    sample batches in ``inbox`` and, whenever it holds exactly a checkpoint's number of samples,
    evaluates the frozen model as ``InProcessRun.evaluate`` does (fresh
    ``ArmSim(spec, substream_seed(seed, "eval_sim"))``). Sends ``("area", ...)``, then
    ``("eval", at, errors, seconds)`` per checkpoint, or ``("error", text)``, to ``outbox``. Ends
    at ``("stop",)``, or at once when its parent has died (:func:`_exit_with_parent`)."""
    _exit_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # `sagg run` stops us (a terminal Ctrl-C reaches us too)
    try:
        os.nice(nice)
    except OSError:
        pass
    try:
        area, goals, learner = evaluation_setup(learner_params, spec)
        outbox.put(("area", area.lower, area.upper, area.resolution, area.mask, area.cell_points, goals))
        memory = learner.memory
        pending = sorted(set(checkpoints))

        def due() -> None:
            while pending and len(memory) == pending[0]:
                at = pending.pop(0)
                t0 = time.perf_counter()
                errors = evaluate_frozen(learner, spec, learner_params, goals)
                outbox.put(("eval", at, errors, time.perf_counter() - t0))

        while True:
            due()
            item = inbox.get()
            if item[0] == "stop":
                return
            _, start, alpha, dalpha, dy = item
            if start != len(memory):
                raise RuntimeError(f"sample batch starts at {start} but {len(memory)} samples were rebuilt")
            for i in range(len(alpha)):
                learner.store(alpha[i], dalpha[i], dy[i])
                due()
    except Exception as exc:  # noqa: BLE001 - reported by the orchestrator
        outbox.put(("error", f"{type(exc).__name__}: {exc}"))


class Evaluator:
    """The run's evaluation, in a separate process (its own GIL: the recorder in this process keeps
    up) at a lower CPU priority than the graph. Samples from /sagg/sample are checked for order,
    batched and shipped to it; results come back through :meth:`poll`."""

    def __init__(self, learner_params: dict, spec, checkpoints: list[int],
                 nice: int = EVAL_NICE):
        ctx = multiprocessing.get_context("spawn")  # never fork a process that runs DDS threads
        self.inbox, self.outbox = ctx.Queue(), ctx.Queue()
        self.proc = ctx.Process(target=_eval_worker, name="sagg-evaluator", daemon=True,
                                args=(self.inbox, self.outbox, learner_params, spec,
                                      list(checkpoints), nice))
        # lazy (heavy): mujoco
        from sagg_sim_bridge.arms import arm_base_point
        self.base = arm_base_point(spec)  # the arm's base (distance bands of the metrics)
        self.area = None  # the ReachableArea of Y, once the worker has computed it
        self.test_goals: np.ndarray | None = None
        self._frame: dict | None = None  # eval_metrics.metric_frame of the test goals, with them
        self.checkpoints = sorted(set(checkpoints))
        self.curve: list[dict] = []
        self.errors: dict[int, np.ndarray] = {}
        self.eval_seconds = 0.0
        self.error: str | None = None
        self.samples = 0  # samples received (in order) so far
        self._batch: list[tuple] = []
        self._sent = 0
        # this process's copy of the samples: the memory digest of the summary
        self.alpha: list[np.ndarray] = []
        self.delta_alpha: list[np.ndarray] = []
        self.delta_y: list[np.ndarray] = []

    def start(self) -> None:
        self.proc.start()

    def add(self, index: int, alpha, delta_alpha, delta_y) -> None:
        if index != self.samples:
            if self.error is None:
                self.error = (f"/sagg/sample index {index} received after {self.samples} samples: samples "
                              "were lost or reordered")
            return
        self.samples += 1
        self.alpha.append(alpha)
        self.delta_alpha.append(delta_alpha)
        self.delta_y.append(delta_y)

    def flush(self) -> None:
        """Ship the samples received since the last flush (non-blocking: a feeder thread sends)."""
        if self._sent < self.samples:
            a, b = self._sent, self.samples
            self.inbox.put(("samples", a, np.array(self.alpha[a:b]), np.array(self.delta_alpha[a:b]),
                            np.array(self.delta_y[a:b])))
            self._sent = b

    def poll(self) -> list[tuple[int, np.ndarray]]:
        """Evaluations finished since the last call, as ``(micro_actions, errors)``."""
        done = []
        while True:
            try:
                item = self.outbox.get_nowait()
            except queue.Empty:
                break
            if item[0] == "error":
                self.error = item[1]
                continue
            if item[0] == "area":
                # lazy (heavy): mujoco
                from sagg_sim_bridge.arm import ReachableArea
                self.area = ReachableArea(*item[1:6])
                self.test_goals = item[6]
                # the evaluation's metrics (eval_metrics, as in-process; bands from the arm's base),
                # also for points evaluated before (a resumed run's, from its bags)
                self._frame = metric_frame(self.test_goals, self.base)
                for c in self.curve:
                    c.update(error_metrics(self.errors[c["micro_actions"]], self._frame))
                continue
            _, at, errors, secs = item
            self.eval_seconds += secs
            self.errors[at] = errors
            self.curve.append({"micro_actions": int(at), "mean_error": float(errors.mean()),
                               "median_error": float(np.median(errors))})
            if self._frame is not None:
                self.curve[-1].update(error_metrics(errors, self._frame))
            done.append((at, errors))
        if self.error is None and not self.proc.is_alive() and self.proc.exitcode not in (None, 0):
            self.error = f"evaluation process exited with code {self.proc.exitcode}"
        return done

    def metrics(self) -> dict | None:
        """The metric frame of the test goals without the per-goal bands (result.json's
        ``eval_metrics``: R, the tolerance, the band edges), None before the test goals exist."""
        return None if self._frame is None else frame_summary(self._frame)

    def finished(self, upto: int) -> bool:
        """Every checkpoint up to ``upto`` micro-actions is evaluated."""
        return all(c in self.errors for c in self.checkpoints if c <= upto)

    def stop(self, timeout: float = 1.0) -> None:
        """Stop the process: it exits at once when idle (every checkpoint done: the end of a run);
        one still evaluating (a failed or interrupted run, whose results nobody reads any more) is
        killed after ``timeout`` s."""
        try:
            self.inbox.put(("stop",))
        except (OSError, ValueError):
            pass
        self.proc.join(timeout)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        for q in (self.inbox, self.outbox):
            q.cancel_join_thread()
            q.close()


def memory_info(alpha: list, delta_alpha: list, delta_y: list) -> dict:
    """summary.json's ``memory`` of samples received in order (lists of vectors): their count and
    the digest and size of a SampleMemory holding them (the learner's own class, so the digest
    equals its memory's)."""
    if not alpha:
        return {"samples": 0}
    mem = SampleMemory(len(alpha[0]), len(delta_alpha[0]), len(delta_y[0]), capacity=len(alpha))
    for a, da, dy in zip(alpha, delta_alpha, delta_y):
        mem.add(a, da, dy)
    return {"samples": len(mem), "digest": mem.digest(), "bytes": int(mem.nbytes)}
