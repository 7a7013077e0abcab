"""``--prior SOURCE``: another run's model as this run's prior (``sagg run``, ``sagg experiment``).

SOURCE is what a finished run leaves:

- a ``sagg run`` directory or one of its bags: its samples from the learner's final checkpoint, or
  rebuilt from the bags as ``sagg relearn`` does (:func:`.reach.frozen_model`); its region tree from
  the goal generator's checkpoint;
- a directory holding ``memory.npz`` (``sagg experiment --save-model``, ``sagg relearn --out``), and
  ``regions.npz`` when it was saved with the model.

The prior is copied into this run's own directory (``OUT/prior/``: ``memory.npz``, ``regions.npz``
with ``--prior-regions``, ``prior.json`` saying where it came from), so the run and its resume do not
depend on SOURCE staying where it was. The nodes get it as parameters: the learner's
``prior.memory`` (and ``prior.radius``: sagg_low_level/prior.py has the precedence rule), the goal
generator's ``prior.regions``.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from sagg_common.params import ConfigError
from sagg_low_level.memory import SampleTable

from .reach import frozen_model

PRIOR_DIR = "prior"


def _generator_state(run_dir: Path) -> Path | None:
    """The goal generator's last state file of a ``sagg run`` directory (its region tree), or None."""
    meta = run_dir / "checkpoint" / "generator.json"
    if not meta.is_file():
        return None
    state = run_dir / "checkpoint" / json.loads(meta.read_text())["state_file"]
    return state if state.is_file() else None


def _copy_model(source: Path, dest: Path, say) -> Path | None:
    """``dest/memory.npz`` from SOURCE; returns the file holding SOURCE's region tree, or None."""
    if (source / "memory.npz").is_file():
        shutil.copyfile(source / "memory.npz", dest / "memory.npz")
        regions = source / "regions.npz"
        return regions if regions.is_file() else None
    if not source.exists():
        raise ConfigError(f"--prior: '{source}' does not exist; allowed: a `sagg run` directory or one of its "
                          "bags, or a directory with memory.npz (`sagg experiment --save-model`, `sagg relearn`)")
    frozen_model(source, dest, say)
    run_dir = source if (source / "params.yaml").is_file() else source.parent
    return _generator_state(run_dir)


def prepare_prior(source: str | Path, out: str | Path, regions: bool = False, say=print) -> dict:
    """Copy SOURCE's model into ``out/prior`` and return the parameter overrides that give it to
    the nodes (``prior.memory``; ``prior.regions`` with ``regions``). ConfigError when SOURCE holds
    no model, or no region tree while ``regions`` asks for one."""
    source = Path(source)
    dest = Path(out) / PRIOR_DIR
    dest.mkdir(parents=True, exist_ok=True)
    tree = _copy_model(source, dest, say)
    memory = dest / "memory.npz"
    try:
        samples = len(SampleTable.load(memory))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"--prior: the model of '{source}' cannot be read: {exc}") from exc
    overrides = {"prior.memory": str(memory.resolve())}
    if regions:
        if tree is None:
            raise ConfigError(f"--prior-regions: '{source}' holds no region tree (a `sagg run` directory with its "
                              "checkpoint, or `sagg experiment --save-model`); allowed: without --prior-regions")
        shutil.copyfile(tree, dest / "regions.npz")
        overrides["prior.regions"] = str((dest / "regions.npz").resolve())
    (dest / "prior.json").write_text(json.dumps({"source": str(source.resolve()), "samples": samples,
                                                 "regions": regions}, indent=1))
    say(f"prior: {samples:,} samples of {source}" + (", and its region tree" if regions else ""))
    return overrides


# the nodes' parameters that name the prior's files, and the files' names in DIR/prior
PRIOR_FILES = (("sagg_learner", "prior.memory", "memory.npz"), ("sagg_goal_generator", "prior.regions", "regions.npz"))


def own_prior_files(configs: list[dict], out: str | Path) -> list[str]:
    """A resumed run's prior from its own ``DIR/prior`` when the files its settings name are gone
    (the run directory was moved or copied): each of ``configs`` (node section -> parameters)
    changed in place; one note per file taken from there."""
    notes = []
    for section, key, name in PRIOR_FILES:
        own = Path(out) / PRIOR_DIR / name
        for config in configs:
            named = config.get(section, {}).get(key)
            if named and not Path(named).is_file() and own.is_file():
                config[section][key] = str(own.resolve())
                notes.append(f"{section}: {key} '{named}' is gone; the run's own {own} is used")
    return notes
