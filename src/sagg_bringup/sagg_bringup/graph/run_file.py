"""``DIR/run.json``: a run directory's own settings, what its params.yaml (a configuration) leaves
out, and what ``sagg run --resume DIR`` continues with (ROS-free).

Every graph run writes it before its nodes start, so that it is there even when the run is killed
before its summary exists: the set-up, the **driver** (``sim``: sagg's simulated bridge;
``external``: a robot's driver that sagg does not start), the timing, the ROS domain (and whether
sagg picked it as a private one), the budget, the evaluation period, the config and the overrides
it was started with, and the options of an external-driver run.

A resume never guesses: a directory whose run.json is missing or unreadable, or names a driver this
sagg cannot continue, is refused. A run that learned on a robot is continued only on the robot:
never with the simulated bridge, which would publish joint states where the robot's driver does
and send the learner's commands to the robot while it learns from a simulation.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from sagg_common.journal import write_json_atomic
from sagg_common.params import ConfigError

RUN_FILE = "run.json"
FORMAT = "sagg.run/2"
# the first format was written by the simulated-bridge runner only (no driver key): its driver is sim
FORMAT_SIM_ONLY = "sagg.run/1"
DRIVERS = ("sim", "external")


def write_run_file(out: Path, *, setup: str, driver: str, timing: str, domain_id: int, domain_private: bool,
                   micro_actions: int, eval_every: int, config: str | Path, overrides: dict[str, Any] | None,
                   **options) -> None:
    """Write ``out/run.json`` (atomically). ``config``: the file the run was started from (stored
    absolute); ``overrides``: ``--set`` and ``--seed`` / ``--strategy`` as given; ``options``: what
    else the runner needs to continue the same run (e.g. an external driver's evaluation settings)."""
    if driver not in DRIVERS:
        raise ValueError(f"driver {driver!r}; allowed: {', '.join(DRIVERS)}")
    write_json_atomic(Path(out) / RUN_FILE, {
        "format": FORMAT, "setup": setup, "driver": driver, "timing": timing, "domain_id": int(domain_id),
        "domain_private": bool(domain_private), "micro_actions": int(micro_actions),
        "eval_every": int(eval_every), "config": str(Path(config).resolve()), "overrides": dict(overrides or {}),
        **options})


def _refuse(path: Path, why: str) -> ConfigError:
    return ConfigError(f"--resume: {why}; the run's driver and settings are unknown, so the resume is refused "
                       f"rather than guessed ('{path}' is written by `sagg run` before its nodes start); "
                       "allowed: the directory of a `sagg run`")


def read_run_file(out: Path) -> dict[str, Any]:
    """The settings in ``out/run.json``, checked (ConfigError naming the file and what is wrong)."""
    path = Path(out) / RUN_FILE
    if not path.is_file():
        raise _refuse(path, f"'{path}' not found")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise _refuse(path, f"'{path}' cannot be read ({exc})") from exc
    if not isinstance(doc, dict):
        raise _refuse(path, f"'{path}' holds a {type(doc).__name__}, not an object")
    fmt = doc.get("format")
    if fmt == FORMAT_SIM_ONLY:
        doc = {**doc, "driver": "sim"}
    elif fmt != FORMAT:
        raise _refuse(path, f"'{path}': format {fmt!r}; allowed: {FORMAT!r} or {FORMAT_SIM_ONLY!r}")
    if doc.get("driver") not in DRIVERS:
        raise _refuse(path, f"'{path}': driver {doc.get('driver')!r}; allowed: {', '.join(DRIVERS)}")
    for key in ("micro_actions", "eval_every"):
        value = doc.get(key)
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise _refuse(path, f"'{path}': {key} {value!r}; allowed: an integer >= 1")
    if not isinstance(doc.get("timing"), str):
        raise _refuse(path, f"'{path}': timing {doc.get('timing')!r}; allowed: a string")
    return doc
