"""A package ROS tools accept: every import of each Python package (its modules and launch files) is
covered by its package.xml, and every dependency key of the manifests is a ROS package or a rosdep
key that resolves on Ubuntu 24.04 (noble) / Jazzy.

The rosdep keys below were looked up in ros/rosdistro (commit 8468e88):
rosdep/python.yaml has python3-numpy, python3-yaml, python3-scipy, python3-matplotlib,
python3-pytest (and, looked up at commit 000730d, python3-sklearn) with an `ubuntu` entry (apt) and
python3-mujoco-pip, python3-rosbags-pip with an `ubuntu: pip:` entry (PyPI mujoco / rosbags);
jazzy/distribution.yaml releases every ROS package listed in ROS_PACKAGES. (`python3-mujoco` and
`python3-rosbags`, used before, are not keys.) mcap-ros2-support (a `pip` entry for every platform)
is the key whose PyPI package requires `mcap`.
"""
from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PY_PACKAGES = ("sagg_common", "sagg_goal_generator", "sagg_low_level", "sagg_sim_bridge", "sagg_bringup",
               "sagg_lab")
OUR_PACKAGES = set(PY_PACKAGES) | {"sagg_msgs"}
# Python module -> rosdep key (rosdistro rosdep/python.yaml, ubuntu noble)
PYTHON_KEYS = {"numpy": "python3-numpy", "yaml": "python3-yaml", "scipy": "python3-scipy",
               "matplotlib": "python3-matplotlib", "pytest": "python3-pytest",
               "mujoco": "python3-mujoco-pip", "rosbags": "python3-rosbags-pip", "sklearn": "python3-sklearn",
               # (no key installs `mcap` alone; the pip package mcap-ros2-support requires it)
               "mcap": "mcap-ros2-support",
               # (no key installs `threadpoolctl` alone; python3-sklearn's package requires it)
               "threadpoolctl": "python3-sklearn"}
# ROS 2 Jazzy packages (jazzy/distribution.yaml): importable module = package name
ROS_PACKAGES = {"rclpy", "rcl_interfaces", "std_msgs", "std_srvs", "sensor_msgs", "geometry_msgs",
                "trajectory_msgs", "diagnostic_msgs", "builtin_interfaces", "rosgraph_msgs",
                "visualization_msgs", "launch", "launch_ros", "ament_index_python", "action_msgs"}
# imported only behind an optional extra (`sagg bench compare --ray`, `pip install sagg_bringup[ray]`),
# not a dependency of the ROS package; explauto only by lab/peer_explauto.py, a script run under the
# peer's own interpreter (the peer comparison), never imported by sagg
OPTIONAL = {"ray", "explauto"}
DEP_TAGS = ("depend", "exec_depend", "build_depend", "build_export_depend", "buildtool_depend", "test_depend")


def imports(pkg: str) -> set[str]:
    """Top-level modules imported anywhere in the package's modules and launch files."""
    files = [f for f in (ROOT / "src" / pkg).rglob("*.py") if ".egg-info" not in str(f) and f.name != "setup.py"]
    out: set[str] = set()
    for f in files:
        for n in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(n, ast.Import):
                out |= {a.name.split(".")[0] for a in n.names}
            elif isinstance(n, ast.ImportFrom) and n.level == 0 and n.module:
                out.add(n.module.split(".")[0])
    return {m for m in out if m not in sys.stdlib_module_names and m != pkg}


def manifest(pkg: str) -> dict[str, set[str]]:
    root = ET.parse(ROOT / "src" / pkg / "package.xml").getroot()
    return {tag: {e.text.strip() for e in root.findall(tag)} for tag in DEP_TAGS}


def missing_dependencies(pkg: str, deps: dict[str, set[str]]) -> list[str]:
    """The imports of ``pkg`` that ``deps`` (a manifest's dependencies) do not cover."""
    run = deps["depend"] | deps["exec_depend"]
    return [f"{mod} (key {PYTHON_KEYS.get(mod, mod)})" for mod in sorted(imports(pkg) - OPTIONAL)
            if PYTHON_KEYS.get(mod, mod) not in run]


@pytest.mark.parametrize("pkg", PY_PACKAGES)
def test_every_import_is_a_declared_dependency(pkg):
    deps = manifest(pkg)
    missing = missing_dependencies(pkg, deps)
    assert not missing, f"src/{pkg}/package.xml lacks <exec_depend> for: {', '.join(missing)}"
    assert "python3-pytest" in deps["test_depend"]


@pytest.mark.parametrize("pkg", PY_PACKAGES + ("sagg_msgs",))
def test_every_key_resolves_on_jazzy_noble(pkg):
    known = set(PYTHON_KEYS.values()) | ROS_PACKAGES | OUR_PACKAGES | {
        # build tools of the interface package (ament_cmake), all in jazzy/distribution.yaml
        "ament_cmake", "rosidl_default_generators", "rosidl_default_runtime", "ament_lint_auto",
        "ament_lint_common", "ament_cmake_pytest",
        # the Python headers for sagg_low_level's C extension (ros/rosdistro rosdep/python.yaml: ubuntu python3-dev)
        "python3-dev"}
    keys = set().union(*manifest(pkg).values())
    unknown = sorted(k for k in keys if k not in known)
    assert not unknown, f"src/{pkg}/package.xml: keys {unknown} are neither ROS packages nor rosdep keys we checked"


def test_the_check_catches_a_missing_dependency():
    """The scan sees what a manifest lacks: sagg_sim_bridge without its mujoco and scipy-free keys."""
    deps = manifest("sagg_sim_bridge")
    assert missing_dependencies("sagg_sim_bridge", deps) == []
    deps["exec_depend"] = deps["exec_depend"] - {"python3-mujoco-pip", "diagnostic_msgs"}
    assert missing_dependencies("sagg_sim_bridge", deps) == ["diagnostic_msgs (key diagnostic_msgs)",
                                                             "mujoco (key python3-mujoco-pip)"]
    # the old, unresolvable key does not cover the import
    deps["exec_depend"] |= {"python3-mujoco", "diagnostic_msgs"}
    assert missing_dependencies("sagg_sim_bridge", deps) == ["mujoco (key python3-mujoco-pip)"]
