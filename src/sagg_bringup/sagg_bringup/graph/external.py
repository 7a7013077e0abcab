"""``sagg run CONFIG --driver external``: the goal generator and the learner against a robot driver
that is already running (your arm's ros2_control stack, a tracker, or ``test/fake_driver.py``).

Like :func:`~sagg_bringup.graph.graph.run_graph` (same session: private ``ROS_DOMAIN_ID`` unless
``--domain-id`` names the driver's, recorder, progress, summary and report), except:

- no bridge is started; before the nodes start, the driver's side of the contract is checked and
  what is missing is named (:class:`~.driver_monitor.DriverMonitor`: topic, type, joint names), every few seconds,
  until ``driver_timeout``;
- the learner's ``joints`` / ``joint_limits`` / ``rest_posture`` are the config's when it sets
  ``joints`` (your arm), else those of the config's simulated arm;
- **evaluation on the robot** (:mod:`.robot_eval`): with learning paused (at the end, the
  learner has stopped at ``max_micro_actions``; in between, ``/sagg/pause``), each test goal is
  reached from rest by the learner's own ``/sagg/reach`` action (:class:`~.reach_client.ReachClient`:
  the learner's model, and its rules for every motion: joint limits, ``max_joint_step``, the scene,
  streamed setpoints within the velocity limits, the stopped-arm hold), and the final distance is
  the learner's measured task point. ``robot_eval_goals`` goals, at the
  end and every ``robot_eval_every`` micro-actions (0: only at the end; real robots are slow), at
  most ``robot_eval_goal_seconds`` s per goal;
- **simulated evaluation**, labelled as such: when the config's simulated arm is the same arm (same
  number of joints, limits and rest posture; :func:`sim_model_matches`), the offline evaluation of
  ``sagg run`` from the recorded samples, on the model's 100 test goals, is given too.

Test goals on the robot: the simulated model's test-goal set (``test_goals(spec, Y, n, eval.seed)``)
when there is one; else (the reachable area is unknown) ``n`` points spread by farthest-point
selection (seeded by ``eval.seed``) over the task points the robot reached before the first
evaluation, which is stated in the summary (``robot_evaluation.goal_source``): such goals are
reachable but not independent of the exploration.
"""
from __future__ import annotations

import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError, read_config
from sagg_common.progress import Progress

from ..inprocess.arm_params import NODES, graph_params
from ..inprocess.evaluator import Evaluator
from ..report.report import arm_rows, write_report
from ..bags.topics import graph_topics
from .arm_run import ArmStreams, plan_arm_run
from .driver_monitor import DriverMonitor, model_task
from .reach_client import ReachClient
from .robot_eval import RobotEvaluation
from .processes import GraphError
from .run_file import write_run_file
from .session import STALL_TIMEOUT, FollowedEvaluation, GraphSession

EXTERNAL_NODES = {k: v for k, v in NODES.items() if k != "sagg_sim_bridge"}
# Seconds between two "waiting for the driver" lines.
WAIT_REPORT_EVERY = 5.0


# ------------------------------------------------------------------------------ parameters
def explicit_joints(config_path: str | Path, overrides: dict[str, Any] | None) -> bool:
    """True when the config (learner section or ``/**``) or an override sets ``joints``: the
    learner then uses the config's joints, limits and rest posture (your arm)."""
    sections = read_config(config_path)
    return any("joints" in sections.get(s, {}) for s in ("/**", "sagg_learner")) or "joints" in (overrides or {})


def external_params(full: dict[str, dict], micro_actions: int, own_joints: bool, spec=None) -> dict[str, dict]:
    """The nodes' parameters for an external driver: :func:`~sagg_bringup.inprocess.arm_params.graph_params`, but
    the learner keeps the config's ``joints`` / ``joint_limits`` / ``rest_posture`` when
    ``own_joints`` (they are checked here, before anything starts); ``spec``: the config's arm, when
    the caller has it."""
    # lazy (heavy): ROS
    from sagg_low_level.node import robot_from_params
    if full["sagg_learner"].get("rest_return") == "direct":
        raise ConfigError("parameter 'rest_return': 'direct' (one command across the range to the rest "
                          "posture) is for the simulated bridge only; allowed with --driver external: 'stepped'")
    params = graph_params(full, micro_actions, "external", spec)
    if own_joints:
        lp = params["sagg_learner"]
        for k in ("joints", "joint_limits.lower", "joint_limits.upper", "rest_posture"):
            lp[k] = full["sagg_learner"][k]
        robot_from_params(lp)  # ConfigError naming the parameter
    return params


def sim_model_matches(learner_params: dict, spec) -> bool:
    """The config's simulated arm (``spec``) is a model of the learner's arm: same number of joints,
    same joint limits and rest posture (to 1e-9 rad). Joint names may differ (a driver names its
    joints its own way); link lengths cannot be checked here, the config states them."""
    lower, upper = spec.limits()
    lp = learner_params
    if len(lp["joints"]) != len(spec.joint_names()):
        return False
    return all(np.allclose(np.asarray(lp[k], float), v, rtol=0.0, atol=1e-9) for k, v in (
        ("joint_limits.lower", lower), ("joint_limits.upper", upper), ("rest_posture", spec.rest_posture())))


def wait_for_driver(session: GraphSession, monitor: DriverMonitor, timeout: float, progress: bool) -> float:
    """Spin until the driver meets the contract; print what is missing every
    :data:`WAIT_REPORT_EVERY` s; GraphError naming it after ``timeout`` s. Returns the seconds waited."""
    t0 = time.monotonic()
    last = None
    while True:
        session.spin()
        missing = monitor.missing(session.node)
        now = time.monotonic()
        if not missing:
            return now - t0
        if now - t0 > timeout:
            raise GraphError(f"the driver did not come up in {timeout:.0f} s; missing:\n  - " + "\n  - ".join(missing))
        if now - t0 > 1.0 and (last is None or now - last >= WAIT_REPORT_EVERY):
            last = now
            if progress:
                print(f"waiting for the driver (ROS_DOMAIN_ID {session.domain}):\n  - " + "\n  - ".join(missing),
                      file=sys.stderr, flush=True)


class Pauser:
    """``/sagg/pause`` (std_srvs/SetBool) from the orchestrator: pause the learner and wait until it
    has stopped acting, or resume it. Stopped: paused in /sagg/status, and neither a new micro-action
    nor a command on the commands topic for ``quiet`` s (the micro-action in flight when the pause
    came completes first: its command, if it reached the driver after ours, would move the arm
    elsewhere; measured under load before this wait)."""

    def __init__(self, session: GraphSession, monitor: DriverMonitor, quiet: float):
        # lazy (heavy): ROS
        from std_srvs.srv import SetBool
        self.session, self.monitor, self.quiet, self._req = session, monitor, quiet, SetBool.Request
        self.client = session.node.create_client(SetBool, "/sagg/pause")

    def set(self, paused: bool, timeout: float = 30.0) -> None:
        fut = self.client.call_async(self._req(data=paused))
        t0 = time.monotonic()
        while not fut.done():
            self.session.spin()
            if time.monotonic() - t0 > timeout:
                raise GraphError("/sagg/pause: no answer from the learner")
        if not paused:
            return
        st, mon = self.session.st, self.monitor
        last = (st.samples, time.monotonic())
        while True:
            self.session.spin()
            now = time.monotonic()
            if st.samples != last[0]:
                last = (st.samples, now)
            paused = st.status is not None and st.status["paused"]
            if paused and now - last[1] > self.quiet and now - mon.cmd_rx > self.quiet:
                return
            if now - t0 > timeout + self.quiet:
                raise GraphError("the learner did not pause")


# ------------------------------------------------------------------------------ the run
def check_robot_eval(robot_eval_goals: int, robot_eval_every: int, robot_eval_goal_seconds: float) -> None:
    """The evaluation on the robot's options; ConfigError naming them."""
    if robot_eval_goals < 1 or robot_eval_every < 0 or not robot_eval_goal_seconds > 0:
        raise ConfigError(f"--robot-eval-goals {robot_eval_goals} / --robot-eval-every {robot_eval_every} / "
                          f"--robot-eval-goal-seconds {robot_eval_goal_seconds}; allowed: goals >= 1, every >= 0, "
                          "seconds > 0")


def run_external_graph(config_path: str | Path, micro_actions: int, out_dir: str | Path, *,
                       seed: int | None = None, strategy: str | None = None, eval_every: int = 1000,
                       overrides: dict[str, Any] | None = None, progress: bool = True,
                       domain_id: int | None = None, stall_timeout: float = STALL_TIMEOUT, report: bool = True,
                       robot_eval_goals: int = 10, robot_eval_every: int = 0,
                       robot_eval_goal_seconds: float = 120.0, driver_timeout: float = 120.0,
                       resume: dict | None = None) -> dict:
    """``sagg run CONFIG --driver external``; returns the summary (also in DIR/summary.json).

    ``resume``: the settings of the stopped run in ``out_dir`` (``sagg run --resume DIR``, on the
    same robot): as :func:`~sagg_bringup.graph.graph.run_graph`'s, the nodes resume from their
    checkpoints and this segment is recorded into the next bag; the learner measures the posture
    and returns to rest first."""
    robot_eval = {"robot_eval_goals": robot_eval_goals, "robot_eval_every": robot_eval_every,
                  "robot_eval_goal_seconds": robot_eval_goal_seconds}
    check_robot_eval(**robot_eval)
    plan = plan_arm_run(config_path, micro_actions, out_dir, nodes=EXTERNAL_NODES, eval_every=eval_every,
                        strategy=strategy, seed=seed, overrides=overrides, domain_id=domain_id,
                        resume=resume is not None,
                        node_params=lambda full, spec, ov: external_params(full, micro_actions,
                                                                           explicit_joints(config_path, ov), spec))
    out, lp, spec = plan.out, plan.lp, plan.spec
    simulated = sim_model_matches(lp, spec)
    if not simulated:
        plan.config.pop("sagg_sim_bridge")  # not a model of this arm: no reachable area, no simulated evaluation
    # the driver runs in the environment's domain and discovery range (not a private one)
    if domain_id is None:
        domain_id = int(os.environ.get("ROS_DOMAIN_ID") or 0)
    # before anything starts: a killed run is known to have learned on this robot (never resumed otherwise)
    write_run_file(out, setup="arm", driver="external", timing="external driver", domain_id=domain_id,
                   domain_private=False, micro_actions=micro_actions, eval_every=eval_every,
                   config=(resume or {}).get("config", config_path),
                   overrides=(resume or {}).get("overrides", plan.overrides), driver_timeout=driver_timeout,
                   **robot_eval)
    # (the driver's state streams go on after the nodes stop: the final drain does not wait for them)
    session = GraphSession(plan.procs, domain_id, graph_topics(lp), plan.bag_path, out, drain=2000, localhost=False)
    try:
        robot_run = RobotRun(session, plan, robot_eval_goals, robot_eval_every, robot_eval_goal_seconds, simulated,
                             progress)
        bar = Progress(micro_actions, f"{lp['strategy']} seed {lp['seed']} (graph, external driver)", enabled=progress)

        def body() -> None:
            if robot_run.evaluator is not None:
                robot_run.evaluator.start()
            robot_run.driver_wait = wait_for_driver(session, robot_run.monitor, driver_timeout, progress)
            session.start_nodes(plan.params_file, robot_run.streams.node_extra())
            session.wait_for_learner(
                micro_actions, stall_timeout, "micro-actions", bar, tick=robot_run.tick,
                may_end=robot_run.evaluation.may_end if robot_run.evaluation is not None else None,
                stall_detail=robot_run.driver_state)
            robot_run.evaluate(session.st.samples, final=True)
            session.final_drain()
    except BaseException:
        session.close()
        raise

    session.run(body, bar, between=robot_run.evaluator.stop if robot_run.evaluator is not None else None)
    summary = robot_run.summary()

    def report_now() -> None:
        path = write_report(summary, out, area=robot_run.area,
                            setup_rows=arm_rows(plan.config.get("sagg_sim_bridge") or {}))
        path.write_text(path.read_text() + robot_report_section(summary))

    return session.finish(summary, report_now if report and summary["curve"] else None)


class RobotRun:
    """The parts of an external-driver run that a simulated one lacks: the driver's monitor (its
    contract, what it measures), the evaluation on the robot (:class:`RobotEvaluation`, at the end
    and every ``every`` micro-actions with learning paused), and, when the config's simulated arm is
    this arm (``simulated``), the offline evaluation of the recorded samples in simulation."""

    def __init__(self, session: GraphSession, plan, n_goals: int, every: int, goal_seconds: float, simulated: bool,
                 progress: bool):
        # lazy (heavy): mujoco
        from sagg_sim_bridge.arms import arm_base_point, arm_reachable_area, arm_test_goals
        self.session, self.plan, self.progress, self.simulated = session, plan, progress, simulated
        lp, spec = plan.lp, plan.spec
        t_lower, t_upper = plan.task_box
        task_topic = lp["task_topic"] if lp["task_topic"].startswith("/") else "/" + lp["task_topic"]
        self.monitor = DriverMonitor(lp, task_topic, model_task(lp))
        self.monitor.subscribe(session.node)
        self.streams = ArmStreams(session, plan)
        self.evaluator = self.streams.resume_evaluation(
            (lambda todo: Evaluator(plan.config["sagg_learner"], spec, todo)) if simulated else None)
        self.evaluation = FollowedEvaluation(session, self.evaluator, progress) if simulated else None
        self.reached: list[np.ndarray] = []  # task points measured while learning (robot test goals)
        self.monitor.on_tip = self._on_tip
        self.streams.record()
        self.client = ReachClient(session.node, session.spin)
        self.area = arm_reachable_area(spec, t_lower, t_upper, seed=lp["eval.seed"]) if simulated else None
        goals = (arm_test_goals(spec, t_lower, t_upper, n=n_goals, seed=lp["eval.seed"], area=self.area)
                 if simulated else None)
        self.robot_eval = RobotEvaluation(lp, self.client, n_goals, every, goals,
                                          arm_base_point(spec) if simulated else None, goal_seconds)
        self.pauser = Pauser(session, self.monitor, lp["settle_timeout"] + 0.5)
        self.driver_wait = float("nan")

    def _on_tip(self, p) -> None:
        if self.session.st.samples and len(self.reached) < 200_000:
            self.reached.append(p[:len(self.plan.lp["task_space.lower"])].copy())

    def driver_state(self) -> str:
        """What the driver lacks now (the stall error's detail)."""
        return "driver: " + ("; ".join(self.monitor.missing(self.session.node)) or "meets the contract")

    def tick(self, now: float) -> bool:
        """The simulated evaluation followed; an evaluation on the robot when one is due (learning
        paused meanwhile: True, the stall clock starts again)."""
        if self.evaluation is not None:
            self.evaluation.tick(now)
        st, total, r = self.session.st, self.plan.micro_actions, self.robot_eval
        done = st.status is not None and st.status["micro_actions"] >= total
        if r.next_at is not None and r.next_at < total and st.samples >= r.next_at \
                and not done:  # (the end has its own)
            self.evaluate(min(st.samples, total), final=False)
            r.next_at += r.every
            return True
        return False

    def evaluate(self, at: int, final: bool) -> None:
        """The evaluation on the robot at ``at`` micro-actions, through the learner's ``/sagg/reach``;
        during learning (not ``final``) with learning paused (each reach ends back where it paused)."""
        session = self.session
        if self.progress:
            print(f"\nevaluating on the robot at {at} micro-actions ({self.robot_eval.n_goals} goals from rest"
                  + (", learning paused)" if not final else ")"), file=sys.stderr, flush=True)
        if not final:  # (each reach then ends back where learning paused: the learner's own return)
            self.pauser.set(True)
        errors = self.robot_eval.run(at, self.reached)
        session.view.set_test_goals(self.robot_eval.goals)
        if not final:
            self.pauser.set(False)
        session.st.last_error = float(errors.mean())

    def summary(self) -> dict:
        """summary.json: the session's keys, the arm's, the robot's evaluation and which curve is which."""
        session, plan, monitor, r = self.session, self.plan, self.monitor, self.robot_eval
        robot_summary = r.summary()
        robot_summary.update(driver_wait_seconds=self.driver_wait, joint_state_rate=DriverMonitor.rate(monitor.js_rx),
                             task_point_rate=DriverMonitor.rate(monitor.tip_rx))
        robot_curve = [{k: c[k] for k in ("micro_actions", "mean_error", "median_error")} for c in r.curve]
        if r.initial_errors is not None:
            e = r.initial_errors
            robot_curve.insert(0, {"micro_actions": 0, "mean_error": float(e.mean()),
                                   "median_error": float(np.median(e))})
        ev = self.evaluator
        if ev is not None and ev.area is not None:
            self.area = ev.area
        sim_curve = sorted(ev.curve, key=lambda c: c["micro_actions"]) if ev is not None else []
        summary = session.summary(
            plan.lp, plan.config, plan.params, plan.params_file, "external driver", plan.micro_actions,
            sim_curve if self.simulated else robot_curve, self.area, plan.t_start, self.streams.prior_samples,
            eval_seconds=(ev.eval_seconds if ev is not None else 0.0) + r.seconds, test_goals=robot_summary["goals"],
            driver="external", robot_evaluation=robot_summary,
            curve_source="simulated (offline, from the recorded samples)" if self.simulated else "on the robot",
            simulated_evaluation=self.simulated, **self.streams.summary_keys())
        if ev is not None:
            summary["test_goals"] = ev.test_goals.tolist() if ev.test_goals is not None else None
        write_json_atomic(plan.out / "robot_evaluation.json", {"summary": robot_summary, "trace": self.client.trace})
        return summary


def robot_report_section(summary: dict) -> str:
    """The report's section on the evaluation on the robot (and which curve is which)."""
    r = summary["robot_evaluation"]
    lines = ["", "## Evaluation on the robot", "",
             f"The frozen model reached {len(r['goals'] or [])} test goals from rest through the driver, learning "
             f"paused ({'every ' + str(r['every']) + ' micro-actions and ' if r['every'] else ''}at the end); "
             f"test goals: {r['goal_source']}. Errors measured by the task-point topic.", "",
             "| micro-actions | mean error (on the robot) | median error | within tolerance |",
             "|---:|---:|---:|---:|",
             f"| 0 (empty model: the arm stays at rest) | {r['initial_mean_error']:.3f} | "
             f"{float(np.median(r['initial_errors'])) if r['initial_errors'] else float('nan'):.3f} | – |"]
    lines += [f"| {c['micro_actions']:,} | {c['mean_error']:.3f} | {c['median_error']:.3f} | "
              f"{c['within_share']:.0%} |" for c in r["curve"]]
    frame = r.get("eval_metrics")
    if frame and r["curve"]:
        bands = r["curve"][-1]["band_mean_errors"]
        edges = frame["band_edges"]
        lines += ["", f"Within tolerance: within {frame['within']:.3g} (2 % of R = {frame['radius']:.3g}, the "
                  "farthest test goal from the base). Final mean error per distance-from-base band: "
                  + "; ".join(f"{a:.3g}-{b:.3g} ({c} goals): {'–' if e is None else f'{e:.3f}'}"
                              for a, b, c, e in zip(edges, edges[1:], frame["band_counts"], bands)) + "."]
    lines += ["", f"Joint states at {r['joint_state_rate']:.0f}/s, task points at {r['task_point_rate']:.0f}/s; "
              f"{r['steps']} reaching steps through the learner's /sagg/reach in {r['seconds']:.1f} s "
              f"({r['goals_timed_out']} goals cut at {r['goal_seconds']:g} s).", ""]
    if summary.get("simulated_evaluation"):
        lines += ["The learning curve above is the **simulated** evaluation (offline, the recorded samples "
                  "in the config's simulated model of the same arm, on its test goals).", ""]
    else:
        lines += ["The config's simulated arm is not this arm (joints, limits or rest posture differ): "
                  "no simulated evaluation; the learning curve above is the evaluation on the robot.", ""]
    return "\n".join(lines)
