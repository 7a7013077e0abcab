"""``sagg check-driver CONFIG``: check a running driver against the hardware contract before learning.

With the learner's parameters of ``CONFIG`` (``joints``, limits, rest posture, controller, task
topic, ``observation_delay``, ``settle_velocity``; the simulated arm's when the config sets no
``joints``), it

1. waits for the contract (:class:`~sagg_bringup.graph.driver_monitor.DriverMonitor`: ``/joint_states`` and the
   task topic published with the right types and every joint named, a subscriber on the commands);
2. listens at rest for ``--seconds``: publish rates, the delay between a message's stamp and its
   arrival (same clock assumed), the name mapping (each learner joint's index in the message), and
   the noise (standard deviation of each joint position and of the task point);
3. moves one joint by ``--step`` rad (at most ``max_joint_step``, inside the limits), holding the
   others where they are: time to the first joint state that shows the move, time to settled,
   the measured displacement of that joint and of every other joint (a wrong name mapping or
   command order moves another joint), and the task point's displacement; then moves it back;
4. prints the report and the ``observation_delay`` / ``joint_state_timeout`` it suggests.

Exit code 0 when the contract holds and only the moved joint moved (by 50-150 % of the step),
1 otherwise (each problem named), 2 for a bad config.
"""
from __future__ import annotations

import os
import signal
import sys
import time

import numpy as np

from sagg_common.params import ConfigError
from sagg_common.publishers import describe
from sagg_common.ros_params import HW_DEPTH, reliable
from sagg_common.sources import with_message_info

from .driver_monitor import DriverMonitor, model_task
from .external import explicit_joints, external_params
from ..inprocess.arm_params import load_graph_config


def learner_params(config: str) -> dict:
    full = load_graph_config(config)
    return external_params(full, 0, explicit_joints(config, None))["sagg_learner"]


class _Probe:
    """The monitor plus per-message records (receive time, stamp, mapped positions, tip)."""

    def __init__(self, lp: dict):
        task = lp["task_topic"] if lp["task_topic"].startswith("/") else "/" + lp["task_topic"]
        self.mon = DriverMonitor(lp, task, model_task(lp))
        self.js: list[tuple[float, int, np.ndarray | None]] = []
        self.tips: list[tuple[float, int, np.ndarray]] = []
        self.index: list[int] | None = None
        self.m = len(lp["task_space.lower"])  # task dimensions: x, y (and z)

    def on_js(self, data: bytes, info: dict) -> None:
        mon = self.mon
        mon.on_joint_state(data, info)
        names = mon.intake.names
        if names is None or not any(j in names for j in mon.joints):
            return  # undecodable, or another driver's joints (e.g. a gripper's): the learner ignores them
        if all(j in names for j in mon.joints):
            self.index = [names.index(j) for j in mon.joints]
        self.js.append((time.time(), mon.intake.message_stamp,
                        mon.alpha.copy() if mon.alpha is not None else None))

    def on_tip(self, msg, info: dict) -> None:
        self.mon.on_task_point(msg, info)
        self.tips.append((time.time(), DriverMonitor._stamp(msg),
                          np.array([msg.point.x, msg.point.y, msg.point.z])[:self.m]))


def publishers_report(node, mon: DriverMonitor, say) -> dict:
    """Every publisher of the watched inputs and how the learner would take their messages (said
    and returned): rclpy names no publisher per message, so per topic the publishers (node, GID),
    the joint-name lists seen on /joint_states with what the learner does with each, and the
    number of sources sending what the learner uses (one: accepted; more: the learner holds)."""
    out: dict = {}
    now = time.monotonic()
    streams = [("/joint_states", mon.intake.sources, "the learner's joints")]
    if mon.task_fk is None:
        streams.append((mon.task_topic, mon.tip_sources, "task points"))
    for topic, chains, what in streams:
        pubs = [describe(i) for i in node.get_publishers_info_by_topic(topic)]
        sources = chains.live(now)
        verdict = ("accepted (one source)" if sources <= 1 and not chains.ambiguous(now) else
                   f"NOT accepted: {sources} sources send {what}; the learner holds while they do")
        out[topic] = {"publishers": pubs, "sources": sources, "verdict": verdict}
        say(f"{topic}: {len(pubs)} publisher(s): {'; '.join(pubs) or 'none'}; {what}: {verdict}")
    lists = {", ".join(mon.js_names or []): "every learner joint: used"} if mon.js_names else {}
    for names, n in mon.other_names.items():
        lists[", ".join(names) or "(no joint)"] = f"none of the learner's joints: ignored ({n} messages)"
    out["joint_lists"] = lists
    for names, how in lists.items():
        say(f"  /joint_states naming [{names}]: {how}")
    out["rejected"] = dict(mon.rejected)  # (the learner's rules: it would reject these too)
    for kind, n in mon.rejected.items():
        say(f"  /joint_states: {n} message(s) rejected [{kind}] (the learner rejects them too)")
    return out


# s: a probe move sent as a trajectory (command_interface 'trajectory') takes this long (slow, a few cm)
PROBE_SECONDS = 1.0


def probe_target(start: np.ndarray, j: int, step: float, lower: np.ndarray, upper: np.ndarray, scene):
    """The probe move: joint ``j`` by ``step`` rad (down when up leaves its range) from ``start``,
    within the limits; the other way when the scene (None: none) refuses the first. Returns the
    target, or None and the last refusal when the scene refuses both."""
    refusal = None
    first = 1.0 if start[j] + step <= upper[j] else -1.0
    for sign in (first, -first):
        target = start.copy()
        target[j] = np.clip(start[j] + sign * step, lower[j], upper[j])
        refusal = None if scene is None else scene.segment(start, target)
        if refusal is None:
            return target, None
    return None, refusal


def check_driver(config: str, joint: str | None = None, step: float = 0.05, seconds: float = 2.0,
                 domain_id: int | None = None, timeout: float = 30.0, out=sys.stdout) -> dict:
    """Run the check; returns the measurements and ``problems`` (empty = fine)."""
    # lazy (heavy): ROS
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    from sagg_common.scene import scene_from_params  # (mujoco)

    lp = learner_params(config)
    joints = list(lp["joints"])
    joint = joint or joints[-1]
    if joint not in joints:
        raise ConfigError(f"--joint {joint!r}; allowed: one of the learner's joints {', '.join(joints)}")
    if not 0 < step <= lp["max_joint_step"]:
        raise ConfigError(f"--step {step}; allowed: (0, max_joint_step = {lp['max_joint_step']}]")
    # the scene (scene.*, with the robot's model): the probe move is checked as the learner's moves are
    scene = scene_from_params(lp, joints, os.path.dirname(os.path.abspath(config)))
    ctx = Context()
    rclpy.init(context=ctx, signal_handler_options=SignalHandlerOptions.NO,
               **({} if domain_id is None else {"domain_id": int(domain_id)}))
    stop: list[int] = []
    old = {s: signal.signal(s, lambda *_: stop.append(1)) for s in (signal.SIGINT, signal.SIGTERM)}
    check = _DriverCheck(ctx, lp, joint, step, stop, out)
    try:
        if check.contract(timeout) and check.at_rest(seconds) and check.probe_move(scene):
            check.say("OK: the driver meets the contract" if not check.problems
                      else "PROBLEMS:\n  - " + "\n  - ".join(check.problems))
        return check.res
    finally:
        check.close()
        rclpy.shutdown(context=ctx)
        for s, h in old.items():
            signal.signal(s, h)


class _DriverCheck:
    """One check of a driver on a node of its own (``sagg_check_driver``): the probe of the driver's
    messages, the probe move's commands, what was measured (``res``) and the problems found (in
    ``res["problems"]`` too). Each step says what it found on ``out``."""

    def __init__(self, ctx, lp: dict, joint: str, step: float, stop: list[int], out):
        # lazy (heavy): ROS
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from geometry_msgs.msg import PointStamped
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        from trajectory_msgs.msg import JointTrajectory
        from sagg_low_level.node_moves import trajectory_message

        self.lp, self.stop, self.out = lp, stop, out
        self.joints = list(lp["joints"])
        self.joint, self.j, self.step = joint, self.joints.index(joint), step
        self.node = rclpy.create_node("sagg_check_driver", context=ctx)
        self.ex = SingleThreadedExecutor(context=ctx)
        self.ex.add_node(self.node)
        self.probe = _Probe(lp)
        mon = self.mon = self.probe.mon
        self.node.create_subscription(JointState, "/joint_states", with_message_info(self.probe.on_js),
                                      reliable(100), raw=True)
        if mon.task_fk is None:
            self.node.create_subscription(PointStamped, mon.task_topic, with_message_info(self.probe.on_tip),
                                          reliable(100))
        else:  # task_source 'model': the task point of each measured posture, through the robot's model
            mon.on_tip = lambda p: self.probe.tips.append((time.time(), mon.tip_stamp, p[:self.probe.m]))
        self.trajectory = mon.cmd_type.startswith("trajectory_msgs")  # (command_interface 'trajectory')
        self._array, self._trajectory_message = Float64MultiArray, trajectory_message
        self.pub = self.node.create_publisher(JointTrajectory if self.trajectory else Float64MultiArray,
                                              mon.cmd_topic, reliable(HW_DEPTH))
        self.problems: list[str] = []
        self.res: dict = {"joints": self.joints, "moved_joint": joint, "step": step, "problems": self.problems}

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def spin_for(self, secs: float, until=None) -> bool:
        """Spin for ``secs`` s or until ``until()`` holds (then True); KeyboardInterrupt on a signal."""
        t_end = time.monotonic() + secs
        while time.monotonic() < t_end:
            if self.stop:
                raise KeyboardInterrupt
            self.ex.spin_once(timeout_sec=0.01)
            if until is not None and until():
                return True
        return False

    def command(self, start: np.ndarray, target: np.ndarray) -> None:
        """The probe's setpoint; as a trajectory over PROBE_SECONDS with that interface."""
        if self.trajectory:
            self.pub.publish(self._trajectory_message(self.joints, start, target, PROBE_SECONDS))
        else:
            self.pub.publish(self._array(data=target.tolist()))

    def contract(self, timeout: float) -> bool:
        """1. The contract: waits up to ``timeout`` s for it; False (the problems named) when unmet."""
        mon = self.mon
        t0 = time.monotonic()
        missing = mon.missing(self.node, own_node="sagg_check_driver")
        while missing and time.monotonic() - t0 < timeout:
            self.spin_for(0.5)
            missing = mon.missing(self.node, own_node="sagg_check_driver")
        if missing:
            self.problems += missing
            self.say("contract NOT met:\n  - " + "\n  - ".join(missing))
            return False
        task = (mon.task_topic if mon.task_fk is None else
                f"the task point from the joints through {mon.task_fk.robot.path} (effector "
                f"{mon.task_fk.robot.effector!r}; every joint found in the model)")
        self.say(f"contract met: /joint_states names {', '.join(self.joints)}; {task}; {mon.cmd_topic} has a "
                 "subscriber")
        return True

    def at_rest(self, seconds: float) -> bool:
        """2. Listening at rest for ``seconds``: rates, delays, name mapping, noise, publishers;
        False when fewer than two joint states or task points came."""
        probe, res, joints = self.probe, self.res, self.joints
        probe.js.clear()
        probe.tips.clear()
        self.spin_for(seconds)
        js, tips = probe.js, probe.tips
        if len(js) < 2 or len(tips) < 2:
            self.problems.append(f"fewer than 2 joint states / task points in {seconds} s at rest")
            return False
        res["joint_state_rate"] = (len(js) - 1) / (js[-1][0] - js[0][0])
        res["task_point_rate"] = (len(tips) - 1) / (tips[-1][0] - tips[0][0])
        res["joint_state_delay"] = float(np.median([rx - st / 1e9 for rx, st, _ in js]))
        res["task_point_delay"] = float(np.median([rx - st / 1e9 for rx, st, _ in tips]))
        res["name_mapping"] = {name: i for name, i in zip(joints, probe.index or [])}
        pos = np.array([a for _, _, a in js if a is not None])
        res["joint_noise"] = dict(zip(joints, pos.std(axis=0).tolist()))
        res["task_point_noise"] = np.array([t for _, _, t in tips]).std(axis=0).tolist()
        self.say(f"rates: joint states {res['joint_state_rate']:.1f}/s, task points {res['task_point_rate']:.1f}/s")
        res["publishers"] = publishers_report(self.node, self.mon, self.say)
        self.problems += [f"{t}: {v['verdict']}" for t, v in res["publishers"].items()
                          if isinstance(v, dict) and v.get("verdict", "").startswith("NOT")]
        self.say(f"delay stamp -> arrival (same clock): joint states {1e3 * res['joint_state_delay']:.1f} ms, "
                 f"task points {1e3 * res['task_point_delay']:.1f} ms")
        self.say("name mapping (learner joint -> index in /joint_states): "
                 + ", ".join(f"{k} -> {v}" for k, v in res["name_mapping"].items()))
        self.say("noise at rest (std): joints "
                 + ", ".join(f"{k} {v:.2g} rad" for k, v in res["joint_noise"].items())
                 + f"; task point {', '.join(f'{v:.2g}' for v in res['task_point_noise'])}")
        return True

    def probe_move(self, scene) -> bool:
        """3. One joint, a little, then back: False when the scene refuses the move both ways (said,
        nothing moved)."""
        mon, j, step = self.mon, self.j, self.step
        start = mon.alpha.copy()
        tip0 = mon.tip[:self.probe.m].copy()
        lower, upper = np.asarray(self.lp["joint_limits.lower"]), np.asarray(self.lp["joint_limits.upper"])
        target, refusal = probe_target(start, j, step, lower, upper, scene)
        if target is None:  # (both ways refused by the scene: no motion test, said)
            self.say(f"the probe move of {self.joint} by ±{step} rad is refused by the scene ({refusal.cause}: "
                     f"{refusal.detail}): not moved; try another --joint")
            return False
        stamp0 = mon.js_stamp
        t_cmd = time.time()
        self.command(start, target)
        half = abs(target[j] - start[j]) / 2
        # wait for any joint to move (a wrong mapping moves another one), then for the arm to settle
        moved = self.spin_for(10.0, lambda: mon.js_stamp > stamp0 and np.abs(mon.alpha - start).max() > half)
        if not moved:
            self.problems.append(f"no joint moved within 10 s of a command on {mon.cmd_topic}")
            self.say(self.problems[-1])
            return True
        self._measure_move(start, target, tip0, t_cmd, half)
        # back where it was
        self.command(mon.alpha.copy(), start)
        self.spin_for(0.2)
        self.spin_for(max(2.0, self.lp["settle_timeout"]), lambda: mon.settled)
        self._suggest()
        return True

    def _measure_move(self, start: np.ndarray, target: np.ndarray, tip0: np.ndarray, t_cmd: float,
                      half: float) -> None:
        """The probe move's response, settling and displacements; a step off by more than 50 % or
        another joint moving is a problem."""
        mon, res, j, joint, joints = self.mon, self.res, self.j, self.joint, self.joints
        first = next((rx for rx, st, a in self.probe.js if rx >= t_cmd and a is not None
                      and np.abs(a - start).max() > half), time.time())
        res["response_seconds"] = first - t_cmd
        self.spin_for(0.2)
        self.spin_for(max(2.0, self.lp["settle_timeout"]), lambda: mon.settled)
        res["settle_seconds"] = time.time() - t_cmd
        delta = mon.alpha - start
        res["displacement"] = dict(zip(joints, delta.tolist()))
        res["task_point_displacement"] = float(np.linalg.norm(mon.tip[:self.probe.m] - tip0))
        ratio = float(delta[j] / (target[j] - start[j]))
        res["step_ratio"] = ratio
        self.say(f"moved {joint} by {target[j] - start[j]:+.3f} rad: measured {delta[j]:+.3f} rad "
                 f"({100 * ratio:.0f} %), first sign after {1e3 * res['response_seconds']:.0f} ms, "
                 f"settled after {1e3 * res['settle_seconds']:.0f} ms; "
                 f"task point moved {res['task_point_displacement']:.3g}")
        if not 0.5 <= ratio <= 1.5:
            self.problems.append(f"joint {joint} moved {100 * ratio:.0f} % of the commanded step; allowed: 50-150 %")
        noise = np.array([res["joint_noise"][n] for n in joints])
        others = [n for i, n in enumerate(joints)
                  if i != j and abs(delta[i]) > max(0.25 * self.step, 6 * noise[i])]
        if others:
            self.problems.append(f"commanding {joint} also moved {', '.join(others)}: the command order (= 'joints') "
                                 "or the names in /joint_states do not match the driver's")

    def _suggest(self) -> None:
        """4. The observation_delay and joint_state_timeout the measured rates and delays suggest."""
        res, lp = self.res, self.lp
        period = 1.0 / res["joint_state_rate"]
        res["suggested_observation_delay"] = (max(res["joint_state_delay"], res["task_point_delay"], 0.0)
                                              + 2 * period)
        res["suggested_joint_state_timeout"] = max(2.0, 10 * period)
        self.say(f"suggested: observation_delay {res['suggested_observation_delay']:.3f} "
                 f"(now {lp['observation_delay']}), "
                 f"joint_state_timeout >= {res['suggested_joint_state_timeout']:.1f} (now {lp['joint_state_timeout']})")


def main_check_driver(args) -> int:
    # lazy (heavy): the set-up registry (mujoco)
    from .launch_params import resolve_config
    res = check_driver(str(resolve_config(args.config)), args.joint, args.step, args.seconds, args.domain_id,
                       args.timeout)
    return 1 if res["problems"] else 0
