"""What an evolving-context arm config needs beyond its schema values (ROS-free; every runner's
config loader calls :func:`finish_arm_config`): the arm it describes, its model file found, and the
task-unit parameters fitted to the arm's size.

- **Files**: ``arm.model`` and ``arm.package_paths`` may be relative to the config file's directory
  (a config next to its robot); they are made absolute here, so the resolved config (result.json,
  a run's params.yaml, a worker of ``sagg bench compare``) names the same files from anywhere.
- **Task units**: the learner's parameters that are lengths in task units have defaults that are
  the paper's values for its 50-unit arm (Sec. 3.4: v 2, ε_C 0.1; the evaluation's tolerance 0.01).
  For an arm from a model file (a 1 m arm in metres, a 50 mm one in mm) those defaults are scaled by
  ``reach / 50``, ``reach`` being the arm's largest effector distance from its base
  (:func:`~sagg_sim_bridge.arms.arm_reach`), unless the config (or ``--set``) gives them: the same
  motion per micro-action relative to the arm, whatever its units. The generated planar arm keeps
  them as they are (its ``total_length`` is 50 by default; a planar arm of another length gives
  them, as config/arm7_ratio15.yaml does). Every scaled value is said once per process and is in
  the resolved config (hence in params.yaml and result.json).
"""
from __future__ import annotations

import sys
from pathlib import Path

from sagg_common.params import ConfigError, is_given, read_config

# the learner's task-unit lengths and the reach their defaults are meant for (the paper's 50-unit arm)
TASK_UNIT_PARAMS = ("v", "eps_c", "eval.tolerance")
PAPER_REACH = 50.0
_SAID: set[str] = set()


def absolute_model_paths(bp: dict, base_dir: Path) -> None:
    """``arm.model`` and ``arm.package_paths`` of the bridge's parameters ``bp``, relative to
    ``base_dir``, made absolute (in place; an empty model stays empty: the planar arm)."""
    if bp.get("arm.model"):
        bp["arm.model"] = str((base_dir / bp["arm.model"]).resolve())
        bp["arm.package_paths"] = [str((base_dir / p).resolve()) for p in bp.get("arm.package_paths", [])]


def scaled_task_units(lp: dict, reach: float, given) -> dict[str, float]:
    """The learner's task-unit defaults scaled by ``reach / PAPER_REACH`` (those ``given(name)`` is
    false for); returns them (the caller sets them)."""
    k = float(reach) / PAPER_REACH
    return {name: lp[name] * k for name in TASK_UNIT_PARAMS if name in lp and not given(name)}


def finish_arm_config(out: dict[str, dict], path: str | Path, overrides: dict | None = None):
    """The arm of a resolved config ``out`` (the three node sections, in place): model files made
    absolute, task-unit defaults scaled for a model arm; returns its spec (ConfigError names a bad
    ``arm.*`` parameter)."""
    # lazy (heavy): mujoco
    from sagg_sim_bridge.arms import arm_reach, arm_spec_from_params, arm_task_dim
    bp, lp = out["sagg_sim_bridge"], out["sagg_learner"]
    absolute_model_paths(bp, Path(path).resolve().parent)
    if lp.get("task_model.file"):  # (the learner's own model file, task_source 'model')
        base = Path(path).resolve().parent
        lp["task_model.file"] = str((base / lp["task_model.file"]).resolve())
        lp["task_model.package_paths"] = [str((base / d).resolve()) for d in lp["task_model.package_paths"]]
    spec = arm_spec_from_params(bp)
    dims, m = len(lp["task_space.lower"]), arm_task_dim(spec)
    if dims != m:
        axes = f"arm.task_axes '{bp['arm.task_axes']}'" if bp.get("arm.model") else "the planar arm's (x, y)"
        raise ConfigError(f"parameter 'task_space.lower': {dims} values; allowed: {m}, one per task dimension of "
                          f"{axes}")
    if bp.get("arm.model"):
        sections = read_config(path)
        reach = arm_reach(spec)
        scaled = scaled_task_units(lp, reach, lambda n: is_given(sections, "sagg_learner", n, overrides))
        lp.update(scaled)
        key = f"{bp['arm.model']} {sorted(scaled.items())}"
        if scaled and key not in _SAID:
            _SAID.add(key)
            print(f"{Path(bp['arm.model']).name}: reach {reach:.4g}; task-unit defaults scaled by reach/"
                  f"{PAPER_REACH:g} = {reach / PAPER_REACH:.4g}: "
                  + ", ".join(f"{n} {v:.4g}" for n, v in scaled.items()), file=sys.stderr)
    return spec
