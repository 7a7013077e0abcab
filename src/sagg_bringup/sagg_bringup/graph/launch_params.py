"""What ``ros2 launch sagg_bringup sagg.launch.py`` starts, as a plain function (no launch import):
the config -> node parameters expansion that ``sagg run`` does, so that every installed config
launches with every derived parameter filled in (the learner's ``joints``, ``joint_limits``,
``rest_posture`` from the simulated arm, or the config's own with ``driver:=external``; task space,
DOF, the synergy set-ups' nodes).

``launch/sagg.launch.py`` calls :func:`launch_plan` and :func:`write_plan` and turns the result into
``launch_ros`` ``Node`` actions; the tests call them for every installed config.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

from sagg_common.params import ConfigError

from .params_files import write_params_file
from .setups import setup_of

DRIVERS = ("sim", "external")
DEFAULT_CONFIG = "arm8"


def config_dirs() -> list[Path]:
    """Where configs are looked up by name: the installed ``share/sagg_bringup/config`` (ament
    prefixes, then this Python's prefix), then the repository's ``config/``."""
    dirs = [Path(p) / "share" / "sagg_bringup" / "config"
            for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    dirs.append(Path(sys.prefix) / "share" / "sagg_bringup" / "config")
    dirs.append(Path(__file__).resolve().parents[4] / "config")
    return dirs


def installed_configs() -> dict[str, Path]:
    """Every config name -> file (the first directory of :func:`config_dirs` that has it wins)."""
    out: dict[str, Path] = {}
    for d in config_dirs():
        if d.is_dir():
            for f in sorted(d.glob("*.yaml")):
                out.setdefault(f.stem, f)
    return out


def resolve_config(config: str) -> Path:
    """A config file: ``config`` as a path if it exists, else an installed config's name (``arm8``
    or ``arm8.yaml``)."""
    p = Path(config).expanduser()
    if p.is_file():
        return p
    configs = installed_configs()
    name = p.name[:-5] if p.name.endswith(".yaml") else p.name
    if name in configs and p.parent == Path("."):
        return configs[name]
    raise ConfigError(f"config {config!r}: no such file; allowed: a parameter file or one of "
                      f"{', '.join(sorted(configs)) or '(no installed config)'}")


@dataclass
class LaunchPlan:
    """The nodes to start (``(package, executable, node name)``) and every node's parameters."""

    config: Path
    driver: str
    setup: str  # the set-up registry's name (sagg_bringup.graph.setups)
    nodes: list[tuple[str, str, str]] = field(default_factory=list)
    params: dict[str, dict] = field(default_factory=dict)


def launch_plan(config: str, driver: str = "sim", max_micro_actions: int = 0) -> LaunchPlan:
    """The parameters ``sagg run`` would give the nodes for ``config`` (without its recorder waits:
    :func:`~sagg_bringup.graph.params_files.run_only_params`), and the nodes for ``driver`` (``sim``: with the
    MuJoCo bridge; ``external``: the goal generator and the learner only). ``max_micro_actions``:
    the learner's stop (0 = never)."""
    if driver not in DRIVERS:
        raise ConfigError(f"driver:={driver!r}; allowed: one of {', '.join(DRIVERS)}")
    path = resolve_config(config)
    setup = setup_of(path)
    params = setup.graph_params(setup.graph_config(path), max_micro_actions, driver, path)
    nodes = setup.nodes
    plan = LaunchPlan(path, driver, setup.name)
    for name, (module, script) in nodes.items():
        if driver == "external" and name == "sagg_sim_bridge":
            continue
        plan.nodes.append((module.split(".")[0], script, name))
    plan.params = params
    return plan


def write_plan(plan: LaunchPlan, path: str | Path) -> Path:
    """The plan's parameter file (the ``params.yaml`` form ``sagg run`` writes)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_params_file(path, plan.params)
    return path
