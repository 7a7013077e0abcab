"""Simulated fishing rod for synergy learning (paper Sec. 5.1). ROS-free (MuJoCo).

A 4-DOF arm (base yaw, shoulder, elbow and wrist pitch) on a post at the origin holds a rod; a
flexible line (a chain of short segments on ball joints) carries a float. The water is the plane
z = 0. An experiment restores the rest state (the float hanging still above the water), tracks the
trajectory's joint velocities (zero-order hold; the joints follow the integrated velocity with stiff
position servos, the paper's "low-level pre-programmed PID controller"), holds still after the last
point, and watches the float for ``watch_time`` seconds in all. The outcome is the float's (x, y)
at its first contact with the water (the crossing of z = float radius, linearly interpolated between
two checks), times ``position_scale``; with no contact the trial has no outcome (None): the caller
discards and counts it (Sec. 5.1: "if not, we do not consider this trial").

Simplifications (ours): the arm, rod, line and float do not collide with each other (contacts are
off: only the float's height is watched); the rod is rigid and the line carries the flexibility.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from sagg_common.params import Schema, dataclass_schema
from sagg_common.synergy import Trajectory

from .model_spec import RestStateSim, model_doc, spec_from_params as _spec_from_params, validate_fields

JOINT_NAMES = ["base_yaw", "shoulder", "elbow", "wrist"]
# rest: facing +x turned by 0.3 rad (an asymmetric rest, like the paper's), upper arm up, forearm and
# rod raised forward
REST_POSTURE = [0.3, -0.2, 0.9, 0.3]


def _f(x: float) -> str:
    return repr(float(x))


@dataclass
class FishingSpec:
    """Geometry and control of the fishing robot (metres, kg, s). The paper gives none of these;
    ``position_scale`` (task units per metre) makes the reachable set a disk of radius ≈ 1 around
    the base (Sec. 5.1): measured over 200 uniformly random synergies with the default velocity
    range (±1.5 rad/s per joint), 67.5 % touched the water, landing radii up to 1.36 m (99th
    percentile 1.30 m), so 0.75 units per metre gives a reachable disk of radius ≈ 1."""

    post_height: float = 0.3
    upper_arm: float = 0.25
    forearm: float = 0.2
    rod: float = 0.5
    line_segments: int = 6
    line_length: float = 0.45
    line_mass: float = 0.003
    line_damping: float = 0.0005
    float_radius: float = 0.02
    float_mass: float = 0.01
    kp: float = 400.0
    joint_damping: float = 20.0
    joint_range: float = 2.6       # ± range (rad) of every arm joint
    timestep: float = 0.002
    check_every: int = 5           # physics steps between velocity-reference updates / water checks
    watch_time: float = 4.0        # seconds watched from the start (the motion lasts 2 s)
    settle_time: float = 2.0       # rest state: settled this long at build time
    position_scale: float = 0.75   # task units per metre

    def validate(self) -> None:
        validate_fields(self, "fishing", ("line_segments", "check_every"), ("line_damping", "settle_time"), 0.01)


SCHEMA: Schema = dataclass_schema("fishing", FishingSpec, model_doc("Fishing-rod model", "sagg_sim_bridge/fishing.py"))


def spec_from_params(params: dict) -> FishingSpec:
    return _spec_from_params(params, "fishing", FishingSpec)


def fishing_mjcf(spec: FishingSpec) -> str:
    """Generated MJCF: post, 4-DOF arm, rigid rod, line of ball-jointed segments, float, water."""
    spec.validate()
    seg = spec.line_length / spec.line_segments
    seg_mass = spec.line_mass / spec.line_segments
    jr = spec.joint_range
    out = [
        '<mujoco model="sagg_fishing_rod">',
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="{_f(spec.timestep)}" integrator="implicitfast">',
        '    <flag contact="disable"/>',
        '  </option>',
        '  <visual><global offwidth="640" offheight="480"/></visual>',
        '  <worldbody>',
        '    <light pos="0 0 3" dir="0 0 -1" directional="true"/>',
        '    <geom name="water" type="plane" size="3 3 0.1" rgba="0.3 0.5 0.9 0.6"/>',
        f'    <geom name="post" type="cylinder" fromto="0 0 0 0 0 {_f(spec.post_height)}" size="0.04" '
        'rgba="0.5 0.4 0.3 1"/>',
        f'    <body name="base" pos="0 0 {_f(spec.post_height)}">',
        f'      <joint name="base_yaw" type="hinge" axis="0 0 1" range="{_f(-jr)} {_f(jr)}"/>',
        '      <geom type="sphere" size="0.04" mass="0.5" rgba="0.3 0.3 0.3 1"/>',
        '      <body name="upper_arm">',
        f'        <joint name="shoulder" type="hinge" axis="0 1 0" range="{_f(-jr)} {_f(jr)}"/>',
        f'        <geom type="capsule" fromto="0 0 0 0 0 {_f(spec.upper_arm)}" size="0.025" mass="0.3" '
        'rgba="0.3 0.5 0.8 1"/>',
        f'        <body name="forearm" pos="0 0 {_f(spec.upper_arm)}">',
        f'          <joint name="elbow" type="hinge" axis="0 1 0" range="{_f(-jr)} {_f(jr)}"/>',
        f'          <geom type="capsule" fromto="0 0 0 0 0 {_f(spec.forearm)}" size="0.02" mass="0.2" '
        'rgba="0.3 0.5 0.8 1"/>',
        f'          <body name="hand" pos="0 0 {_f(spec.forearm)}">',
        f'            <joint name="wrist" type="hinge" axis="0 1 0" range="{_f(-jr)} {_f(jr)}"/>',
        f'            <geom name="rod" type="capsule" fromto="0 0 0 0 0 {_f(spec.rod)}" size="0.008" '
        'mass="0.05" rgba="0.4 0.25 0.1 1"/>',
        f'            <site name="rod_tip" pos="0 0 {_f(spec.rod)}" size="0.01"/>',
    ]
    indent = "            "
    pos = f"0 0 {_f(spec.rod)}"
    for i in range(spec.line_segments):
        out += [
            f'{indent}<body name="line_{i}" pos="{pos}">',
            f'{indent}  <joint name="line_{i}" type="ball" damping="{_f(spec.line_damping)}"/>',
            f'{indent}  <geom type="capsule" fromto="0 0 0 0 0 {_f(-seg)}" size="0.002" mass="{_f(seg_mass)}" '
            'rgba="0.9 0.9 0.9 1"/>',
        ]
        indent += "  "
        pos = f"0 0 {_f(-seg)}"
    out += [
        f'{indent}<body name="float" pos="{pos}">',
        f'{indent}  <geom type="sphere" size="{_f(spec.float_radius)}" mass="{_f(spec.float_mass)}" '
        'rgba="0.9 0.1 0.1 1"/>',
        f'{indent}</body>',
    ]
    for _ in range(spec.line_segments + 4):
        indent = indent[:-2]
        out.append(f"{indent}</body>")
    out += ['  </worldbody>', '  <actuator>']
    for name in JOINT_NAMES:
        out.append(f'    <position name="{name}" joint="{name}" kp="{_f(spec.kp)}" '
                   f'kv="{_f(spec.joint_damping)}" ctrlrange="{_f(-jr)} {_f(jr)}"/>')
    out += ['  </actuator>', '</mujoco>']
    return "\n".join(out) + "\n"


def first_crossing(z0: float, z1: float, p0, p1, level: float) -> np.ndarray | None:
    """Contact detection: the point where the segment p0 → p1 (heights z0 → z1) first reaches
    ``level`` from above (linear interpolation), or None when it stays above."""
    if z1 > level:
        return None
    if z0 <= level:
        return np.asarray(p0, dtype=float).copy()
    s = (z0 - level) / (z0 - z1)
    return np.asarray(p0, dtype=float) + s * (np.asarray(p1, dtype=float) - np.asarray(p0, dtype=float))


class FishingSim(RestStateSim):
    """The simulated fishing rod: a joint-velocity trajectory in, the float's landing (x, y) out."""

    task_dim = 2
    joint_names = JOINT_NAMES

    def __init__(self, spec: FishingSpec | None = None):
        self.spec = spec or FishingSpec()
        self.spec.validate()
        self._build(fishing_mjcf(self.spec), JOINT_NAMES, REST_POSTURE, self.spec.settle_time,
                    self.spec.timestep)
        self._float = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, "float")
        self.lower = np.full(4, -self.spec.joint_range)
        self.upper = np.full(4, self.spec.joint_range)
        self.experiments = 0
        self.no_contact = 0
        self.reset()
        self.rest_float = self.data.xpos[self._float].copy()
        if self.rest_float[2] <= self.spec.float_radius:
            raise ValueError("fishing model: the float touches the water at rest; shorten "
                             "fishing.line_length or raise fishing.post_height")

    @property
    def rest_outcome(self) -> np.ndarray:
        """The float's (x, y) at rest (task units): y_start of the competence (Sec. 3.5)."""
        return self.rest_float[:2] * self.spec.position_scale

    def _velocities(self, traj: Trajectory) -> np.ndarray:
        if traj.velocities is None:
            raise ValueError("fishing trajectory: allowed: velocities (velocity-tracked joints)")
        if list(traj.joint_names) != JOINT_NAMES:
            if sorted(traj.joint_names) != sorted(JOINT_NAMES):
                raise ValueError(f"fishing trajectory joints: got {list(traj.joint_names)}; "
                                 f"allowed: exactly {JOINT_NAMES}")
            return traj.velocities[:, [list(traj.joint_names).index(n) for n in JOINT_NAMES]]
        return traj.velocities

    def execute(self, traj: Trajectory) -> np.ndarray | None:
        """Run a joint-velocity trajectory from rest; return the float's (x, y) at first water
        contact (task units) or None (no contact within ``watch_time``; counted in ``no_contact``).
        The velocity reference is integrated into position targets (clipped to the joint range)
        every ``check_every`` physics steps; the height check runs at the same rate."""
        vel = self._velocities(traj)
        self.reset()
        m, d, k = self.model, self.data, self.spec.check_every
        dt = self.spec.timestep * k
        n_checks = int(math.ceil(round(self.spec.watch_time / dt, 9)))
        level = self.spec.float_radius
        ref = self.rest.copy()
        lo, hi = self.lower, self.upper
        fpos = d.xpos[self._float]
        mujoco.mj_kinematics(m, d)
        prev = fpos.copy()
        times = traj.times
        result = None
        for i in range(n_checks):
            t = i * dt
            j = int(np.searchsorted(times, t, side="right")) - 1
            v = vel[max(j, 0)] if t <= times[-1] else vel[-1]
            ref = np.clip(ref + v * dt, lo, hi)
            d.ctrl[:] = ref
            mujoco.mj_step(m, d, nstep=k)
            mujoco.mj_kinematics(m, d)
            hit = first_crossing(prev[2], fpos[2], prev, fpos, level)
            if hit is not None:
                result = hit[:2] * self.spec.position_scale
                break
            prev = fpos.copy()
        self.experiments += 1
        if result is None:
            self.no_contact += 1
        return result
