"""Tests of the model arm: a robot from its URDF/MJCF file in the simulator core
(sagg_sim_bridge.model_arm, .model_load, .model_kin, .arms), its 3-D reachable set and test goals,
and that the planar arm's reachable area and test goals are byte-identical to the branch point."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from sagg_common.params import ConfigError, schema_defaults
from sagg_sim_bridge.arm import ArmSim, ArmSpec
from sagg_sim_bridge.arms import (arm_base_point, arm_reach, arm_reachable_area, arm_spec_from_params,
                                  arm_test_goals, make_arm_sim)
from sagg_sim_bridge.model_arm import ModelArmSim
from sagg_sim_bridge.params import SCHEMA

REPO = Path(__file__).resolve().parents[1]
CONFIG = REPO / "config"

# ------------------------------------------------------------------ a small spatial URDF
# Origins (xyz, rpy) and axes of the test arm, used both to write the URDF and to compute the
# effector by hand below.
J1 = dict(xyz=(0.1, -0.05, 0.2), rpy=(0.0, 0.0, 0.3), axis=(0.0, 0.0, 1.0), limit=(-2.0, 2.0))
J2 = dict(xyz=(0.0, 0.08, 0.25), rpy=(0.4, -0.2, 0.1), axis=(0.0, 1.0, 0.0), limit=(-1.5, 1.5))
J3 = dict(xyz=(0.3, 0.0, 0.02), rpy=(0.0, 0.5, 0.0), axis=(0.6, 0.0, 0.8), limit=(-2.5, 1.0))
TOOL = dict(xyz=(0.12, 0.01, -0.03), rpy=(0.0, 0.0, -0.785))
# (collision meshes in OBJ: MuJoCo reads OBJ text, and STL only in binary form)
MESHES = {"base_link": ("package://test_arm_pkg/meshes/base.dae", "package://test_arm_pkg/meshes/base.obj"),
          "l1": ("package://test_arm_pkg/meshes/l1.dae", "package://test_arm_pkg/meshes/l1.obj")}


def _f(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def write_urdf(path: Path, j2_type: str = "revolute") -> Path:
    """The test arm: base_link -j1-> l1 -j2-> l2 -j3-> l3 -fixed-> tool0; base_link and l1 have visual
    and collision meshes under package://test_arm_pkg/ (which exist only when a test creates them)."""
    def link(name: str) -> str:
        inner = ('<inertial><mass value="1.0"/>'
                 '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial>')
        if name in MESHES:
            vis, col = MESHES[name]
            inner += (f'<visual><geometry><mesh filename="{vis}"/></geometry></visual>'
                      f'<collision><geometry><mesh filename="{col}"/></geometry></collision>')
        return f'<link name="{name}">{inner}</link>'

    def joint(name: str, kind: str, parent: str, child: str, j: dict) -> str:
        out = (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
               f'<origin xyz="{_f(j["xyz"])}" rpy="{_f(j["rpy"])}"/>')
        if "axis" in j:
            out += f'<axis xyz="{_f(j["axis"])}"/>'
        if kind == "revolute":
            out += f'<limit lower="{j["limit"][0]}" upper="{j["limit"][1]}" effort="10" velocity="1"/>'
        return out + "</joint>"

    text = "\n".join([
        '<robot name="test_arm">', link("base_link"), link("l1"), link("l2"), link("l3"), '<link name="tool0"/>',
        joint("j1", "revolute", "base_link", "l1", J1), joint("j2", j2_type, "l1", "l2", J2),
        joint("j3", "revolute", "l2", "l3", J3), joint("tool_joint", "fixed", "l3", "tool0", TOOL), "</robot>"])
    path.write_text(text)
    return path


def params(**kw) -> dict:
    """The bridge's resolved parameters (schema defaults) with ``arm.<key>`` / ``rest_posture`` set."""
    p = schema_defaults(SCHEMA)
    for k, v in kw.items():
        p[k if k == "rest_posture" else "arm." + k.replace("__", ".")] = v
    return p


def urdf_spec(tmp_path: Path, **kw):
    write_urdf(tmp_path / "arm.urdf", kw.pop("j2_type", "revolute"))
    base = dict(model="arm.urdf", effector="tool0", rest_posture=[0.1, 0.2, -0.3])
    base.update(kw)
    return arm_spec_from_params(params(**base), str(tmp_path))


def transform(xyz, rpy) -> np.ndarray:
    """URDF origin: translation xyz, then fixed-axis roll-pitch-yaw R = Rz(y) Ry(p) Rx(r)."""
    r, p, y = rpy
    rx = np.array([[1, 0, 0], [0, math.cos(r), -math.sin(r)], [0, math.sin(r), math.cos(r)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    t = np.eye(4)
    t[:3, :3] = rz @ ry @ rx
    t[:3, 3] = xyz
    return t


def rotation(axis, q) -> np.ndarray:
    """Homogeneous rotation by q about the unit vector axis (Rodrigues)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = np.eye(4)
    t[:3, :3] = np.eye(3) + math.sin(q) * k + (1 - math.cos(q)) * k @ k
    return t


def hand_tool0(q) -> np.ndarray:
    """tool0's world position: T = Π (origin_i · Rot(axis_i, q_i)) · origin_tool."""
    t = np.eye(4)
    for j, qi in zip((J1, J2, J3), q):
        t = t @ transform(j["xyz"], j["rpy"]) @ rotation(j["axis"], qi)
    return (t @ transform(TOOL["xyz"], TOOL["rpy"]))[:3, 3]


# ------------------------------------------------------------------ loading a robot_description
def test_urdf_with_missing_package_meshes_loads_kinematic_and_says_so_once(tmp_path, capsys):
    spec = urdf_spec(tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    # the collision meshes are named; MuJoCo never loads URDF visuals, so they are not looked for
    assert MESHES["base_link"][1] in err[0] and MESHES["l1"][1] in err[0] and "dropped" in err[0]
    sims = [make_arm_sim(spec, seed=i) for i in range(3)]
    assert all(isinstance(s, ModelArmSim) for s in sims)
    assert capsys.readouterr().err == ""  # once per process, not per simulator
    assert spec.joint_names() == ["j1", "j2", "j3"]
    # the fixed tool frame is kept as a body (MuJoCo fuses it by default) and is the effector
    assert sims[0].model.body("tool0").id > 0


def test_dynamic_mode_needs_the_meshes_and_names_them(tmp_path):
    with pytest.raises(ConfigError, match=r"package://test_arm_pkg/meshes/base.obj.*arm.mode"):
        urdf_spec(tmp_path, mode="dynamic")


OBJ = "v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n"


@pytest.mark.parametrize("where", ["package_paths", "ament_prefix"])
def test_package_meshes_are_found_through_package_paths_and_ament_prefix_path(tmp_path, monkeypatch, where):
    root = tmp_path / ("pkgs" if where == "package_paths" else "prefix/share")
    meshes = root / "test_arm_pkg" / "meshes"
    meshes.mkdir(parents=True)
    for name in ("base.obj", "l1.obj"):
        (meshes / name).write_text(OBJ)
    kw = {"mode": "dynamic"}
    if where == "package_paths":
        kw["package_paths"] = ["pkgs"]
        monkeypatch.setenv("AMENT_PREFIX_PATH", "")
    else:
        monkeypatch.setenv("AMENT_PREFIX_PATH", f"/nonexistent:{tmp_path / 'prefix'}")
    spec = urdf_spec(tmp_path, **kw)  # dynamic mode: every mesh must be found
    sim = make_arm_sim(spec, 0)
    assert sim.model.nmesh == 2 and sim.model.nu == 3  # the meshes, and a position servo per joint
    a, _ = sim.command(np.array([0.2, 0.1, -0.2]))
    assert sim.last_settled and np.allclose(a, [0.2, 0.1, -0.2], atol=1e-3)


# ------------------------------------------------------------------ kinematics
def test_effector_equals_the_hand_computed_transform(tmp_path):
    sim = make_arm_sim(urdf_spec(tmp_path), 0)
    for q in ([0.0, 0.0, 0.0], [0.7, -1.1, 0.4], [-1.9, 1.4, -2.2]):
        _, y = sim.command(np.array(q))
        np.testing.assert_allclose(y, hand_tool0(q), rtol=0, atol=1e-12)
        np.testing.assert_allclose(sim.tip_positions(np.array([q]))[0], hand_tool0(q), rtol=0, atol=1e-12)


def test_selected_joints_are_commanded_in_their_order_and_the_others_held_at_rest(tmp_path):
    spec = urdf_spec(tmp_path, joints=["j3", "j1"], rest_posture=[0.5, -0.4])
    sim = make_arm_sim(spec, 0)
    assert sim.joint_names == ["j3", "j1"]
    a, y = sim.command(np.array([0.3, 1.2]))
    np.testing.assert_array_equal(a, [0.3, 1.2])
    np.testing.assert_allclose(y, hand_tool0([1.2, 0.0, 0.3]), atol=1e-12)  # j2 held at its rest 0
    batch = np.random.default_rng(0).uniform(sim.lower, sim.upper, (50, 2))
    np.testing.assert_allclose(sim.tip_positions(batch), sim.fk_mujoco(batch), rtol=0, atol=1e-12)


def test_joint_without_range_needs_joint_limits(tmp_path):
    with pytest.raises(ConfigError) as exc:
        urdf_spec(tmp_path, j2_type="continuous")
    msg = str(exc.value)
    assert "arm.joint_limits" in msg and "j2" in msg and "\n" not in msg
    spec = urdf_spec(tmp_path, j2_type="continuous", joint_limits__lower=[-1.0, -3.0, -1.0],
                     joint_limits__upper=[1.0, 3.0, 1.0])
    lo, hi = spec.limits()
    np.testing.assert_array_equal(lo, [-1.0, -3.0, -1.0])
    np.testing.assert_array_equal(hi, [1.0, 3.0, 1.0])


def test_missing_effector_is_one_clear_error_listing_the_names(tmp_path):
    with pytest.raises(ConfigError) as exc:
        urdf_spec(tmp_path, effector="gripper_tip")
    msg = str(exc.value)
    assert "arm.effector" in msg and "gripper_tip" in msg and "tool0" in msg and "\n" not in msg


def test_rest_posture_from_home_keyframe_else_parameter_else_an_error_naming_both(tmp_path):
    with pytest.raises(ConfigError, match=r"rest_posture.*'home'"):
        urdf_spec(tmp_path, rest_posture=[0.0])  # [0.0] is the schema's "not given"
    spec = arm_spec_from_params(params(model=str(CONFIG / "robots/arm6.xml"), effector="tool"), None)
    np.testing.assert_array_equal(spec.rest_posture(), [0, -2.0, 1.6, -1.1707963267948966, -1.5707963267948966, 0])
    with pytest.raises(ConfigError, match=r"rest_posture: got 2 values"):
        urdf_spec(tmp_path, rest_posture=[0.1, 0.2])


def test_task_axes_xy_gives_2d_points(tmp_path):
    sim3 = make_arm_sim(urdf_spec(tmp_path), 0)
    sim2 = make_arm_sim(urdf_spec(tmp_path, task_axes=["x", "y"]), 0)
    assert sim2.task_dim == 2 and sim3.task_dim == 3
    q = np.array([0.4, -0.3, 0.9])
    _, y2 = sim2.command(q)
    _, y3 = sim3.command(q)
    assert y2.shape == (2,) and sim2.observe()[1].shape == (2,)
    np.testing.assert_array_equal(y2, y3[:2])
    assert sim2.tip_positions(np.array([q, q])).shape == (2, 2)
    with pytest.raises(ConfigError, match="arm.task_axes"):
        urdf_spec(tmp_path, task_axes=["y", "x"])


def test_a_task_space_of_another_size_than_the_task_axes_is_one_clear_error(tmp_path):
    from sagg_bringup.graph.setups import load_experiment_config
    cfg = tmp_path / "arm6_2d.yaml"
    cfg.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"task_space": {"lower": [-1.0, -1.0], "upper": [1.0, 1.0]}}},
        "sagg_sim_bridge": {"ros__parameters": {"arm": {"model": str(REPO / "config/robots/arm6.xml"),
                                                        "effector": "tool"}}}}))
    with pytest.raises(ConfigError, match=r"'task_space.lower': 2 values; allowed: 3.*arm.task_axes 'xyz'"):
        load_experiment_config(cfg)
    # the same arm with a 2-D task (a camera above the table) is fine
    data = yaml.safe_load(cfg.read_text())
    data["sagg_sim_bridge"]["ros__parameters"]["arm"]["task_axes"] = "xy"
    cfg.write_text(yaml.safe_dump(data))
    load_experiment_config(cfg)


def test_command_observe_and_batched_fk_agree(tmp_path):
    sim = make_arm_sim(urdf_spec(tmp_path), 0)
    rng = np.random.default_rng(1)
    postures = rng.uniform(sim.lower, sim.upper, (40, 3))
    ys = np.array([sim.command(q)[1] for q in postures])
    np.testing.assert_array_equal(ys[-1], sim.observe()[1])
    np.testing.assert_allclose(sim.tip_positions(postures), ys, rtol=0, atol=1e-12)  # batched FK
    np.testing.assert_allclose(np.array([sim.tip_positions(q) for q in postures]), ys, rtol=0, atol=1e-12)


@pytest.mark.parametrize("mode", ["kinematic", "dynamic"])
def test_state_round_trip_gives_identical_commands_with_motor_noise(mode):
    spec = arm_spec_from_params(params(model=str(CONFIG / "robots/arm6.xml"), effector="tool", mode=mode,
                                       motor_noise=0.2), None)
    rng = np.random.default_rng(2)
    sim = make_arm_sim(spec, seed=5)
    for _ in range(300):  # beyond one noise block (256 micro-actions)
        sim.command(sim.observe()[0] + rng.uniform(-0.05, 0.05, 6))
    state = json.loads(json.dumps(sim.get_state()))
    steps = rng.uniform(-0.05, 0.05, (20, 6))
    first = [sim.command(sim.observe()[0] + s) for s in steps]
    other = make_arm_sim(spec, seed=77)
    other.set_state(state)
    again = [other.command(other.observe()[0] + s) for s in steps]
    for (a1, y1), (a2, y2) in zip(first, again):
        np.testing.assert_array_equal(a1, a2)
        np.testing.assert_array_equal(y1, y2)
    assert not np.array_equal(first[0][0], sim.observe()[0])  # the commands did move the arm


EVERY_JOINT = """<mujoco model="every_joint">
  <compiler angle="radian" autolimits="true"/>
  <worldbody>
    <body name="base" pos="0.3 0 0">
      <freejoint name="float"/>
      <geom type="sphere" size="0.05"/>
      <body name="carriage" pos="0 0.1 0" euler="0.3 0 0">
        <joint name="rail" type="slide" axis="1 0.5 0" range="-0.2 0.3" ref="0.05"/>
        <geom type="sphere" size="0.03"/>
        <body name="wrist" pos="0 0 0.2">
          <joint name="swivel" type="ball" pos="0 0 0.02"/>
          <geom type="sphere" size="0.03"/>
          <body name="forearm" pos="0.1 0 0.1" quat="0.9 0.1 -0.3 0.2">
            <joint name="elbow" axis="0.3 -0.4 0.8" pos="0.05 0.02 0" range="-2 2" ref="0.4"/>
            <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.02"/>
            <site name="tip" pos="0.25 0.01 -0.02"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <keyframe>
    <key name="home" qpos="0.1 -0.2 0.4  0.8 0.2 -0.4 0.3  0.1  0.9 0.1 0.3 -0.2  0.5"/>
  </keyframe>
</mujoco>
"""


def test_batched_fk_matches_mujoco_for_every_joint_kind(tmp_path):
    """Commanded slide and hinge (off-centre anchor, nonzero ref) below a held free joint and a held
    ball joint: the vectorised FK equals mj_kinematics, and every position lies in the bounding ball
    that reach and the reachable set rely on."""
    path = tmp_path / "every_joint.xml"
    path.write_text(EVERY_JOINT)
    spec = arm_spec_from_params(params(model=str(path), effector="tip"), None)
    sim = make_arm_sim(spec, 0)
    assert sim.joint_names == ["rail", "elbow"]  # hinge/slide joints only; free and ball held
    postures = np.random.default_rng(6).uniform(sim.lower, sim.upper, (500, 2))
    y = sim.tip_positions(postures)
    np.testing.assert_allclose(y, sim.fk_mujoco(postures), rtol=0, atol=1e-12)
    np.testing.assert_allclose(sim.command(postures[0])[1], y[0], rtol=0, atol=1e-12)
    center, radius = sim.arm.kin.ball()
    assert np.all(np.linalg.norm(y - center, axis=1) <= radius + 1e-12)
    assert spec.reach() <= radius + 1e-12


# ------------------------------------------------------------------ the example arms
def dh_standard(q, d, a, alpha) -> np.ndarray:
    t = np.eye(4)
    for qi, di, ai, al in zip(q, d, a, alpha):
        ct, st, ca, sa = math.cos(qi), math.sin(qi), math.cos(al), math.sin(al)
        t = t @ np.array([[ct, -st * ca, st * sa, ai * ct], [st, ct * ca, -ct * sa, ai * st],
                          [0, sa, ca, di], [0, 0, 0, 1]])
    return t[:3, 3]


def dh_modified(q, rows, tail) -> np.ndarray:
    t = np.eye(4)
    for qi, (al, ai, di) in zip(q, rows):
        t = t @ transform((0, 0, 0), (al, 0, 0)) @ transform((ai, 0, 0), (0, 0, 0)) @ \
            transform((0, 0, 0), (0, 0, qi)) @ transform((0, 0, di), (0, 0, 0))
    return (t @ transform((0, 0, tail), (0, 0, 0)))[:3, 3]


def test_example_arms_have_the_published_kinematics():
    """config/robots/arm6.xml is the UR5's standard DH chain, arm7.urdf the Panda's modified DH chain
    (+ a tool 0.1034 m beyond the flange); both load from their configs' directory."""
    a6 = make_arm_sim(arm_spec_from_params(params(model="robots/arm6.xml", effector="tool"), str(CONFIG)), 0)
    rest7 = [0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4]
    a7 = make_arm_sim(arm_spec_from_params(params(model="robots/arm7.urdf", effector="tool0", rest_posture=rest7),
                                           str(CONFIG)), 0)
    rng = np.random.default_rng(3)
    for q in rng.uniform(a6.lower, a6.upper, (5, 6)):
        np.testing.assert_allclose(
            a6.command(q)[1], dh_standard(q, [0.089159, 0, 0, 0.10915, 0.09465, 0.0823], [0, -0.425, -0.39225, 0, 0, 0],
                                          [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]), atol=1e-12)
    rows = [(0, 0, 0.333), (-math.pi / 2, 0, 0), (math.pi / 2, 0, 0.316), (math.pi / 2, 0.0825, 0),
            (-math.pi / 2, -0.0825, 0.384), (math.pi / 2, 0, 0), (math.pi / 2, 0.088, 0)]
    for q in rng.uniform(a7.lower, a7.upper, (5, 7)):
        np.testing.assert_allclose(a7.command(q)[1], dh_modified(q, rows, 0.107 + 0.1034), atol=1e-12)
    np.testing.assert_array_equal(a7.rest, rest7)
    np.testing.assert_allclose(a7.upper[3], -0.0698)  # the Panda's elbow never straightens


# ------------------------------------------------------------------ reachable set, test goals
SHELL_ARM = """<mujoco model="shell">
  <compiler angle="radian"/>
  <worldbody>
    <body name="b0">
      <joint name="yaw" axis="0 0 1" range="-3.141592653589793 3.141592653589793"/>
      <body name="b1" pos="0 0 0.1">
        <joint name="pitch" axis="0 1 0" range="-3.141592653589793 3.141592653589793"/>
        <body name="b2" pos="0.5 0 0">
          <joint name="elbow" axis="0 1 0" range="-3.141592653589793 3.141592653589793"/>
          <site name="tip" pos="0.3 0 0"/>
        </body>
      </body>
    </body>
  </worldbody>
  <keyframe><key name="home" qpos="0 0.3 0.5"/></keyframe>
</mujoco>
"""
L1, L2, SHOULDER = 0.5, 0.3, np.array([0.0, 0.0, 0.1])


@pytest.fixture(scope="module")
def shell(tmp_path_factory):
    """A 2-link spatial arm (yaw, pitch, elbow, all ±π) whose workspace is the spherical shell
    |p - shoulder| in [l1 - l2, l1 + l2], its 3-D reachable set and 100 test goals."""
    path = tmp_path_factory.mktemp("shell") / "shell.xml"
    path.write_text(SHELL_ARM)
    spec = arm_spec_from_params(params(model=str(path), effector="tip"), None)
    lo, hi = SHOULDER - 0.9, SHOULDER + 0.9
    area = arm_reachable_area(spec, lo, hi, seed=4)
    goals = arm_test_goals(spec, lo, hi, n=100, seed=4, area=area)
    return spec, area, goals


def test_reach_and_base_point_of_the_shell_arm(shell):
    spec, _, _ = shell
    assert arm_reach(spec) == pytest.approx(L1 + L2, abs=1e-6)
    np.testing.assert_array_equal(arm_base_point(spec), SHOULDER)
    assert arm_reach(ArmSpec()) == 50.0


def test_3d_test_goals_are_reached_positions_in_distinct_cells(shell):
    _, area, goals = shell
    assert area.mask.ndim == 3 and goals.shape == (100, 3)
    r = np.linalg.norm(goals - SHOULDER, axis=1)
    assert np.all(r >= L1 - L2 - 1e-9) and np.all(r <= L1 + L2 + 1e-9)  # in the shell: reachable
    assert np.all(area.contains(goals))
    cells = np.floor((goals - area.lower) / area.cell_size).astype(int)
    assert len(np.unique(cells, axis=0)) == 100


def test_3d_reachable_volume_of_the_shell_arm_within_3_percent(shell):
    """Analytic volume 4/3·π·((l1+l2)³ - (l1-l2)³) = 2.111 m³; the estimate at the default resolution
    (reach/25 = 0.032 m, 2M samples) is 1.1% low (seeds 0, 4, 9: -1.08, -1.10, -1.06%; counting
    boundary voxels by their 6 face neighbours instead of all 26 gave +3.0%): tolerance 3%."""
    _, area, _ = shell
    exact = 4.0 / 3.0 * math.pi * ((L1 + L2) ** 3 - (L1 - L2) ** 3)
    assert area.area() == pytest.approx(exact, rel=0.03)


# The digests of the next test, computed in a child process (see there why).
_PLANAR_DIGESTS = """
import hashlib, json
import numpy as np
from sagg_sim_bridge.arm import ArmSpec, reachable_area, test_goals
from sagg_sim_bridge.arms import arm_test_goals

def sha(*arrays):
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]

ratio15 = ArmSpec(dof=7, total_length=1.0, link_ratio=1.5, joint_limit=1.0471975511965976,
                  base_limit=1.0471975511965976, rest_shape="zigzag")
out = []
for spec, lo, hi in ((ArmSpec(), [0.0, -60.0], [100.0, 60.0]), (ratio15, [-0.5, -1.0], [1.0, 1.0])):
    a = reachable_area(spec, lo, hi, seed=0)
    g = test_goals(spec, lo, hi, n=100, seed=0, area=a)
    out.append({"area": sha(a.mask, a.cell_points, a.lower, a.upper, np.float64(a.resolution)),
                "goals": sha(g),
                "registry_same": arm_test_goals(spec, lo, hi, n=100, seed=0).tobytes() == g.tobytes()})
print(json.dumps(out))
"""


def test_planar_reachable_area_and_test_goals_are_unchanged():
    """Digests of the planar arm's reachable area (mask, reached points, box) and test goals,
    computed before the arm went N-D (commit 58a4de9): byte-identical after the N-D rewrite.

    Those digests were taken where numpy's dispatch went up to X86_V3 (AVX2). On a CPU with AVX-512
    numpy picks other loops (X86_V4 and up) for part of the float64 FK, whose last bits differ
    (measured on the paper's arm: 78 of 15,878 reached points by at most 2.6e-14, the
    mask unchanged; the goals drawn from the points change with them; the pinned digests again with
    `NPY_DISABLE_CPU_FEATURES=X86_V4`). The check is of our code, not of the
    CPU: it runs in a child process with numpy's features above X86_V3 disabled, which numpy's
    documented `NPY_DISABLE_CPU_FEATURES` does."""
    simd = np.show_config(mode="dicts")["SIMD Extensions"]
    above_v3 = [f for f in simd.get("found") or [] if f.startswith(("X86_V4", "AVX512"))]
    env = dict(os.environ)
    env.pop("NPY_ENABLE_CPU_FEATURES", None)
    disabled = (env.get("NPY_DISABLE_CPU_FEATURES") or "").replace(",", " ").split()  # kept: not in "found"
    if above_v3 or disabled:
        env["NPY_DISABLE_CPU_FEATURES"] = " ".join(dict.fromkeys(disabled + above_v3))
    proc = subprocess.run([sys.executable, "-c", _PLANAR_DIGESTS], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    assert [[g["area"], g["goals"]] for g in got] == [["6e10806e3d0bfd5e", "9f8769d8d82caded"],
                                                     ["4cc65d0c541ef671", "ab721830c7867d5b"]]
    assert all(g["registry_same"] for g in got)  # the registry's test goals = the planar arm's


def test_the_registry_builds_the_planar_arm_from_the_full_schema():
    spec = arm_spec_from_params(schema_defaults(SCHEMA))  # model fields present, arm.model empty
    assert spec == ArmSpec()
    sim = make_arm_sim(spec, 0)
    assert type(sim) is ArmSim and sim.task_dim == 2


# ------------------------------------------------------------------ the scene (scene.*)
def arm6_in_scene(mode: str = "kinematic", **scene) -> ModelArmSim:
    """config/arm6_mjcf.yaml's arm with the scene parameters ``scene.<key>``."""
    p = params(model="robots/arm6.xml", effector="tool", mode=mode)
    p.update({f"scene.{k}": v for k, v in scene.items()})
    return make_arm_sim(arm_spec_from_params(p, str(CONFIG)), 0)


@pytest.mark.parametrize("mode", ["kinematic", "dynamic"])
def test_a_model_arm_with_a_floor_counts_a_command_that_goes_through_it(mode):
    """arm6 above a table at z = 0: free commands count no contact; a command that lowers the arm
    through the table counts one (by cause floor); lifting it out again counts none. In dynamic mode
    the table holds the arm up (the tool stays at the table); in kinematic mode nothing blocks."""
    sim = arm6_in_scene(mode, floor=0.0)
    assert sim.scene is not None and sim.contacts == 0
    rest = sim.rest.copy()
    for pan, lift in ((0.5, -1.8), (-0.5, -1.2), (0.0, -2.0)):
        sim.command(np.array([pan, lift, *rest[2:]]))
    assert sim.contacts == 0
    _, y = sim.command(np.array([0.0, 0.0, *rest[2:]]))  # the folded forearm down into the table
    assert sim.contacts == 1 and sim.contacts_by_cause == {"self": 0, "floor": 1, "box": 0}
    assert sim.last_contact.cause == "floor" and "the floor at z=0.000" in sim.last_contact.detail
    if mode == "dynamic":
        assert y[2] > -0.01 and sim.observe()[0][1] < -0.3  # blocked: the tool stays at the table
    else:
        assert y[2] < -0.3                                   # set through it
    sim.command(rest)  # the way out
    assert sim.contacts == 1


def test_a_box_is_a_contact_and_without_a_scene_nothing_is_counted_or_built():
    target = np.array([0.0, -1.0, 1.6, -1.1707963267948966, -1.5707963267948966, 0.0])
    probe = arm6_in_scene()
    probe.command(target)
    wrist = probe.data.xpos[mujoco.mj_name2id(probe.model, mujoco.mjtObj.mjOBJ_BODY, "wrist_1_link")].tolist()
    sim = arm6_in_scene(boxes=[*wrist, 0.03, 0.03, 0.03])  # a box where that command takes the wrist
    sim.command(target)
    assert sim.contacts == 1 and sim.contacts_by_cause["box"] == 1 and sim.last_contact.cause == "box"
    assert "box 1" in sim.last_contact.detail
    plain = arm_spec_from_params(params(model="robots/arm6.xml", effector="tool"), str(CONFIG))
    assert plain.scene is None  # self-collision alone (on by default) does not make a simulated scene
    sim = make_arm_sim(plain, 0)
    sim.command(np.array([0.0, -2.0, 3.1, *sim.rest[3:]]))  # folded onto itself: not counted
    assert sim.scene is None and sim.contacts == 0 and sim.arm._scene_model is None


def test_the_planar_arm_has_no_scene():
    p = schema_defaults(SCHEMA)
    p["scene.boxes"] = [0.5, 0.0, 0.2, 0.1, 0.1, 0.1]
    with pytest.raises(ConfigError, match=r"parameter 'scene.boxes'.*planar arm"):
        arm_spec_from_params(p)
    p = schema_defaults(SCHEMA)
    p["scene.self_collision"] = False
    assert arm_spec_from_params(p) == ArmSpec()


def test_the_bridge_publishes_the_contacts_on_its_diagnostics(tmp_path):
    """The bridge node (built in this process, not spun) with arm6 above a table: a command through
    the table shows as contacts = 1, contacts.floor = 1 in its /diagnostics status."""
    import rclpy
    from rclpy.serialization import serialize_message
    from std_msgs.msg import Float64MultiArray

    from sagg_bringup.graph.processes import pick_domain_id
    from sagg_sim_bridge.node import BridgeNode

    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"scene": {"floor": 0.0}}},
        "sagg_sim_bridge": {"ros__parameters": {"arm": {"model": str(CONFIG / "robots/arm6.xml"),
                                                        "effector": "tool"}}}}))
    rclpy.init(args=["--ros-args", "--params-file", str(path)], domain_id=pick_domain_id())
    try:
        node = BridgeNode()
        sent = []
        node.diag_pub.publish = sent.append
        rest = node.sim.rest
        node.on_command(serialize_message(Float64MultiArray(data=[0.0, 0.0, *map(float, rest[2:])])))
        node.publish_diagnostics()
        values = {kv.key: kv.value for kv in sent[-1].status[0].values}
        assert values["contacts"] == "1" and values["contacts.floor"] == "1" and values["contacts.self"] == "0"
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
