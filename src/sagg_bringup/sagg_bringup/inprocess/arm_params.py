"""The evolving-context arm's graph parameters: its node executables, the nodes' full schemas, the
config resolved for ``sagg run`` and what ``sagg run`` fills in (joints, limits and rest posture of
the simulated arm, the learner's budget, the bridge timing)."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from sagg_common.params import ConfigError, resolve_nodes
from sagg_goal_generator.core import SCHEMA as GEN_CORE
from sagg_goal_generator.schema import SCHEMA as GEN_NODE
from sagg_low_level.learner import SCHEMA as LEARNER_CORE
from sagg_low_level.schema import LEARNER_SCHEMA as LEARNER_NODE

from .arm_config import finish_arm_config

# node section -> (package, console script)
NODES = {
    "sagg_sim_bridge": ("sagg_sim_bridge", "mujoco_bridge"),
    "sagg_goal_generator": ("sagg_goal_generator", "goal_generator"),
    "sagg_learner": ("sagg_low_level", "learner"),
}
TIMINGS = ("lockstep", "realtime")


def node_schemas() -> dict[str, tuple]:
    """Full parameter schemas (core + node-only) of the three nodes, from the node modules."""
    # lazy (heavy): mujoco
    from sagg_sim_bridge.schema import BRIDGE_SCHEMA as BRIDGE_NODE
    return {"sagg_sim_bridge": BRIDGE_NODE, "sagg_goal_generator": GEN_NODE, "sagg_learner": LEARNER_NODE}


def core_schemas() -> dict[str, tuple]:
    # lazy (heavy): mujoco
    from sagg_sim_bridge.params import SCHEMA as BRIDGE_CORE
    return {"sagg_goal_generator": GEN_CORE, "sagg_learner": LEARNER_CORE, "sagg_sim_bridge": BRIDGE_CORE}


def resolve_arm(path: str | Path, overrides: dict[str, Any] | None = None) -> tuple[dict[str, dict], Any]:
    """Resolved parameters of the three nodes (full schemas): defaults < ``/**`` < node section <
    overrides, and the simulated arm they describe (the one :func:`arm_spec_from_params` of a run:
    it validates the arm, naming the bad parameter). Same checks as the in-process loader; an
    override no node declares is an error."""
    out = resolve_nodes(path, node_schemas(), overrides)
    return out, finish_arm_config(out, path, overrides)


def load_graph_config(path: str | Path, overrides: dict[str, Any] | None = None) -> dict[str, dict]:
    """The resolved parameters of :func:`resolve_arm` (the arm checked, not kept)."""
    return resolve_arm(path, overrides)[0]


def core_config(full: dict[str, dict]) -> dict[str, dict]:
    """The core parameters only (the ``config`` of an in-process ``result.json``)."""
    return {name: {p.name: full[name][p.name] for p in schema} for name, schema in core_schemas().items()}


def fill_task_model(lp: dict, bp: dict) -> None:
    """The learner's robot model (``task_model.*``: the task point with ``task_source: model``, the
    scene's geometry and the velocity limits) when it has none: the config's simulated arm's model
    (``arm.model``, effector, axes, package paths); ConfigError when ``task_source: model`` has
    none (in place)."""
    if lp.get("task_model.file") or "task_model.file" not in lp:
        return
    if not bp.get("arm.model"):
        if lp.get("task_source") == "model":
            raise ConfigError("parameter 'task_source': 'model' needs the robot's model: task_model.file (or a "
                              "simulated arm from a model file, arm.model, in the config)")
        return
    lp.update({"task_model.file": bp["arm.model"], "task_model.effector": bp["arm.effector"],
               "task_model.task_axes": bp["arm.task_axes"], "task_model.package_paths": list(bp["arm.package_paths"])})


def graph_params(full: dict[str, dict], max_micro_actions: int, timing: str,
                 spec=None) -> dict[str, dict]:
    """The parameters the nodes get: the resolved config plus what ``sagg run`` fills in; ``spec``:
    the arm of ``full`` when the caller has it (:func:`resolve_arm`). ``timing``: the simulated
    bridge's ``lockstep`` or ``realtime``, or ``external`` (the user's driver in place of the
    bridge: the learner keeps the config's ``rest_return`` and ``observation_delay``)."""
    # lazy (heavy): mujoco
    from sagg_sim_bridge.arms import arm_spec_from_params
    params = {name: dict(values) for name, values in full.items()}
    spec = spec if spec is not None else arm_spec_from_params(full["sagg_sim_bridge"])
    lower, upper = spec.limits()
    lp = params["sagg_learner"]
    extra = {"joints": spec.joint_names(), "joint_limits.lower": lower.tolist(),
             "joint_limits.upper": upper.tolist(), "rest_posture": spec.rest_posture().tolist(),
             "max_micro_actions": int(max_micro_actions)}
    for k, v in extra.items():
        if k in lp:
            lp[k] = v
    # the bridge and the learner must agree on the topics
    bp = params["sagg_sim_bridge"]
    fill_task_model(lp, bp)
    if "timing" in bp and timing != "external":
        bp["timing"] = timing
    # lockstep: the simulator's one-command return to rest, as in-process (the graph equals the
    # in-process run); the learner still steps whenever anything but the simulator listens
    if timing == "lockstep" and "rest_return" in lp:
        lp["rest_return"] = "direct"
    # lockstep: the bridge answers each command with the state after it, stamped by its own clock
    # (a simulated step, not the time a real driver takes): a robot's observation_delay, in a config
    # shared with the robot, would wait for a stamp that never comes
    if timing == "lockstep" and "observation_delay" in lp:
        lp["observation_delay"] = 0.0
    # real-time bridge: a joint state sampled before a command arrived must not be taken for its
    # settled result; the learner's own advice is about two publish periods (0 = lockstep value)
    if timing == "realtime" and lp.get("observation_delay") == 0.0 and "publish_rate" in bp:
        lp["observation_delay"] = 2.0 / bp["publish_rate"]
    for k in ("controller", "task_topic"):
        if k in bp and k in lp and bp[k] != lp[k]:
            raise ConfigError(f"parameter '{k}' differs between sagg_sim_bridge ({bp[k]!r}) and "
                              f"sagg_learner ({lp[k]!r}); set it once under '/**'")
    # (the waits for `sagg run`'s recorder are not written here: run_only_params)
    return params
