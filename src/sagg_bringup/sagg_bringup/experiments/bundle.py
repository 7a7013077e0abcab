"""What a sweep ships to its workers: a config and every file it references, as content.

A worker of ``sagg bench compare`` / ``sagg reproduce`` (a local process, or a Ray task on another
node) may run in another directory, or on a machine that has none of the user's files: it needs the
installed packages only. The driver therefore reads, once per comparison, the config file and every
file the resolved config names (:data:`FILE_PARAMS`: a model arm's ``arm.model``, the learner's
``task_model.file``, and what those models read: MJCF includes, meshes found as the simulator finds
them, ``package://`` ones included, textures, height fields, skins) into a :class:`Bundle`. The
worker writes the bundle into a temporary directory of its own, mirroring the driver's absolute
paths under it (``<tmp>/home/u/robot/arm.urdf``), so every relative reference between the files
holds as it is; what is absolute is rewritten to its mirrored place: the file parameters (given to
the run as overrides, after the user's), ``package_paths`` (the driver's, then its
``AMENT_PREFIX_PATH`` shares, in the driver's lookup order) and absolute or ``file://`` asset URIs
and asset directories inside the model files. The run's ``result.json`` names the files as the driver knows them
(:func:`driver_paths`), so a result is the same whichever node computed it.

Left as on the driver's machine: what is not a file of the config (the installed packages, the
worker's own ``AMENT_PREFIX_PATH``, which a mesh not found on the driver could be found in).
"""
from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sagg_common.model_load import model_files
from sagg_common.params import ConfigError
from sagg_common.robot_model import ament_prefixes

from ..graph.setups import load_experiment_config

# node -> (model file parameter, its package directories): the files a resolved config names
# (absolute there: inprocess/arm_config.py makes them so)
FILE_PARAMS = {"sagg_sim_bridge": ("arm.model", "arm.package_paths"),
               "sagg_learner": ("task_model.file", "task_model.package_paths")}


@dataclass(frozen=True)
class Bundle:
    """A config and the files it needs, by the driver's absolute paths.

    ``config``: the config file's path; ``files``: path -> content (the config included);
    ``params``: node -> file parameter -> its value in the driver's resolved config (restored in
    results); ``overrides``: file parameter -> the value a worker runs with, in driver paths that
    the worker mirrors (package directories extended by the driver's ament shares);
    ``absolute_uris``: model file -> the absolute or ``file://`` asset URIs and asset directories
    written in it."""

    config: str
    files: dict[str, bytes]
    params: dict[str, dict[str, Any]]
    overrides: dict[str, Any]
    absolute_uris: dict[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def digest(self) -> str:
        """sha256 over the paths and contents (which bundles are the same: shared once on Ray)."""
        h = hashlib.sha256()
        for path in sorted(self.files):
            h.update(path.encode() + b"\0" + hashlib.sha256(self.files[path]).digest())
        return h.hexdigest()


def _read(path: str, what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise ConfigError(f"{what} '{path}': cannot read ({exc.strerror})") from exc


def _model_part(model: str, package_paths: list[str], files: dict[str, bytes],
                absolute_uris: dict[str, tuple[str, ...]]) -> list[str]:
    """Read one model file and the files it reads into ``files``; note its absolute asset URIs;
    returns its package directories as a worker looks them up (the given ones, then the ament
    shares)."""
    prefixes = ament_prefixes()
    includes, assets, absolute_dirs = model_files(model, tuple(package_paths), prefixes)
    for path in (model, *includes):
        files[path] = _read(path, "model file")
    for found in assets.values():
        if found is not None:
            files[os.path.abspath(found)] = _read(found, "model asset")
    absolute = absolute_dirs + tuple(u for u, found in assets.items()
                                     if found is not None and (u.startswith("file://") or os.path.isabs(u)))
    texts = b"".join(files[p] for p in (model, *includes))
    for uri in absolute:
        if f'"{uri}"'.encode() not in texts and f"'{uri}'".encode() not in texts:
            raise ConfigError(f"model {model}: {uri!r} is not written as a quoted attribute in the model's "
                              "files; cannot ship it to the workers (give it relative to the model)")
    for path in (model, *includes):
        absolute_uris[path] = absolute
    return list(package_paths) + [os.path.join(p, "share") for p in prefixes]


def make_bundle(config: str | Path, overrides: dict | None = None) -> Bundle:
    """The bundle of ``config`` with the user's ``overrides`` (the driver's side; ConfigError for
    a config or a referenced file that cannot be read)."""
    path = str(Path(config).resolve())
    files = {path: _read(str(config), "config file")}
    resolved = load_experiment_config(path, dict(overrides or {}))
    params: dict[str, dict[str, Any]] = {}
    worker: dict[str, Any] = {}
    absolute_uris: dict[str, tuple[str, ...]] = {}
    for node, (file_param, dirs_param) in FILE_PARAMS.items():
        values = resolved.get(node, {})
        if not values.get(file_param):
            continue  # no model file (the planar arm, a synergy robot)
        params[node] = {file_param: values[file_param], dirs_param: list(values[dirs_param])}
        worker[file_param] = values[file_param]
        worker[dirs_param] = _model_part(values[file_param], values[dirs_param], files, absolute_uris)
    return Bundle(path, files, params, worker, absolute_uris)


def mirrored(root: Path, path: str) -> str:
    """Where the driver's absolute ``path`` is under a worker's ``root``."""
    return str(root / Path(path).relative_to(Path(path).anchor))


def _rewrite_uris(text: bytes, uris: tuple[str, ...], root: Path) -> bytes:
    """A model file's absolute and ``file://`` asset URIs (and absolute asset directories) pointed
    at their mirrored copies."""
    for uri in uris:
        target = mirrored(root, uri[len("file://"):] if uri.startswith("file://") else uri)
        for q in ('"', "'"):
            text = text.replace(f"{q}{uri}{q}".encode(), f"{q}{target}{q}".encode())
    return text


def materialise(bundle: Bundle, root: Path) -> tuple[str, dict[str, Any]]:
    """Write ``bundle`` under ``root`` (the worker's side); returns the config's path there and
    the file parameters' overrides that point the run at the copies."""
    for path, content in bundle.files.items():
        target = Path(mirrored(root, path))
        target.parent.mkdir(parents=True, exist_ok=True)
        uris = bundle.absolute_uris.get(path)
        target.write_bytes(_rewrite_uris(content, uris, root) if uris else content)
    overrides = {name: ([mirrored(root, v) for v in value] if isinstance(value, list) else mirrored(root, value))
                 for name, value in bundle.overrides.items()}
    return mirrored(root, bundle.config), overrides


def driver_paths(result: dict, bundle: Bundle) -> dict:
    """``result`` with its resolved config's file parameters as the driver has them."""
    config = dict(result["config"])
    for node, values in bundle.params.items():
        config[node] = {**config[node], **values}
    return {**result, "config": config}
