"""A test driver that behaves like a real ros2_control arm: stands for the hardware in tests and
experiments of sagg's learner (``sagg run CONFIG --driver external --set task_source=model``).

Unlike test/fake_driver.py (a numpy planar arm that tracks perfectly) this one has what a real
position-controlled arm has, each option standing for one behaviour of the hardware:

- **the robot's model file** (``--model`` URDF or MJCF, ``--effector``, ``--rest``, ``--joint-names``):
  the joints, their limits and the rest posture, as the robot_description a real driver is
  started with. Velocity limits: the URDF's ``<limit velocity=...>`` (read with xml.etree);
  an MJCF has none, ``--velocity-limits`` gives them (default pi rad/s each, a UR5's joint speed);
- **controllers** (``--controller``, ``--trajectory-controller``): a forward position controller
  (``/<controller>/commands``, std_msgs/Float64MultiArray in ``--joint-names`` order, default the
  model's moving joints) hands every setpoint to the servo at once, it does NOT interpolate; a
  joint trajectory controller (``/<trajectory_controller>/joint_trajectory``,
  trajectory_msgs/JointTrajectory, joints mapped by name, joints it does not name held) follows
  the points in time, linearly interpolated from the measured posture at its start (the header
  stamp, or its arrival when zero). The last command of either kind wins. Setpoints are clipped
  to the joint limits (as ros2_control's joint limiter does);
- **servo tracking** (``--rate`` 250 Hz control loop): each joint moves toward its setpoint with a
  first-order lag (``--lag`` time constant, s), its speed clipped to its velocity limit and its
  acceleration to ``--max-acceleration`` (rad/s^2; one value or one per joint; braking is planned
  so that a joint stops at its setpoint). Each cycle integrates over the real time since the last
  (Python timers are late sometimes; at most 4 periods: after a stall the arm does not catch up),
  so a joint never moves more than its limit x the time between two stamps;
- **sensing** (``--noise``, ``--latency``, ``--seed``): ``/joint_states`` at the loop rate with
  positions AND velocities (Gaussian reading noise ``--noise``, rad and rad/s), stamped with the
  sampling time, published ``--latency`` s later (a delay line: the fieldbus and the driver's
  own cycle);
- **a gripper** (``--gripper-joint``, '' for none): its joint in a SEPARATE JointState on
  /joint_states from a publisher of its own at 50 Hz (position 0.04 m), as a gripper driver beside
  the arm's does: readers must pick their joints by name;
- **calibration gap** (``--length-scale``, ``--joint-offsets``): the arm's true kinematics are not
  the model file's: every body offset (and the effector site) is scaled by ``--length-scale`` and
  each joint's zero is off by its offset. Convention: the driver reports (and servoes) its ENCODER
  angles; the TRUE joint angle is ``encoder + offset``. The model file's forward kinematics of
  the reported angles therefore miss the true tool point (by ~1 cm for the defaults on arm7, said
  at start). The table check below uses the true geometry;
- **protective stops** (as a UR's or Franka's safety controller): (a) **table**: when a point of a
  moving link would go below ``--table`` z (world frame; default no table). The links are capsules
  of radius ``--link-radius`` between consecutive body origins of the chain from the base to the
  effector (and the effector site), on the true geometry; a link that no joint can move (the base
  column, a link turning about its own axis on it) is not checked. The arm stops at the first
  contact posture (found by bisection on the cycle's step: it does not penetrate). (b) **jump**:
  when a setpoint is more than ``--jump-limit`` rad from the current measured posture in any joint
  (every forward command; for a trajectory, the interpolated setpoint of each cycle, i.e. a
  trajectory asking for more than the arm can follow). On a stop the motion stops at once
  (velocities zero, position held), a WARN line names the cause, every command is ignored for
  ``--stop-ignore`` s, then commands are accepted again (the operator cleared the stop; the arm
  holds its posture until the next command);
- **e-stop for tests** (``--freeze-at T --freeze-for D``): T s after the first command the arm
  stops and ignores commands for D s (an emergency stop pressed, then released; not a protective
  stop); SIGUSR1 toggles such a freeze, for interactive use. After a release the arm holds its
  posture until the next command (which may then be a jump);
- **statistics**: at exit (SIGINT/SIGTERM) one line ``real arm driver: N commands, S protective
  stops (table T, jump J), ignored I, largest setpoint jump X rad, largest speed V rad/s (limit L),
  table contacts C`` (V: the largest joint speed over the run, L: that joint's limit) and, with
  ``--stats FILE``, the same as JSON, written atomically every 2 s while running and at exit (so a
  SIGKILLed run still has them; ``running`` tells which). Keys: see :meth:`ArmCore.stats`.

QoS: reliable, depth 10; a single-threaded executor spun in the main loop (as test/fake_driver.py).

Run (the Panda-like arm of config/arm7_urdf.yaml, its rest_posture, a table at the base's height)::

    .venv/bin/python test/arm_driver.py --model config/robots/arm7.urdf --effector tool0 \\
        --rest 0 -0.7853981633974483 0 -2.356194490192345 0 1.5707963267948966 0.7853981633974483 \\
        --table 0.0 --stats /tmp/arm_driver.json

or the UR5-like MJCF arm (rest posture: its keyframe "home")::

    .venv/bin/python test/arm_driver.py --model config/robots/arm6.xml --effector tool --table 0.0
"""
from __future__ import annotations

import argparse
import collections
import json
import math
import os
import signal
import sys
import xml.etree.ElementTree as ET

import mujoco
import numpy as np

from sagg_common.model_load import compile_spec, load_spec
from sagg_common.robot_model import RobotModel, ament_prefixes

GRIPPER_RATE = 50.0      # Hz, the gripper driver's JointState
GRIPPER_POSITION = 0.04  # m, an open parallel gripper's finger
STATS_EVERY = 2.0        # s
BISECTIONS = 24          # table contact: the step is cut to within 2^-24 of the contact posture


# ------------------------------------------------------------------------------------ the model
def urdf_velocity_limits(path: str) -> dict[str, float]:
    """Joint name -> ``<limit velocity=...>`` (rad/s or m/s) of a URDF's joints that give one."""
    out = {}
    for joint in ET.parse(path).getroot().iter("joint"):
        limit = joint.find("limit")
        if limit is not None and limit.get("velocity") is not None:
            out[joint.get("name")] = float(limit.get("velocity"))
    return out


def per_joint(values: list[float] | None, n: int, what: str, default: float | None = None) -> np.ndarray:
    """One value per joint from a list of 1 (for every joint) or n values."""
    if not values:
        if default is None:
            raise ValueError(f"{what}: no value")
        values = [default]
    if len(values) == 1:
        return np.full(n, float(values[0]))
    if len(values) != n:
        raise ValueError(f"{what}: got {len(values)} values; allowed: 1 or {n} (one per joint)")
    return np.asarray(values, dtype=float)


class TrueGeometry:
    """The arm as it really is (the calibration gap): the model file with every body offset and the
    effector site scaled by ``length_scale``, joint ``j`` at ``encoder[j] + offsets[j]``. The links
    are capsules between consecutive points of the chain base -> effector (body origins, then the
    effector site when the effector is a site); only links that some joint moves are checked."""

    def __init__(self, robot: RobotModel, length_scale: float, offsets: np.ndarray, radius: float):
        spec, _ = load_spec(robot.path, (), ament_prefixes(), True)
        for body in spec.bodies:
            body.pos = np.asarray(body.pos) * length_scale
        for site in spec.sites:
            site.pos = np.asarray(site.pos) * length_scale
        self.model = compile_spec(spec, robot.path)
        self.data = mujoco.MjData(self.model)
        self.qpos = np.array(robot.qpos_rest, dtype=float)
        self.qadr = robot.qadr
        self.offsets = offsets
        self.radius = radius
        m = self.model
        chain, b = [], robot.body
        while b != 0:
            chain.append(b)
            b = int(m.body_parentid[b])
        self.chain = chain[::-1]
        self.site = robot.site
        self.names = [m.body(i).name for i in self.chain] + ([m.site(self.site).name] if self.site >= 0 else [])
        # which chain points move: compare them over a few postures spread over the joint box
        rng = np.random.default_rng(0)
        samples = [robot.rest] + [rng.uniform(robot.lower, robot.upper) for _ in range(8)]
        pts = np.array([self.points(q) for q in samples])
        moves = np.ptp(pts, axis=0).max(axis=1) > 1e-9
        # link k = segment (point k, point k+1): checked when either end moves
        links = [k for k in range(len(self.names) - 1) if moves[k] or moves[k + 1]]
        self.checked = np.array(sorted({k for k in links} | {k + 1 for k in links}), dtype=np.int64)
        self.links = [f"{self.names[k]}->{self.names[k + 1]}" for k in links]

    def points(self, encoder: np.ndarray) -> np.ndarray:
        """(k, 3) world points of the chain (true geometry) for the reported angles ``encoder``."""
        self.qpos[self.qadr] = encoder + self.offsets
        self.data.qpos[:] = self.qpos
        mujoco.mj_kinematics(self.model, self.data)
        pts = self.data.xpos[self.chain]
        if self.site >= 0:
            pts = np.vstack((pts, self.data.site_xpos[self.site][None, :]))
        return pts.copy()

    def tool(self, encoder: np.ndarray) -> np.ndarray:
        return self.points(encoder)[-1]

    def lowest(self, encoder: np.ndarray) -> tuple[float, str]:
        """The lowest z of the checked links' capsules and the point it is at."""
        z = self.points(encoder)[self.checked, 2]
        i = int(np.argmin(z))
        return float(z[i]) - self.radius, self.names[int(self.checked[i])]


# ------------------------------------------------------------------------------------ the arm
class ArmCore:
    """The arm's controller, servo and safety controller, ROS-free (times in s, any origin).

    ``command`` (a forward setpoint) and ``trajectory`` take commands; ``step(now)`` runs one
    control cycle and returns the encoder posture and velocity; ``events`` collects the log lines
    (level, text) for the caller to print."""

    def __init__(self, names, lower, upper, rest, vmax, amax, lag: float, jump_limit: float, stop_ignore: float,
                 table: float | None, geometry: TrueGeometry | None, rate: float,
                 freeze_at: float | None = None, freeze_for: float = 0.0):
        self.names = list(names)
        self.n = len(self.names)
        self.index = {name: i for i, name in enumerate(self.names)}
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.vmax, self.amax = np.asarray(vmax, float), np.asarray(amax, float)
        self.lag, self.jump_limit, self.stop_ignore = lag, jump_limit, stop_ignore
        self.table, self.geometry = table, geometry
        self.period = 1.0 / rate
        self.freeze_at, self.freeze_for = freeze_at, freeze_for
        self.q = np.array(rest, dtype=float)
        self.v = np.zeros(self.n)
        self.target = self.q.copy()
        self.traj: tuple[np.ndarray, np.ndarray] | None = None  # (times (k,), postures (k, n))
        self.last_time: float | None = None
        self.first_command: float | None = None
        self.stopped_until: float | None = None
        self.user_frozen = False
        self.was_frozen = False
        self.events: list[tuple[str, str]] = []
        # statistics
        self.commands = self.trajectories = self.rejected = 0
        self.stops = {"table": 0, "jump": 0}
        self.ignored = {"stop": 0, "freeze": 0}
        self.freezes = 0
        self.table_contacts = 0
        self.largest_jump = 0.0
        self.max_speed = np.zeros(self.n)
        self.cycles = 0
        self.lowest_z: float | None = None
        if table is not None and geometry is not None:
            z, where = geometry.lowest(self.q)
            self.lowest_z = z
            if z < table:
                self.events.append(("warn", f"the rest posture is below the table ({where} at z={z:.4f} m, table "
                                            f"{table} m): only motions that raise it are allowed"))

    # ---------------------------------------------------------------- state
    def frozen(self, now: float) -> bool:
        if self.user_frozen:
            return True
        if self.freeze_at is None or self.first_command is None:
            return False
        t = now - self.first_command
        return self.freeze_at <= t < self.freeze_at + self.freeze_for

    def stopped(self, now: float) -> bool:
        return self.stopped_until is not None and now < self.stopped_until

    def hold(self) -> None:
        """Stop at once: velocities zero, the setpoint = the posture, no trajectory."""
        self.v[:] = 0.0
        self.target = self.q.copy()
        self.traj = None

    def protective_stop(self, cause: str, now: float, detail: str) -> None:
        self.stops[cause] += 1
        self.stopped_until = now + self.stop_ignore
        self.hold()
        self.events.append(("warn", f"PROTECTIVE STOP ({cause}): {detail}; commands ignored for "
                                    f"{self.stop_ignore:g} s (stop {sum(self.stops.values())})"))

    def _accept(self, now: float) -> bool:
        """Count a well-formed command; False when it must be ignored (frozen, stopped)."""
        self.commands += 1
        if self.first_command is None:
            self.first_command = now
        if self.frozen(now):
            self.ignored["freeze"] += 1
            return False
        if self.stopped(now):
            self.ignored["stop"] += 1
            return False
        return True

    def _check_jump(self, setpoint: np.ndarray, now: float, what: str) -> bool:
        """True if ``setpoint`` is within the jump limit of the posture (else a protective stop)."""
        d = np.abs(setpoint - self.q)
        j = int(np.argmax(d))
        self.largest_jump = max(self.largest_jump, float(d[j]))
        if d[j] > self.jump_limit:
            self.protective_stop("jump", now, f"{what} {d[j]:.4f} rad from the measured posture in {self.names[j]} "
                                              f"(limit {self.jump_limit:g} rad)")
            return False
        return True

    # ---------------------------------------------------------------- commands
    def command(self, values, now: float) -> None:
        """A forward position controller's setpoint (command order = ``names``)."""
        sp = np.asarray(values, dtype=float)
        if sp.shape != (self.n,) or not np.all(np.isfinite(sp)):
            self.rejected += 1
            self.events.append(("error", f"bad command of {sp.size} values ignored (need {self.n} finite values)"))
            return
        if not self._accept(now):
            return
        sp = np.clip(sp, self.lower, self.upper)
        if self._check_jump(sp, now, "setpoint"):
            self.traj = None
            self.target = sp

    def trajectory(self, joint_names, points, start: float | None, now: float) -> None:
        """A joint trajectory: ``points`` = [(time_from_start s, positions)], joints by name."""
        unknown = [j for j in joint_names if j not in self.index]
        bad = (unknown or len(set(joint_names)) != len(joint_names) or not points
               or any(len(p) != len(joint_names) or not all(map(math.isfinite, p)) for _, p in points)
               or any(b[0] < a[0] for a, b in zip(points, points[1:])) or points[0][0] < 0)
        if bad:
            self.rejected += 1
            self.events.append(("error", f"bad trajectory ignored: joints {list(joint_names)} (unknown: {unknown}), "
                                         f"{len(points)} points (need increasing times, one finite position per "
                                         "joint)"))
            return
        if not self._accept(now):
            return
        self.trajectories += 1
        cols = [self.index[j] for j in joint_names]
        t0 = now if start is None else start
        times, postures = [t0], [self.q.copy()]  # from the measured posture, as a closed-loop JTC
        for t, p in points:
            x = self.target.copy()  # joints it does not name: held at their current setpoint
            x[cols] = p
            times.append(t0 + t)
            postures.append(np.clip(x, self.lower, self.upper))
        self.traj = (np.array(times), np.array(postures))

    def _setpoint(self, now: float) -> bool:
        """The trajectory's setpoint now (False: it caused a protective stop)."""
        if self.traj is None:
            return True
        times, postures = self.traj
        if now >= times[-1]:
            sp = postures[-1].copy()
            self.traj = None
        else:
            k = int(np.searchsorted(times, now, side="right"))
            if k == 0:
                sp = postures[0].copy()
            else:
                f = (now - times[k - 1]) / (times[k] - times[k - 1])
                sp = postures[k - 1] + f * (postures[k] - postures[k - 1])
        if not self._check_jump(sp, now, "trajectory setpoint"):
            return False
        self.target = sp
        return True

    # ---------------------------------------------------------------- the control cycle
    def step(self, now: float) -> tuple[np.ndarray, np.ndarray]:
        self.cycles += 1
        # the real elapsed time (at most 4 periods: after a stall the arm does not catch up)
        dt = self.period if self.last_time is None else min(now - self.last_time, 4.0 * self.period)
        if dt <= 0.0:
            return self.q, self.v
        self.last_time = now
        frozen = self.frozen(now)
        if frozen != self.was_frozen:
            self.was_frozen = frozen
            if frozen:
                self.freezes += 1
                self.hold()
                self.events.append(("warn", "FROZEN (e-stop pressed): the arm stops and ignores commands"))
            else:
                self.hold()
                self.events.append(("info", "released (e-stop cleared): commands are accepted again"))
        if self.stopped_until is not None and not self.stopped(now):
            self.stopped_until = None
            self.events.append(("info", "protective stop cleared: commands are accepted again"))
        if frozen or self.stopped(now) or not self._setpoint(now):
            self.v[:] = 0.0
            return self.q, self.v
        err = self.target - self.q
        mag = np.abs(err)
        lag = (1.0 - math.exp(-dt / self.lag)) / dt if self.lag > 0 else 1.0 / dt
        a = self.amax
        # the speed from which the joint can still stop at the setpoint within this step's motion
        brake = np.sqrt((a * dt) ** 2 + 2.0 * a * mag) - a * dt
        want = np.sign(err) * np.minimum(np.minimum(mag * lag, brake), self.vmax)
        v = self.v + np.clip(want - self.v, -a * dt, a * dt)
        v = np.clip(v, -self.vmax, self.vmax)
        q = np.clip(self.q + v * dt, self.lower, self.upper)
        v = (q - self.q) / dt  # a joint at its hard limit stops there
        if self.table is not None and self.geometry is not None:
            z, where = self.geometry.lowest(q)
            z_now = self.lowest_z if self.lowest_z is not None else self.geometry.lowest(self.q)[0]
            if z < self.table and z < z_now:
                self.table_contacts += 1
                # the first contact posture on this step (the clear side, to 2^-24 of the step)
                lo, hi = 0.0, 1.0
                if z_now >= self.table:
                    for _ in range(BISECTIONS):
                        mid = 0.5 * (lo + hi)
                        if self.geometry.lowest(self.q + mid * (q - self.q))[0] < self.table:
                            hi = mid
                        else:
                            lo = mid
                q_contact = self.q + lo * (q - self.q)
                self._record(q_contact, dt)
                self.q = q_contact
                self.lowest_z = self.geometry.lowest(self.q)[0]
                self.protective_stop("table", now, f"{where} would reach z={z:.4f} m below the table at "
                                                   f"{self.table:g} m; stopped at its first contact, lowest point "
                                                   f"z={self.lowest_z:.4f} m")
                return self.q, self.v
            self.lowest_z = z
        self._record(q, dt)
        self.q, self.v = q, v
        return self.q, self.v

    def _record(self, q: np.ndarray, dt: float) -> None:
        np.maximum(self.max_speed, np.abs(q - self.q) / dt, out=self.max_speed)

    # ---------------------------------------------------------------- statistics
    def stats(self) -> dict:
        """commands (well-formed commands received, trajectories included), trajectories, rejected
        (malformed), protective_stops, stops_table, stops_jump, ignored (= ignored_stop +
        ignored_freeze), freezes, largest_setpoint_jump (rad, a setpoint's largest distance from the
        posture when it arrived, stopped ones included), largest_speed (rad/s) with speed_limit and
        speed_joint (the joint it was reached by), max_speed and velocity_limits (per joint, in
        joint_names order), table_contacts (control cycles whose step was cut at the table),
        lowest_point (z of the lowest checked link point now, true geometry; None without table),
        cycles, joint_names."""
        j = int(np.argmax(self.max_speed))
        return {
            "commands": self.commands, "trajectories": self.trajectories, "rejected": self.rejected,
            "protective_stops": sum(self.stops.values()), "stops_table": self.stops["table"],
            "stops_jump": self.stops["jump"], "ignored": sum(self.ignored.values()),
            "ignored_stop": self.ignored["stop"], "ignored_freeze": self.ignored["freeze"], "freezes": self.freezes,
            "largest_setpoint_jump": self.largest_jump, "largest_speed": float(self.max_speed[j]),
            "speed_limit": float(self.vmax[j]), "speed_joint": self.names[j],
            "max_speed": self.max_speed.tolist(), "velocity_limits": self.vmax.tolist(),
            "table_contacts": self.table_contacts, "lowest_point": self.lowest_z, "cycles": self.cycles,
            "joint_names": self.names,
        }


def stats_line(s: dict) -> str:
    return (f"real arm driver: {s['commands']} commands, {s['protective_stops']} protective stops (table "
            f"{s['stops_table']}, jump {s['stops_jump']}), ignored {s['ignored']}, largest setpoint jump "
            f"{s['largest_setpoint_jump']:.6f} rad, largest speed {s['largest_speed']:.6f} rad/s (limit "
            f"{s['speed_limit']:g}), table contacts {s['table_contacts']}")


def write_stats(path: str, s: dict) -> None:
    """``s`` as JSON at ``path``, atomically (a temporary file in the same directory, renamed)."""
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "w") as f:
        json.dump(s, f, indent=1)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def build(a: argparse.Namespace) -> tuple[RobotModel, ArmCore, dict]:
    """The model, the arm and what to say at start, from the options (ROS-free; ValueError on bad
    options, sagg's ConfigError on a bad model)."""
    robot = RobotModel.load(os.path.abspath(a.model), a.effector, joints=tuple(a.joint_names),
                            rest=tuple(a.rest or ()))
    names, n = list(robot.joint_names), len(robot.joint_names)
    if a.velocity_limits:
        vmax = per_joint(a.velocity_limits, n, "--velocity-limits")
        vsource = "--velocity-limits"
    elif a.model.lower().endswith(".urdf"):
        table = urdf_velocity_limits(a.model)
        missing = [j for j in names if j not in table]
        if missing:
            raise ValueError(f"--model {a.model}: no <limit velocity> for {missing}; give --velocity-limits")
        vmax = np.array([table[j] for j in names])
        vsource = "the URDF's <limit velocity>"
    else:
        vmax = np.full(n, math.pi)
        vsource = "default pi rad/s (an MJCF has no velocity limits)"
    amax = per_joint(a.max_acceleration, n, "--max-acceleration")
    offsets = per_joint(a.joint_offsets, n, "--joint-offsets")
    if np.any(vmax <= 0) or np.any(amax <= 0):
        raise ValueError("velocity and acceleration limits must be > 0")
    geometry = TrueGeometry(robot, a.length_scale, offsets, a.link_radius)
    core = ArmCore(names, robot.lower, robot.upper, robot.rest, vmax, amax, a.lag, a.jump_limit, a.stop_ignore,
                   a.table, geometry, a.rate, a.freeze_at, a.freeze_for)
    gap = float(np.linalg.norm(geometry.tool(robot.rest) - robot.kin.positions(np.asarray(robot.rest)[None])[0]))
    info = {"velocity_source": vsource, "calibration_gap_m": gap, "links": geometry.links,
            "notices": list(robot.notices)}
    return robot, core, info


# ------------------------------------------------------------------------------------ ROS
def make_node(a: argparse.Namespace, robot: RobotModel, core: ArmCore):
    import rclpy.node
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    from trajectory_msgs.msg import JointTrajectory

    class RealArmDriver(rclpy.node.Node):
        def __init__(self):
            super().__init__("real_arm_driver")
            self.core = core
            self.rng = np.random.default_rng(a.seed)
            self.noise = a.noise
            self.delay = collections.deque()
            self.latency_ns = int(round(a.latency * 1e9))
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
            self.js_pub = self.create_publisher(JointState, "/joint_states", qos)
            self.gripper = a.gripper_joint
            if self.gripper:
                # a publisher of its own: the gripper's driver is another source on /joint_states
                self.gripper_pub = self.create_publisher(JointState, "/joint_states", qos)
                self.create_timer(1.0 / GRIPPER_RATE, self.on_gripper)
            self.create_subscription(Float64MultiArray, f"/{a.controller}/commands", self.on_command, qos)
            self.create_subscription(JointTrajectory, f"/{a.trajectory_controller}/joint_trajectory",
                                     self.on_trajectory, qos)
            self.create_timer(1.0 / a.rate, self.on_cycle)
            self.stats_path = a.stats
            if a.stats:
                self.create_timer(STATS_EVERY, self.write_stats)

        def now_s(self) -> tuple[int, float]:
            ns = self.get_clock().now().nanoseconds
            return ns, ns * 1e-9

        def flush_events(self) -> None:
            log = self.get_logger()
            for level, text in self.core.events:
                # (one call site per severity: rclpy refuses a site whose severity changes)
                if level == "warn":
                    log.warning(text)
                elif level == "error":
                    log.error(text)
                else:
                    log.info(text)
            self.core.events.clear()

        def on_command(self, msg) -> None:
            self.core.command(msg.data, self.now_s()[1])
            self.flush_events()

        def on_trajectory(self, msg) -> None:
            _, now = self.now_s()
            st = msg.header.stamp
            start = None if (st.sec == 0 and st.nanosec == 0) else st.sec + st.nanosec * 1e-9
            points = [(p.time_from_start.sec + p.time_from_start.nanosec * 1e-9, list(p.positions))
                      for p in msg.points]
            self.core.trajectory(list(msg.joint_names), points, start, now)
            self.flush_events()

        def on_cycle(self) -> None:
            ns, now = self.now_s()
            q, v = self.core.step(now)
            self.flush_events()
            js = JointState()
            js.header.stamp.sec, js.header.stamp.nanosec = divmod(ns, 1_000_000_000)
            js.name = self.core.names
            n = self.core.n
            js.position = (q + self.noise * self.rng.standard_normal(n)).tolist()
            js.velocity = (v + self.noise * self.rng.standard_normal(n)).tolist()
            self.delay.append((ns + self.latency_ns, js))
            while self.delay and self.delay[0][0] <= ns:
                self.js_pub.publish(self.delay.popleft()[1])

        def on_gripper(self) -> None:
            js = JointState()
            js.header.stamp = self.get_clock().now().to_msg()
            js.name = [self.gripper]
            js.position = [GRIPPER_POSITION]
            js.velocity = [0.0]
            self.gripper_pub.publish(js)

        def write_stats(self, running: bool = True) -> None:
            if self.stats_path:
                write_stats(self.stats_path, dict(self.core.stats(), running=running))

    return RealArmDriver()


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--model", required=True, help="the robot's URDF (.urdf) or MJCF (.xml)")
    ap.add_argument("--effector", default="", help="the effector body/link or site (tool0, tool)")
    ap.add_argument("--rest", type=float, nargs="+", default=[],
                    help="rest posture, one value per joint (a model without keyframe 'home')")
    ap.add_argument("--joint-names", nargs="+", default=[],
                    help="the commanded joints in command order (default: the joints moving the effector)")
    ap.add_argument("--velocity-limits", type=float, nargs="+", default=[],
                    help="rad/s, 1 or one per joint (default: the URDF's, pi for an MJCF)")
    ap.add_argument("--max-acceleration", type=float, nargs="+", default=[10.0], help="rad/s^2, 1 or one per joint")
    ap.add_argument("--lag", type=float, default=0.03, help="servo's first-order time constant, s")
    ap.add_argument("--rate", type=float, default=250.0, help="control loop and /joint_states, Hz")
    ap.add_argument("--latency", type=float, default=0.004, help="joint state delay line, s")
    ap.add_argument("--noise", type=float, default=1e-4, help="reading noise, rad and rad/s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--controller", default="forward_position_controller")
    ap.add_argument("--trajectory-controller", default="joint_trajectory_controller")
    ap.add_argument("--gripper-joint", default="gripper_finger_joint", help="'' for no gripper")
    ap.add_argument("--length-scale", type=float, default=1.01, help="true body offsets = model's x this")
    ap.add_argument("--joint-offsets", type=float, nargs="+", default=[0.01],
                    help="rad, 1 or one per joint: true angle = reported (encoder) angle + offset")
    ap.add_argument("--table", type=float, default=None, help="table height z, m (default: no table)")
    ap.add_argument("--link-radius", type=float, default=0.04, help="the links' capsule radius, m")
    ap.add_argument("--jump-limit", type=float, default=0.3, help="rad: a setpoint farther from the posture stops")
    ap.add_argument("--stop-ignore", type=float, default=3.0, help="s: commands ignored after a protective stop")
    ap.add_argument("--freeze-at", type=float, default=None, help="s after the first command: e-stop pressed")
    ap.add_argument("--freeze-for", type=float, default=0.0, help="s: then released")
    ap.add_argument("--stats", default="", help="JSON statistics file (every 2 s and at exit)")
    return ap


def main(argv: list[str] | None = None) -> int:
    ap = parser()
    a = ap.parse_args(argv)
    if a.rate <= 0 or a.lag < 0 or a.latency < 0 or a.noise < 0 or a.stop_ignore < 0 or a.jump_limit <= 0:
        ap.error("--rate and --jump-limit must be > 0; --lag, --latency, --noise, --stop-ignore >= 0")
    try:
        robot, core, info = build(a)
    except Exception as exc:  # noqa: BLE001 - ValueError of the options, ConfigError of the model
        ap.error(str(exc))
    import rclpy
    import rclpy.executors
    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = make_node(a, robot, core)
    log = node.get_logger()
    for notice in info["notices"]:
        log.info(notice)
    gap_mm = info["calibration_gap_m"] * 1e3
    log.info(f"{a.model}: joints {core.names}, velocity limits {core.vmax.tolist()} rad/s ({info['velocity_source']}),"
             f" acceleration {core.amax.tolist()} rad/s^2, lag {a.lag:g} s, latency {a.latency:g} s; calibration gap:"
             f" lengths x{a.length_scale:g}, offsets {a.joint_offsets} rad, effector {gap_mm:.1f} mm from the"
             f" model's at rest; table {a.table}, checked links {info['links']}")
    node.flush_events()
    stop: list[int] = []
    signal.signal(signal.SIGINT, lambda *_: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))

    def toggle(*_):
        core.user_frozen = not core.user_frozen
    signal.signal(signal.SIGUSR1, toggle)
    ex = rclpy.executors.SingleThreadedExecutor()
    ex.add_node(node)
    try:
        while not stop and rclpy.ok():
            ex.spin_once(timeout_sec=0.05)
    finally:
        node.write_stats(running=False)
        print(stats_line(core.stats()), flush=True)
        ex.remove_node(node)
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
