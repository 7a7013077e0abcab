"""A sweep's task carries its config and every file it references (sagg_bringup.experiments.bundle):
a worker whose machine has none of the user's files computes the run the driver would have.

The robots here read their files in the ways a model may: an MJCF include, meshes relative to the
model and absolute (MJCF), ``file://`` and ``package://`` through a relative ``arm.package_paths``
(URDF), the config naming the model by a relative path with ``..``. Dynamic mode, which needs every mesh: a
mesh left behind fails the run instead of being dropped. The originals are moved away before the
worker runs."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from sagg_bringup.experiments.bundle import make_bundle
from sagg_bringup.experiments.sweep import execute_run
from sagg_bringup.graph.setups import run_experiment

TETRAHEDRON = "v 0 0 0\nv 0.02 0 0\nv 0 0.02 0\nv 0 0 0.02\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
TIMINGS = ("learn_seconds", "eval_seconds", "micro_actions_per_second")


INERTIAL = ('<inertial><mass value="0.5"/><inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" '
            'iyz="0"/></inertial>')


def mjcf_model() -> str:
    """A 2-joint planar arm (hinges about z, site 'tip') whose meshes are in an included file."""
    return """<mujoco model="bundle_arm">
  <compiler angle="radian" autolimits="true"/>
  <include file="assets.xml"/>
  <default><joint type="hinge" axis="0 0 1" range="-3 3"/><geom type="capsule" size="0.02"/></default>
  <worldbody>
    <body name="l1">
      <joint name="j1"/>
      <geom fromto="0 0 0 0.5 0 0"/>
      <geom type="mesh" mesh="rel"/>
      <body name="l2" pos="0.5 0 0">
        <joint name="j2"/>
        <geom fromto="0 0 0 0.4 0 0"/>
        <geom type="mesh" mesh="abs"/>
        <site name="tip" pos="0.4 0 0"/>
      </body>
    </body>
  </worldbody>
  <keyframe><key name="home" qpos="0.3 0.6"/></keyframe>
</mujoco>
"""


def urdf_model(src: Path) -> str:
    """The same arm as a URDF: a ``package://`` and a ``file://`` collision mesh, tool frame 'tip'."""
    def joint(name, parent, child, x, kind="revolute"):
        limit = '<axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/>' if kind != "fixed" else ""
        return (f'<joint name="{name}" type="{kind}"><origin xyz="{x} 0 0"/><parent link="{parent}"/>'
                f'<child link="{child}"/>{limit}</joint>')

    def link(name, mesh=""):
        col = f'<collision><geometry><mesh filename="{mesh}"/></geometry></collision>' if mesh else ""
        return f'<link name="{name}">{INERTIAL}{col}</link>'
    return "\n".join(['<robot name="bundle_arm">', link("base"), joint("j1", "base", "l1", 0),
                      link("l1", "package://pkgx/d.obj"), joint("j2", "l1", "l2", 0.5),
                      link("l2", f"file://{src / 'abs/c.obj'}"), joint("tip_joint", "l2", "tip", 0.4, "fixed"),
                      link("tip"), "</robot>", ""])


CONFIG = """/**:
  ros__parameters:
    seed: 0
    strategy: sagg-riac
    task_space: {{lower: [-1.2, -1.2], upper: [1.2, 1.2]}}
    rest_posture: [0.3, 0.6]
sagg_learner:
  ros__parameters: {{subgoals: 3}}
sagg_sim_bridge:
  ros__parameters:
    arm: {{model: ../robot/{model}, package_paths: [../pkgs], effector: tip, task_axes: xy, mode: dynamic}}
"""

FILES = {"mjcf": {"cfg/arm.yaml", "robot/arm2.xml", "robot/assets.xml", "robot/meshes/a.obj", "abs/b.obj"},
         "urdf": {"cfg/arm.yaml", "robot/arm2.urdf", "abs/c.obj", "pkgs/pkgx/d.obj"}}


def make_robot(src: Path, kind: str) -> Path:
    """The robot's files under ``src`` (``kind`` mjcf or urdf); returns the config's path."""
    for d in ("cfg", "robot/meshes", "abs", "pkgs/pkgx"):
        (src / d).mkdir(parents=True)
    for f in ("robot/meshes/a.obj", "abs/b.obj", "abs/c.obj", "pkgs/pkgx/d.obj"):
        (src / f).write_text(TETRAHEDRON)
    if kind == "mjcf":
        (src / "robot/arm2.xml").write_text(mjcf_model())
        (src / "robot/assets.xml").write_text(
            f'<mujoco><asset><mesh name="rel" file="meshes/a.obj"/><mesh name="abs" file="{src / "abs/b.obj"}"/>'
            '</asset></mujoco>\n')
    else:
        (src / "robot/arm2.urdf").write_text(urdf_model(src))
    config = src / "cfg/arm.yaml"
    config.write_text(CONFIG.format(model="arm2.xml" if kind == "mjcf" else "arm2.urdf"))
    return config


def differences(a: dict, b: dict, ignore: tuple[str, ...] = ()) -> list[str]:
    """Where two results differ but for their timings and the fields in ``ignore``: top-level
    fields, and the parameters of the resolved config by node (compared as JSON text: NaN equals
    NaN there)."""
    def text(v) -> str:
        return json.dumps(v, sort_keys=True)
    skip = (*TIMINGS, *ignore, "config")
    out = [k for k in sorted(set(a) | set(b)) if k not in skip and text(a.get(k)) != text(b.get(k))]
    ca, cb = a.get("config", {}), b.get("config", {})
    for node in sorted(set(ca) | set(cb)):
        na, nb = ca.get(node, {}), cb.get(node, {})
        out += [f"config.{node}.{n}: {na.get(n)!r} != {nb.get(n)!r}" for n in sorted(set(na) | set(nb))
                if text(na.get(n)) != text(nb.get(n))]
    return out


@pytest.fixture(scope="module", params=["mjcf", "urdf"])
def robot(request, tmp_path_factory):
    base = tmp_path_factory.mktemp("bundle")
    config = make_robot(base / "src", request.param)
    ref = run_experiment(str(config), "sagg-riac", 0, 60, 30, None, progress=False,
                         overrides={"eval.goals": 5})
    bundle = make_bundle(config, {"eval.goals": 5})
    shutil.move(base / "src", base / "gone")  # the worker's machine has none of these files
    return {"base": base, "config": config, "ref": ref, "bundle": bundle, "kind": request.param}


def test_bundle_holds_every_file_of_the_config(robot):
    src = robot["base"] / "src"
    names = {str(Path(p).relative_to(src)) for p in robot["bundle"].files}
    assert names == FILES[robot["kind"]]


def test_a_worker_without_the_files_computes_the_drivers_run(robot):
    out = execute_run(robot["bundle"], "sagg-riac", 0, 60, 30, {"eval.goals": 5})
    assert out["error"] is None, out["error"]
    assert out["where"].endswith(f"pid {os.getpid()}")
    got, ref = out["result"], robot["ref"]
    assert differences(got, ref) == []
    # the files as the driver names them, not the worker's copies
    assert got["config"]["sagg_sim_bridge"]["arm.model"] == ref["config"]["sagg_sim_bridge"]["arm.model"]
    assert ref["config"]["sagg_sim_bridge"]["arm.model"].startswith(str(robot["base"] / "src/robot/arm2."))


def test_a_failing_run_returns_its_traceback_and_where(robot):
    out = execute_run(robot["bundle"], "sagg-riac", 0, 60, 30, {"eval.goals": 5, "subgoals": -1})
    assert out["result"] is None
    assert out["error"].startswith("Traceback") and "ConfigError" in out["error"] and "subgoals" in out["error"]
    assert f"pid {os.getpid()}" in out["where"]
