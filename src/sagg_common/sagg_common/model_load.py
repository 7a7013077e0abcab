"""A robot model file (MuJoCo MJCF ``.xml`` or URDF ``.urdf``) parsed and edited with
``mujoco.MjSpec`` for the model arm (ROS-free).

What a real ``robot_description`` needs (docs/your-robot.md):

- mesh files named by ``package://PKG/path`` URIs are looked up as ``<dir>/PKG/path`` for each
  directory of ``arm.package_paths``, then as ``<prefix>/share/PKG/path`` for each prefix of
  ``AMENT_PREFIX_PATH`` (how ROS 2 finds a package's share directory); ``file:///abs`` URIs and
  absolute paths are taken as they are; other relative paths are relative to the model file's
  directory (and its ``meshdir``), as MuJoCo reads them;
- a mesh that cannot be found is not needed for kinematics: in kinematic mode its geometry is
  dropped (and the caller says so once, naming the files); dynamic mode needs it (ConfigError
  naming the file). MuJoCo never loads URDF ``<visual>`` geometry (``discardvisual``), so only
  collision meshes are looked for in a URDF;
- URDF fixed joints are kept as bodies (``fusestatic`` off), so a tool frame (``tool0``,
  ``flange``) stays a body that can be the effector.
"""
from __future__ import annotations

import os
import xml.etree.ElementTree as ElementTree

import mujoco

from sagg_common.params import ConfigError

MODEL_SUFFIXES = (".xml", ".urdf")
# Kinematic mode: lower bounds on body masses and inertias, so that a moving body whose only
# geometry was dropped (a URDF link without <inertial>) still compiles; they play no part in
# kinematics.
KINEMATIC_MIN_MASS = 1e-6
KINEMATIC_MIN_INERTIA = 1e-12


def asset_candidates(uri: str, model_dir: str, asset_dir: str, package_paths: tuple[str, ...],
                     ament_prefixes: tuple[str, ...]) -> list[str]:
    """Where the file ``uri`` of a model asset may be, in lookup order (see the module docstring)."""
    if uri.startswith("package://"):
        pkg, _, rel = uri[len("package://"):].partition("/")
        if not pkg or not rel:
            return []
        return ([os.path.join(d, pkg, rel) for d in package_paths]
                + [os.path.join(p, "share", pkg, rel) for p in ament_prefixes])
    if uri.startswith("file://"):
        return [uri[len("file://"):]]
    if os.path.isabs(uri):
        return [uri]
    return [os.path.normpath(os.path.join(model_dir, asset_dir, uri))]


def find_asset(uri: str, model_dir: str, asset_dir: str, package_paths: tuple[str, ...],
               ament_prefixes: tuple[str, ...]) -> str | None:
    """The first existing file of :func:`asset_candidates` (None: not found)."""
    return next((p for p in asset_candidates(uri, model_dir, asset_dir, package_paths, ament_prefixes)
                 if os.path.isfile(p)), None)


def included_files(path: str, model_dir: str | None = None) -> list[str]:
    """The files an MJCF model pulls in with ``<include file=...>``, recursively, as absolute paths
    (relative names are relative to the top model's directory, as MuJoCo reads them); a URDF has
    none. ConfigError for an include that is missing or not XML."""
    if not path.lower().endswith(".xml"):
        return []
    model_dir = os.path.dirname(path) if model_dir is None else model_dir
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise ConfigError(f"parameter arm.model: cannot read {path!r} ({exc})") from exc
    out: list[str] = []
    for el in root.iter("include"):
        name = el.get("file", "")
        inc = os.path.normpath(os.path.join(model_dir, name))
        if not name or not os.path.isfile(inc):
            raise ConfigError(f"parameter arm.model: {path} includes {name!r}, not found (looked for {inc})")
        out += [inc, *included_files(inc, model_dir)]
    return out


def model_files(path: str, package_paths: tuple[str, ...],
                ament_prefixes: tuple[str, ...]) -> tuple[list[str], dict[str, str | None], tuple[str, ...]]:
    """Every file the model ``path`` (absolute) is read from: its MJCF includes, and each asset
    file URI (meshes found as :func:`load_spec` finds them, textures, height fields and skins
    relative to their directory) with the absolute path it was found at, None when not found
    (a mesh kinematic mode drops); and its asset directories (``meshdir``, ``texturedir``) that are
    absolute. For copying a model elsewhere (a sweep's workers)."""
    try:
        spec = mujoco.MjSpec.from_file(path)
    except Exception as exc:  # noqa: BLE001 - MuJoCo raises ValueError (parse errors) or others
        raise ConfigError(f"parameter arm.model: MuJoCo cannot parse {path!r}: "
                          f"{' '.join(str(exc).split())}") from exc
    model_dir = os.path.dirname(path)
    assets: dict[str, str | None] = {}
    for mesh in spec.meshes:
        if mesh.file:
            assets[mesh.file] = find_asset(mesh.file, model_dir, spec.meshdir, package_paths, ament_prefixes)
    others = ([(t.file, spec.texturedir) for t in spec.textures]
              + [(a.file, spec.meshdir) for a in (*spec.hfields, *spec.skins)])
    for uri, asset_dir in others:
        if uri and not uri.startswith("package://"):  # (MuJoCo resolves package:// for meshes only)
            assets[uri] = find_asset(uri, model_dir, asset_dir, (), ())
    dirs = tuple(d for d in (spec.meshdir, spec.texturedir) if d and os.path.isabs(d))
    return included_files(path), assets, dirs


def load_spec(path: str, package_paths: tuple[str, ...], ament_prefixes: tuple[str, ...],
              kinematic: bool) -> tuple[mujoco.MjSpec, tuple[str, ...]]:
    """The parsed model with every mesh file resolved to an absolute path, fixed joints kept as
    bodies; returns it and the mesh URIs that were not found (dropped: kinematic mode only)."""
    try:
        spec = mujoco.MjSpec.from_file(path)
    except Exception as exc:  # noqa: BLE001 - MuJoCo raises ValueError (parse errors) or others
        raise ConfigError(f"parameter arm.model: MuJoCo cannot parse {path!r}: "
                          f"{' '.join(str(exc).split())}") from exc
    spec.compiler.fusestatic = False
    spec.strippath = False  # resolved paths are absolute: keep them whole
    model_dir = os.path.dirname(path)
    missing: dict[str, str] = {}  # mesh name -> its URI
    for mesh in spec.meshes:
        uri = mesh.file
        if not uri:
            continue  # an inline mesh (vertices in the file)
        found = find_asset(uri, model_dir, spec.meshdir, package_paths, ament_prefixes)
        if found is None:
            missing[mesh.name] = uri
        else:
            mesh.file = os.path.abspath(found)
    if missing and not kinematic:
        looked = (f"package directories {list(package_paths)} and AMENT_PREFIX_PATH {list(ament_prefixes)}"
                  if any(u.startswith("package://") for u in missing.values()) else f"{model_dir}")
        raise ConfigError(f"parameter arm.model: mesh file(s) {', '.join(sorted(set(missing.values())))} of "
                          f"{path} not found (looked in {looked}); arm.mode 'dynamic' needs every mesh of the "
                          "model (add the package's directory to arm.package_paths), 'kinematic' drops them")
    if missing:
        for geom in list(spec.geoms):
            if geom.meshname in missing:
                spec.delete(geom)
        for mesh in list(spec.meshes):
            if mesh.name in missing:
                spec.delete(mesh)
    if kinematic:
        spec.compiler.boundmass = KINEMATIC_MIN_MASS
        spec.compiler.boundinertia = KINEMATIC_MIN_INERTIA
    return spec, tuple(sorted(set(missing.values())))


def compile_spec(spec: mujoco.MjSpec, path: str) -> mujoco.MjModel:
    """``spec.compile()``; a MuJoCo error becomes a ConfigError naming the model file."""
    try:
        return spec.compile()
    except Exception as exc:  # noqa: BLE001 - MuJoCo raises ValueError with its compiler message
        raise ConfigError(f"parameter arm.model: MuJoCo cannot compile {path!r}: "
                          f"{' '.join(str(exc).split())}") from exc
