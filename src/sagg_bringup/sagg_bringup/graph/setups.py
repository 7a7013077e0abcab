"""The set-up registry (docs/architecture.md): one entry per learning problem, consulted by every runner.

A set-up names its simulator, its learner, the node executables of the graph and their parameter
schemas, how a config is resolved, its in-process runner (``sagg experiment``), its graph runner
(``sagg run``), the topics its graph records, its evaluation and the rows and figures of its
report. Two implementations of one interface (:class:`Setup`):

- :class:`EvolvingArm` (``arm``): the evolving-context arm (Sec. 3): micro-actions Δα from the
  current posture, :class:`~sagg_low_level.learner.EvolvingContextLearner`, nodes ``learner`` +
  ``mujoco_bridge``; resumable, relearnable from bags, runs against an external driver, takes a prior;
- :class:`FixedContext`: synergies θ → outcome y from a rest state (Sec. 4-5),
  :class:`~sagg_low_level.fixed_context.FixedContextLearner`, node ``fixed_learner``; entries
  ``quadruped`` and ``fishing`` (bridge ``synergy_bridge``, trajectories) and ``arm-fixed`` (the arm
  with the learner parameter ``context: fixed``: bridge ``mujoco_bridge``, the position contract).

Which entry a config is (:func:`setup_of`): the parameter ``setup`` (under ``/**`` or
``sagg_sim_bridge``) names a synergy set-up; otherwise the learner parameter ``context`` chooses
the arm (``evolving``) or the fixed-context arm (``fixed``). This module is the only place that
branches on the set-up: the CLI, the in-process and graph runners, the recorder, ``sagg relearn``,
the launch plan and the report ask it. A new set-up is one module with its adapter (see
:class:`~sagg_bringup.inprocess.fixed_experiment.SynergySetup`) plus one line in :data:`SETUPS`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from sagg_common.params import ConfigError, node_params, read_config
from sagg_goal_generator.schema import SCHEMA as GEN_NODE_SCHEMA
from sagg_low_level.learner import CONTEXT
from sagg_low_level.schema import MODEL_SERVER_SCHEMA
from sagg_sim_bridge.schema import BRIDGE_SCHEMA as ARM_BRIDGE_SCHEMA
from sagg_sim_bridge.synergy_params import SETUPS as SYNERGY_SIMS

from ..bags import bags, topics
from ..inprocess import arm_params, experiment, fixed_experiment
from ..report import report
from . import external, graph, fixed_graph
from .run_file import read_run_file
from ..bags.recorder import TopicSpec

GOAL_GENERATOR = ("sagg_goal_generator", "goal_generator")  # (package, console script)


class Setup:
    """The interface of a set-up (one kind of learning problem); see the module docstring.

    Attributes: ``name``; ``context`` ('evolving' or 'fixed'); ``simulator`` and ``learner`` (what
    simulates it and which ROS-free learner core learns it, for people and reports); ``nodes``
    (node section -> (package, console script) of the graph); ``figures`` (the report's figures);
    ``resumable`` (``sagg run --resume``), ``relearnable`` (``sagg relearn``), ``external_driver``
    (``sagg run --driver external``), ``takes_prior`` (``--prior``: another run's samples)."""

    name: str
    context: str
    simulator: str
    learner: str
    nodes: dict[str, tuple[str, str]]
    figures: tuple[str, ...]
    resumable: bool = False
    relearnable: bool = False
    external_driver: bool = False
    takes_prior: bool = False

    def node_schemas(self) -> dict[str, tuple]:
        """The full parameter schema of each node of the graph (node section -> schema)."""
        raise NotImplementedError

    def load_config(self, path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
        """The config's core parameters per node (in-process), every value checked."""
        raise NotImplementedError

    def in_process_run(self, config: dict[str, dict]):
        """A learning run of :meth:`load_config`'s ``config``, stepped in-process (``step_until``,
        ``evaluate``, ``learner``, ``generator``)."""
        raise NotImplementedError

    def run_experiment(self, path, strategy, seed, micro_actions: int, eval_every: int, out_dir,
                       progress: bool = True, overrides: dict[str, Any] | None = None,
                       save_model: bool = False) -> dict:
        """``sagg experiment``: one (strategy, seed) in-process; writes ``out_dir/result.json``
        (``save_model``: and the learned model, where the set-up can be a prior)."""
        raise NotImplementedError

    def graph_config(self, path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
        """The nodes' parameters (full node schemas) of a config."""
        raise NotImplementedError

    def graph_params(self, full: dict[str, dict], budget: int, driver: str = "sim",
                     path: str | Path | None = None) -> dict[str, dict]:
        """What the nodes get (``DIR/params.yaml``, the launch plan): ``full`` plus what ``sagg run``
        fills in; ``budget`` micro-actions (0 = never stop)."""
        raise NotImplementedError

    def run_graph(self, path, micro_actions: int, out_dir, **options) -> dict:
        """``sagg run``: the graph of this set-up; returns the summary."""
        raise NotImplementedError

    def topics(self, learner_params: dict, timing: str = "lockstep") -> list[TopicSpec]:
        """The topics its graph records (names from the learner's parameters)."""
        raise NotImplementedError

    def report_rows(self, config: dict[str, dict]) -> list[tuple[str, str]]:
        """The report's rows describing the simulated robot of a run's ``config``."""
        raise NotImplementedError


@dataclass(frozen=True)
class EvolvingArm(Setup):
    """The evolving-context arm (Sec. 3)."""

    name: str = "arm"
    context: str = "evolving"
    simulator: str = "MuJoCo N-DOF planar arm (sagg_sim_bridge.arm.ArmSim), position contract"
    learner: str = "EvolvingContextLearner (Alg. 3, micro-actions)"
    nodes: dict = None  # type: ignore[assignment]  (set in __post_init__: arm_params.NODES)
    figures: tuple = ("learning_curve", "goals_over_time", "regions_over_time", "competence_map")
    resumable: bool = True
    relearnable: bool = True
    external_driver: bool = True
    takes_prior: bool = True

    def __post_init__(self):
        object.__setattr__(self, "nodes", dict(arm_params.NODES))

    def node_schemas(self):
        return arm_params.node_schemas()

    def load_config(self, path, overrides=None):
        return experiment.load_arm_config(path, overrides)

    def in_process_run(self, config):
        return experiment.InProcessRun(config)

    def run_experiment(self, path, strategy, seed, micro_actions, eval_every, out_dir, progress=True,
                       overrides=None, save_model=False):
        return experiment.run_arm_experiment(path, strategy, seed, micro_actions, eval_every, out_dir,
                                             progress=progress, overrides=overrides, save_model=save_model)

    def graph_config(self, path, overrides=None):
        return arm_params.load_graph_config(path, overrides)

    def graph_params(self, full, budget, driver="sim", path=None):
        if driver == "external":
            return external.external_params(full, budget, external.explicit_joints(path, None))
        return arm_params.graph_params(full, budget, "lockstep")

    def run_graph(self, path, micro_actions, out_dir, driver: str = "sim", **options):
        if driver == "external":
            return external.run_external_graph(path, micro_actions, out_dir, **options)
        return graph.run_graph(path, micro_actions, out_dir, **options)

    def topics(self, learner_params, timing="lockstep"):
        return topics.graph_topics(learner_params, timing)

    def report_rows(self, config):
        return report.arm_rows(config.get("sagg_sim_bridge") or {})


@dataclass(frozen=True)
class FixedContext(Setup):
    """A fixed-context set-up (Sec. 4-5): ``adapter`` is its in-process simulator adapter (how θ is
    executed and the outcome read, its test goals and reachable area; a class of
    :mod:`.fixed_experiment`), ``bridge`` its bridge node (package, console script) and
    ``bridge_schema`` that node's schema, ``learner_schema`` the learner node's (with the set-up's
    defaults), ``topics_of`` its recorded topics, ``rows_of`` its report rows."""

    name: str
    simulator: str
    adapter: type
    bridge: tuple[str, str]
    bridge_schema: tuple
    topics_of: Callable[[dict], list[TopicSpec]]
    rows_of: Callable[[dict], list[tuple[str, str]]]
    learner_schema: tuple = fixed_experiment.LEARNER_SCHEMA
    context: str = "fixed"
    learner: str = "FixedContextLearner (Alg. 4, one synergy θ per experiment)"
    figures: tuple = ("learning_curve",)
    nodes: dict = None  # type: ignore[assignment]  (set in __post_init__)

    def __post_init__(self):
        object.__setattr__(self, "nodes", {"sagg_goal_generator": GOAL_GENERATOR,
                                           "sagg_learner": ("sagg_low_level", "fixed_learner"),
                                           "sagg_sim_bridge": self.bridge})

    def node_schemas(self):
        return {"sagg_goal_generator": GEN_NODE_SCHEMA, "sagg_learner": self.learner_schema,
                "sagg_sim_bridge": self.bridge_schema}

    def load_config(self, path, overrides=None):
        return fixed_experiment.load_fixed_config(path, overrides, self.adapter)

    def in_process_run(self, config):
        return fixed_experiment.FixedRun(config, self.adapter)

    def run_experiment(self, path, strategy, seed, micro_actions, eval_every, out_dir, progress=True,
                       overrides=None, save_model=False):
        if save_model:
            raise ConfigError(f"--save-model: set-up {self.name!r} (fixed context) has no prior; allowed: the "
                              "evolving-context arms")
        return fixed_experiment.run_fixed_experiment(self.adapter, path, strategy, seed, micro_actions,
                                                         eval_every, out_dir, progress=progress,
                                                         overrides=overrides)

    def graph_config(self, path, overrides=None):
        return fixed_graph.resolve_fixed_graph(self, path, overrides)

    def graph_params(self, full, budget, driver="sim", path=None):
        return fixed_graph.fixed_graph_params(full, budget)

    def run_graph(self, path, micro_actions, out_dir, driver: str = "sim", **options):
        return fixed_graph.run_fixed_graph(self, path, micro_actions, out_dir, **options)

    def topics(self, learner_params, timing="lockstep"):
        return self.topics_of(learner_params)

    def report_rows(self, config):
        return self.rows_of(config)


def _arm_position_topics(lp: dict) -> list[TopicSpec]:
    return topics.graph_topics(lp, "lockstep")


def _synergy_rows(config: dict) -> list[tuple[str, str]]:
    return report.synergy_rows(config.get("sagg_sim_bridge") or {})


def _fixed_arm_rows(config: dict) -> list[tuple[str, str]]:
    return report.arm_rows(config.get("sagg_sim_bridge") or {}) + report.FIXED_ARM_ROWS


# name -> set-up (the order is the `sagg params` order of the node tables)
SETUPS: dict[str, Setup] = {s.name: s for s in (
    EvolvingArm(),
    FixedContext("quadruped", "MuJoCo quadruped, 12 joints, sinusoid synergies (sagg_sim_bridge.quadruped)",
                 fixed_experiment.SynergySetup, ("sagg_sim_bridge", "synergy_bridge"),
                 fixed_experiment.SYN_BRIDGE_SCHEMA, topics.trajectory_topics, _synergy_rows),
    FixedContext("fishing", "MuJoCo 4-DOF arm with a rod and a float, velocity synergies (sagg_sim_bridge.fishing)",
                 fixed_experiment.SynergySetup, ("sagg_sim_bridge", "synergy_bridge"),
                 fixed_experiment.SYN_BRIDGE_SCHEMA, topics.trajectory_topics, _synergy_rows),
    FixedContext(fixed_experiment.ARM_FIXED, "MuJoCo N-DOF planar arm, θ = joint targets from rest "
                 "(position contract)", fixed_experiment.ArmPostureSetup, ("sagg_sim_bridge", "mujoco_bridge"),
                 ARM_BRIDGE_SCHEMA, _arm_position_topics, _fixed_arm_rows,
                 fixed_experiment.fixed_arm_learner_schema()),
)}


def _setup_name(sections: dict[str, dict], overrides: dict[str, Any] | None = None) -> str:
    """The registry name of a config's sections (see the module docstring)."""
    name = sections.get("/**", {}).get("setup", sections.get("sagg_sim_bridge", {}).get("setup"))
    if name is not None:
        if name not in SYNERGY_SIMS:
            raise ConfigError(f"parameter 'setup': got {name!r}; allowed: one of {', '.join(map(repr, SYNERGY_SIMS))}")
        return name
    context = sections.get("sagg_learner", {}).get("context", sections.get("/**", {}).get("context", "evolving"))
    context = CONTEXT.validate((overrides or {}).get("context", context))
    return fixed_experiment.ARM_FIXED if context == "fixed" else "arm"


def setup_of(path: str | Path, overrides: dict[str, Any] | None = None) -> Setup:
    """The set-up of a config file (or a run's params.yaml), ``overrides`` included."""
    return SETUPS[_setup_name(read_config(path), overrides)]


def setup_of_result(result: dict) -> Setup:
    """The set-up of a finished run (``result.json`` / ``summary.json``: its resolved ``config``)."""
    return SETUPS[_setup_name(result.get("config") or {})]


def node_tables() -> dict[str, tuple]:
    """Every node's full parameter schema once, for ``sagg params`` and the README: the arm's nodes
    by section name, another set-up's node of the same section as ``section (console script)``."""
    out: dict[str, tuple] = {}
    seen: set[str] = set()
    for setup in SETUPS.values():
        schemas = setup.node_schemas()
        for section in ("sagg_goal_generator", "sagg_learner", "sagg_sim_bridge"):
            script = setup.nodes[section][1]
            if script in seen:
                continue
            seen.add(script)
            out[section if section not in out else f"{section} ({script})"] = schemas[section]
    out["sagg_model_server (model_server)"] = MODEL_SERVER_SCHEMA  # (a finished run's model: sagg serve)
    return out


# ------------------------------------------------------------------------------ what runners call
def load_experiment_config(path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
    """The in-process config of any set-up (:meth:`Setup.load_config`)."""
    return setup_of(path, overrides).load_config(path, overrides)


def in_process_run(path: str | Path, overrides: dict[str, Any] | None = None):
    """The in-process run of any set-up's config (:meth:`Setup.in_process_run`)."""
    setup = setup_of(path, overrides)
    return setup.in_process_run(setup.load_config(path, overrides))


def run_experiment(config_path: str | Path, strategy: str | None, seed: int | None, micro_actions: int,
                   eval_every: int, out_dir: str | Path | None, progress: bool = True,
                   overrides: dict[str, Any] | None = None, save_model: bool = False) -> dict:
    """``sagg experiment`` for any set-up (result.json: ``micro_actions`` counts experiments in the
    fixed context)."""
    setup = setup_of(config_path, overrides)
    return setup.run_experiment(config_path, strategy, seed, micro_actions, eval_every, out_dir,
                                progress=progress, overrides=overrides, save_model=save_model)


def run_graph(config_path: str | Path, micro_actions: int, out_dir: str | Path, *, driver: str = "sim",
              timing: str = "lockstep", **options) -> dict:
    """``sagg run`` for any set-up; ``driver`` 'external' where the set-up has it (continuing a
    stopped run: :func:`resume_graph`)."""
    setup = setup_of(config_path, options.get("overrides"))
    if driver == "external":
        if not setup.external_driver:
            raise ConfigError(f"--driver external: set-up {setup.name!r} is not supported; allowed: "
                              + ", ".join(s.name for s in SETUPS.values() if s.external_driver))
        return setup.run_graph(config_path, micro_actions, out_dir, driver=driver, **options)
    return setup.run_graph(config_path, micro_actions, out_dir, timing=timing, **options)


def resume_graph(out_dir: str | Path, micro_actions: int | None = None, domain_id: int | None = None,
                 **options) -> dict:
    """``sagg run --resume DIR`` for any set-up: the stopped run in ``out_dir`` continued with its
    own parameters (DIR/params.yaml) and settings (DIR/run.json, :func:`.run_file.read_run_file`:
    refused when unreadable), on its own driver (an external driver's run on its robot). Budget:
    ``micro_actions``, else the run's own; domain: ``domain_id``, else the run's own when it was
    given one, else a new private one."""
    out = Path(out_dir)
    params_file = out / "params.yaml"
    if not params_file.is_file():
        raise ConfigError(f"--resume: '{params_file}' not found; allowed: the directory of a `sagg run`")
    setup = setup_of(params_file)
    if not setup.resumable:
        raise ConfigError(f"--resume: '{out}' is a run of set-up {setup.name!r}, which keeps no "
                          "checkpoints (start a new run); allowed: "
                          + ", ".join(s.name for s in SETUPS.values() if s.resumable))
    settings = read_run_file(out)
    if domain_id is None and not settings.get("domain_private", True):
        domain_id = settings["domain_id"]
    budget = micro_actions or settings["micro_actions"]
    if settings["driver"] == "external":  # (on the robot: its driver, its evaluation settings)
        robot = {k: settings[k] for k in EXTERNAL_RESUMED if k in settings}
        return setup.run_graph(params_file, budget, out, driver="external", eval_every=settings["eval_every"],
                               domain_id=domain_id, resume=settings, **{**robot, **options})
    if "driver_timeout" in options:
        raise ConfigError(f"--driver-timeout: '{out}' learned with the simulated bridge; allowed: only when "
                          "resuming a --driver external run")
    return setup.run_graph(params_file, budget, out, timing=settings["timing"],
                           eval_every=settings["eval_every"], domain_id=domain_id, resume=settings, **options)


# the options of an external-driver run that its resume keeps (run.json)
EXTERNAL_RESUMED = ("robot_eval_goals", "robot_eval_every", "robot_eval_goal_seconds", "driver_timeout")


def relearn(bag_dirs: list[str | Path], out_dir: str | Path, params_file: str | Path | None = None, **options) -> dict:
    """``sagg relearn`` (set-ups that can rebuild their learner from bags)."""
    path = bags.params_path(Path(bag_dirs[0]), params_file) if bag_dirs else None
    if path is not None and path.is_file():
        setup = setup_of(path)
        if not setup.relearnable:
            raise ConfigError(f"relearn: the run is of set-up {setup.name!r}; allowed: "
                              + ", ".join(s.name for s in SETUPS.values() if s.relearnable)
                              + " (fixed-context runs are evaluated from their samples by `sagg run` itself)")
    return bags.relearn(bag_dirs, out_dir, params_file, **options)


def recorded_topics(path: str | Path) -> list[TopicSpec]:
    """The topics ``sagg run`` records for the graph a config or params.yaml describes."""
    setup = setup_of(path)
    return setup.topics(node_params(read_config(path), "sagg_learner", setup.node_schemas()["sagg_learner"]))


def write_report(result: dict | str | Path, out_dir: str | Path, area=None) -> Path:
    """report.md + figures of any set-up's run (its rows from the registry)."""
    if not isinstance(result, dict):
        result = json.loads(Path(result).read_text())
    return report.write_report(result, out_dir, area=area,
                               setup_rows=setup_of_result(result).report_rows(result.get("config") or {}))
