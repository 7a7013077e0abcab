"""Simulated 12-DOF quadruped for synergy learning (paper Sec. 4.2). ROS-free (MuJoCo).

Each leg has two hip DOF (abduction about the body's x axis, flexion about its y axis) and a knee
(about y): 12 joints, position actuators (the paper's "pre-programmed PID-like controller"). An
experiment restores the fixed rest state (the robot standing still at the origin, facing +x),
tracks a joint trajectory (the sinusoid synergy's positions, linearly interpolated between the
trajectory points) for its duration, and returns the outcome y = (u, v, φ): the torso's
displacement in the start frame, in task units (``position_scale`` units per metre), and its yaw
change in radians, unwrapped along the motion so that turning more than half a turn is seen
(Y's φ range is [-2π, 2π]). The paper's robot (Breve/ODE) has a decentred head that makes its
reachable set asymmetric in v; ours has one too (``head_offset``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from sagg_common.params import Schema, dataclass_schema
from sagg_common.synergy import Trajectory

from .model_spec import RestStateSim, model_doc, spec_from_params as _spec_from_params, validate_fields

LEGS = ("fl", "fr", "hl", "hr")  # front/hind, left/right
JOINTS_PER_LEG = ("hip_abd", "hip_flex", "knee")
JOINT_NAMES = [f"{leg}_{j}" for leg in LEGS for j in JOINTS_PER_LEG]
# rest posture: hips straight, knees bent (front legs backward, hind legs forward, like a table)
REST_POSTURE = [0.0, 0.35, -0.7, 0.0, 0.35, -0.7, 0.0, -0.35, 0.7, 0.0, -0.35, 0.7]


def _f(x: float) -> str:
    return repr(float(x))


@dataclass
class QuadrupedSpec:
    """Geometry and control of the quadruped (metres, kg, s). The paper gives none of these; ours
    make a random synergy move the torso a few body lengths or less, and ``position_scale`` maps
    metres to task units so the reachable extents compare with the paper's (Sec. 4.5: ACTUATOR-*
    within about [-5, 5] × [-2.5, 2.5] in (u, v)). Measured with the default synergy (amplitudes up to
    0.2/0.5/0.5 rad, 1 Hz, 3 s): 100 uniformly random synergies gave u in [-5.2, 5.0], v in
    [-5.4, 3.8], φ in [-2.0, 2.8] and 2 of 100 ended tilted more than 60°. A narrower, taller body
    (0.2 m wide, 0.15 m leg segments, kp 20) tipped over in 89 of 100."""

    body_length: float = 0.4
    body_width: float = 0.3
    body_height: float = 0.08
    body_mass: float = 2.0
    head_mass: float = 0.5
    head_offset: float = 0.06      # lateral (y) offset of the head: the paper's decentred head
    thigh: float = 0.1
    shin: float = 0.1
    leg_mass: float = 0.15
    friction: float = 1.0
    kp: float = 50.0
    joint_damping: float = 1.0
    hip_range: float = 1.2         # ± joint range (rad) of the hip joints
    knee_range: float = 2.0        # ± joint range (rad) of the knee
    timestep: float = 0.004
    control_every: int = 2         # physics steps per control update (250 Hz at 4 ms)
    settle_time: float = 1.0       # rest state: settled this long under the rest command at build time
    position_scale: float = 10.0   # task units per metre for u and v

    def validate(self) -> None:
        validate_fields(self, "quadruped", ("control_every",),
                        ("head_offset", "joint_damping", "head_mass", "settle_time"), 0.02)


SCHEMA: Schema = dataclass_schema("quadruped", QuadrupedSpec,
                                  model_doc("Quadruped model", "sagg_sim_bridge/quadruped.py"))


def spec_from_params(params: dict) -> QuadrupedSpec:
    return _spec_from_params(params, "quadruped", QuadrupedSpec)


def quadruped_mjcf(spec: QuadrupedSpec) -> str:
    """Generated MJCF: torso box with a head, four 3-DOF legs, floor, position actuators."""
    spec.validate()
    L, W, H = spec.body_length / 2, spec.body_width / 2, spec.body_height / 2
    r = 0.02
    z0 = spec.thigh + spec.shin + H + 0.02
    out = [
        '<mujoco model="sagg_quadruped">',
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="{_f(spec.timestep)}" integrator="implicitfast"/>',
        '  <visual><global offwidth="640" offheight="480"/></visual>',
        '  <default>',
        f'    <joint damping="{_f(spec.joint_damping)}" armature="0.01"/>',
        f'    <geom friction="{_f(spec.friction)} 0.01 0.001" contype="1" conaffinity="1"/>',
        '  </default>',
        '  <asset>',
        '    <texture name="grid" type="2d" builtin="checker" width="256" height="256" '
        'rgb1="0.85 0.85 0.85" rgb2="0.7 0.7 0.7"/>',
        '    <material name="grid" texture="grid" texrepeat="8 8"/>',
        '  </asset>',
        '  <worldbody>',
        '    <light pos="0 0 3" dir="0 0 -1" directional="true"/>',
        '    <geom name="floor" type="plane" size="10 10 0.1" material="grid" contype="1" conaffinity="1"/>',
        f'    <body name="torso" pos="0 0 {_f(z0)}">',
        '      <freejoint name="root"/>',
        f'      <geom name="torso" type="box" size="{_f(L)} {_f(W)} {_f(H)}" mass="{_f(spec.body_mass)}" '
        'rgba="0.3 0.5 0.8 1" contype="0" conaffinity="1"/>',
    ]
    if spec.head_mass > 0:
        out.append(f'      <geom name="head" type="sphere" size="{_f(0.8 * H + 0.01)}" '
                   f'pos="{_f(L + 0.03)} {_f(spec.head_offset)} {_f(H)}" mass="{_f(spec.head_mass)}" '
                   'rgba="0.9 0.6 0.2 1" contype="0" conaffinity="1"/>')
    hr, kr = spec.hip_range, spec.knee_range
    for leg in LEGS:
        sx = 1 if leg[0] == "f" else -1
        sy = 1 if leg[1] == "l" else -1
        out += [
            f'      <body name="{leg}_hip" pos="{_f(sx * (L - r))} {_f(sy * W)} 0">',
            f'        <joint name="{leg}_hip_abd" type="hinge" axis="1 0 0" range="{_f(-hr)} {_f(hr)}"/>',
            f'        <joint name="{leg}_hip_flex" type="hinge" axis="0 1 0" range="{_f(-hr)} {_f(hr)}"/>',
            f'        <geom type="capsule" fromto="0 0 0 0 0 {_f(-spec.thigh)}" size="{_f(r)}" '
            f'mass="{_f(spec.leg_mass / 2)}" rgba="0.2 0.2 0.2 1" contype="0" conaffinity="0"/>',
            f'        <body name="{leg}_shin" pos="0 0 {_f(-spec.thigh)}">',
            f'          <joint name="{leg}_knee" type="hinge" axis="0 1 0" range="{_f(-kr)} {_f(kr)}"/>',
            f'          <geom type="capsule" fromto="0 0 0 0 0 {_f(-spec.shin)}" size="{_f(r)}" '
            f'mass="{_f(spec.leg_mass / 2)}" rgba="0.2 0.2 0.2 1" contype="0" conaffinity="0"/>',
            f'          <geom name="{leg}_foot" type="sphere" pos="0 0 {_f(-spec.shin)}" size="{_f(1.2 * r)}" '
            'mass="0.01" rgba="0.1 0.1 0.1 1"/>',
            '        </body>',
            '      </body>',
        ]
    out += ['    </body>', '  </worldbody>', '  <actuator>']
    for name in JOINT_NAMES:
        rng = kr if name.endswith("knee") else hr
        out.append(f'    <position name="{name}" joint="{name}" kp="{_f(spec.kp)}" '
                   f'ctrlrange="{_f(-rng)} {_f(rng)}"/>')
    out += ['  </actuator>', '</mujoco>']
    return "\n".join(out) + "\n"


def yaw_of(quat: np.ndarray) -> float:
    """Yaw (rad, about world z) of a MuJoCo quaternion (w, x, y, z)."""
    w, x, y, z = quat
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def start_frame_outcome(p0, yaw0: float, p1, yaw_change: float, scale: float) -> np.ndarray:
    """Outcome (u, v, φ) of paper Sec. 4.2: the displacement ``p1 − p0`` (xy, metres) expressed in
    the start frame (rotated by −yaw0) times ``scale`` (task units per metre), and the yaw change φ."""
    c, s = math.cos(yaw0), math.sin(yaw0)
    dx, dy = float(p1[0] - p0[0]), float(p1[1] - p0[1])
    return np.array([scale * (c * dx + s * dy), scale * (-s * dx + c * dy), float(yaw_change)])


class QuadrupedSim(RestStateSim):
    """The simulated quadruped: a joint trajectory in, the outcome (u, v, φ) out."""

    task_dim = 3
    joint_names = JOINT_NAMES

    def __init__(self, spec: QuadrupedSpec | None = None):
        self.spec = spec or QuadrupedSpec()
        self.spec.validate()
        # the fixed rest state: start in the rest posture above the floor, settle under the rest command
        self._build(quadruped_mjcf(self.spec), JOINT_NAMES, REST_POSTURE, self.spec.settle_time,
                    self.spec.timestep)
        self._torso = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "torso")
        self.dt_control = self.spec.timestep * self.spec.control_every
        self.experiments = 0
        self.reset()

    @property
    def rest_outcome(self) -> np.ndarray:
        """The outcome of doing nothing: (0, 0, 0) by construction of the start frame."""
        return np.zeros(3)

    def body_pose(self) -> tuple[np.ndarray, float]:
        return self.data.xpos[self._torso].copy(), yaw_of(self.data.xquat[self._torso])

    def _targets(self, traj: Trajectory) -> np.ndarray:
        if traj.positions is None:
            raise ValueError("quadruped trajectory: allowed: positions (position-controlled joints)")
        if list(traj.joint_names) != list(JOINT_NAMES):
            order = [list(traj.joint_names).index(n) if n in traj.joint_names else -1 for n in JOINT_NAMES]
            if min(order) < 0 or len(traj.joint_names) != len(JOINT_NAMES):
                raise ValueError(f"quadruped trajectory joints: got {list(traj.joint_names)}; "
                                 f"allowed: exactly {JOINT_NAMES}")
            pos = traj.positions[:, order]
        else:
            pos = traj.positions
        n_ctrl = int(math.ceil(round(traj.times[-1] / self.dt_control, 9)))
        t = np.arange(n_ctrl) * self.dt_control
        return np.stack([np.interp(t, traj.times, pos[:, j]) for j in range(pos.shape[1])], axis=1)

    def execute(self, traj: Trajectory) -> np.ndarray:
        """Run a joint trajectory from the rest state and return (u, v, φ) (Sec. 4.2). The joints
        track the linearly interpolated positions, updated every ``control_every`` physics steps,
        until the trajectory's last time."""
        targets = self._targets(traj)
        self.reset()
        m, d, k = self.model, self.data, self.spec.control_every
        p0, yaw0 = self.body_pose()
        yaw_prev, turned = yaw0, 0.0
        quat = d.xquat[self._torso]
        ctrl = d.ctrl
        for row in targets:
            ctrl[:] = row
            mujoco.mj_step(m, d, nstep=k)
            yaw = yaw_of(quat)
            turned += wrap(yaw - yaw_prev)
            yaw_prev = yaw
        mujoco.mj_kinematics(m, d)  # poses after the last step (mj_step leaves them one step behind)
        turned += wrap(yaw_of(quat) - yaw_prev)
        self.experiments += 1
        return start_frame_outcome(p0, yaw0, d.xpos[self._torso], turned, self.spec.position_scale)
