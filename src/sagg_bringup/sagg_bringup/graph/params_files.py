"""Parameter files of a graph run: the ROS 2 parameter-file form ``sagg run`` writes
(``DIR/params.yaml``), what only ``sagg run`` gives the nodes on their command line, the checkpoint
directories of a run, and the bags of a run directory. Set-up independent.

A parameter file is a configuration, not a run: it never holds what ties parameters to one run
directory (:data:`RUN_KEYS`: its checkpoint directory, whether it continues that run, its budget).
Reused with ``ros2 run``, ``ros2 launch config:=`` or another ``sagg run``, it starts a new run;
``sagg run --resume DIR`` is the one way to continue one. Those values go on the nodes' command
lines (:func:`run_values`)."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError

# run-specific node parameters: never written into a parameter file (write_params_file)
RUN_KEYS = ("checkpoint_dir", "resume", "max_micro_actions", "max_experiments")


def _nest(flat: dict[str, Any]) -> dict:
    """``{"a.b": 1}`` -> ``{"a": {"b": 1}}`` (the ROS 2 parameter-file form)."""
    out: dict = {}
    for key, value in flat.items():
        parts = key.split(".")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = value
    return out


def run_values(params: dict[str, dict]) -> dict[str, dict]:
    """The :data:`RUN_KEYS` values of ``params`` per node (nodes without any left out): what a
    run gives its nodes on their command line (``-p``; launch: a parameter dict), since
    :func:`write_params_file` leaves them out."""
    out = {name: {k: values[k] for k in RUN_KEYS if k in values} for name, values in params.items()}
    return {name: v for name, v in out.items() if v}


def run_only_params(params: dict[str, dict]) -> dict[str, dict]:
    """What only ``sagg run`` gives the nodes, on their command line (``-p``), never in
    ``DIR/params.yaml``: the run's own values (:func:`run_values`), and the waits for its recorder
    (every goal and sample must reach it, so nodes that can wait for subscribers wait for one;
    written into params.yaml, these waits made a graph started from it with ``ros2 run`` /
    ``ros2 launch`` without a recorder wait forever)."""
    out = run_values(params)
    for name, key in (("sagg_goal_generator", "min_goal_subscribers"), ("sagg_learner", "min_sample_subscribers")):
        if params.get(name, {}).get(key) == 0:
            out.setdefault(name, {})[key] = 1
    return out


def run_bags(out: Path) -> list[Path]:
    """The bags of a run directory in recording order: ``bag``, ``bag2``, ``bag3``, ..."""
    found = []
    k = 1
    while (out / ("bag" if k == 1 else f"bag{k}") / "metadata.yaml").is_file():
        found.append(out / ("bag" if k == 1 else f"bag{k}"))
        k += 1
    return found


def set_checkpoint_dirs(params: dict[str, dict], out: Path, resume: bool = False) -> list[str]:
    """Learner and generator checkpoint (with their journals) into ``DIR/checkpoint``, the run's
    own, and ``resume`` only for ``sagg run --resume DIR``: a run never continues or writes into
    another run's directory. A new run ignores a ``checkpoint_dir`` its config names (e.g. the
    params.yaml of an older ``sagg run``, which named its run's); returns one note per value
    ignored. When resuming, ``DIR/checkpoint`` if it holds the node's checkpoint (the run
    directory may have been moved or copied), else the directory the config names if that one
    does (a run of an older ``sagg run`` whose config named one)."""
    own = out / "checkpoint"
    notes = []
    for name, meta in (("sagg_learner", "learner.json"), ("sagg_goal_generator", "generator.json")):
        p = params[name]
        if "checkpoint_dir" not in p:
            continue
        named = p["checkpoint_dir"]
        if resume and named and not (own / meta).is_file() and (Path(named) / meta).is_file():
            p["resume"] = True
            continue
        if named and not resume and Path(named).resolve() != own.resolve():
            notes.append(f"{name}: checkpoint_dir '{named}' of the config not used: a run keeps its "
                         f"checkpoints in its own directory ({own})")
        p["checkpoint_dir"] = str(own.resolve())
        p["resume"] = bool(resume)
    return notes


def config_params(params: dict[str, dict]) -> dict[str, dict]:
    """``params`` without the :data:`RUN_KEYS` (what a parameter file holds)."""
    return {name: {k: v for k, v in values.items() if k not in RUN_KEYS} for name, values in params.items()}


def write_params_file(path: Path, params: dict[str, dict]) -> None:
    """``params`` (node name -> flat parameters) as a ROS 2 parameter file, without the run-only
    :data:`RUN_KEYS` (:func:`run_values` has them)."""
    doc = {name: {"ros__parameters": _nest(values)} for name, values in config_params(params).items()}
    header = ("# Generated by sagg: the resolved parameters of the nodes (ROS 2 parameter-file form). A\n"
              "# configuration, not a run: no checkpoint_dir, resume or budget (sagg run gives those on the\n"
              "# nodes' command lines), so reusing it starts a new run (sagg run --resume DIR continues one).\n")
    path.write_text(header + yaml.dump(doc, Dumper=_RosDumper, sort_keys=False, default_flow_style=None, width=120))


class _RosDumper(yaml.SafeDumper):
    """A YAML dumper for ROS 2 parameter files: a string that a YAML 1.1 reader takes for a boolean
    (``y``, ``n``, ``yes``, ``on``, ...; rcl's parser does, PyYAML does not for ``y``/``n``) is
    quoted, so a joint named ``y`` stays a string."""


_BOOL_LIKE = {w for b in ("y", "n", "yes", "no", "on", "off", "true", "false") for w in (b, b.upper(), b.title())}
_RosDumper.add_representer(str, lambda d, s: d.represent_scalar("tag:yaml.org,2002:str", s,
                                                                 style="'" if s in _BOOL_LIKE else None))


RUN_FILE = "run.json"  # a run directory's own settings (what params.yaml, a configuration, leaves out)


def write_run_file(out: Path, **values) -> None:
    """``DIR/run.json``: the settings of this run that its params.yaml does not hold (budget,
    evaluation period, timing), written before the nodes start, so that ``sagg run --resume`` of a
    run killed before its summary.json existed continues with them."""
    write_json_atomic(out / RUN_FILE, {"format": "sagg.run/1", **values})


def read_run_file(out: Path) -> dict:
    """``DIR/run.json`` ({} when the run has none: written by an older sagg run)."""
    path = out / RUN_FILE
    if not path.is_file():
        return {}
    try:
        doc = json.loads(path.read_text())
    except ValueError as exc:
        raise ConfigError(f"--resume: '{path}' is not valid JSON ({exc})") from exc
    return doc if isinstance(doc, dict) else {}
