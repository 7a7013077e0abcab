"""A robot and its scene as one MuJoCo model for collision checking (ROS-free).

Built from the robot's model file (:func:`.model_load.load_spec`, kinematic: meshes that cannot
be found are dropped), then edited with ``mujoco.MjSpec``:

- a link (body) without collision geometry gets capsules of radius ``scene.link_radius`` from its
  origin to each child's origin (zero-length segments skipped); a geom the model marks as never
  colliding (``contype = conaffinity = 0``, e.g. an MJCF's visual geoms) stays out; geoms of the
  world body in the file are not checked (a scene is declared in ``scene.*``);
- the floor (a plane at ``scene.floor``) and the boxes are geoms of the world body, with geom
  margin ``scene.clearance``: MuJoCo reports a contact as soon as a link is closer than that;
- who meets whom, by ``contype``/``conaffinity`` bits: the links a commanded joint moves
  (``MOVING``) meet the obstacles and, with self-collision, each other and the robot's static
  bodies (``STATIC``: the base); static bodies never meet the obstacles (the arm is mounted on the
  table), nor meet the floor the links that only turn about vertical axes (a UR's shoulder turning
  on its base: their height never changes, so a crude shape that dips below the mounting plane
  would otherwise refuse every posture). Links among themselves have margin 0: a contact is an
  overlap;
- self-collision leaves out parent and child (MuJoCo's parent filter, on) and every pair of
  links already touching at the rest posture: the "always / default in collision" pairs that
  MoveIt's setup assistant disables, without which a crude model (capsules meeting at a joint)
  would refuse every posture. They are ``<exclude>`` pairs of the model and named in the notices.

The bound on motion (:func:`motion_radii`) is what a segment's sampling rests on.
"""
from __future__ import annotations

import mujoco
import numpy as np

from .model_kin import BALL, HINGE, SLIDE, quat_matrix
from .model_load import compile_spec, load_spec
from .params import ConfigError
from .robot_model import RobotModel, ament_prefixes
from .scene_params import SceneParams

# contype bits: links moved by a commanded joint, other robot bodies, the boxes, the floor
MOVING, STATIC, OBSTACLE, FLOOR_BIT = 1, 2, 4, 8
VERTICAL = 1.0 - 1e-9                # |cos| between a hinge's axis and z above this: a vertical axis
FLOOR_NAME, BOX_NAME, CAPSULE_NAME = "sagg_scene_floor", "sagg_scene_box_{}", "sagg_scene_capsule_{}_{}"
MIN_SEGMENT = 1e-6                   # m: shorter body-to-child offsets get no capsule
# cause codes per geom (SceneModel.geom_cause)
LINK, STATIC_LINK, FLOOR, BOX, NONE = 0, 1, 2, 3, 4


def _moved_bodies(m: mujoco.MjModel, jids) -> np.ndarray:
    """(nbody,) bool: the bodies that one of the joints ``jids`` moves (its body and descendants)."""
    joint_bodies = {int(m.jnt_bodyid[j]) for j in jids}
    out = np.zeros(m.nbody, dtype=bool)
    for b in range(1, m.nbody):  # parents come before children
        out[b] = b in joint_bodies or bool(out[int(m.body_parentid[b])])
    return out


def _level_bodies(m: mujoco.MjModel, jids, qpos_rest: np.ndarray) -> np.ndarray:
    """(nbody,) bool: the bodies moved by the joints ``jids`` only through hinges whose axis is
    vertical (world z) at rest: turns about vertical axes keep every height, and keep the axes
    below them vertical, so these bodies' heights are the same in every posture."""
    d = mujoco.MjData(m)
    d.qpos[:] = qpos_rest
    mujoco.mj_kinematics(m, d)
    commanded = {int(j) for j in jids}
    out = np.zeros(m.nbody, dtype=bool)
    moved = np.zeros(m.nbody, dtype=bool)
    for b in range(1, m.nbody):
        parent = int(m.body_parentid[b])
        own = [j for j in range(int(m.body_jntadr[b]), int(m.body_jntadr[b]) + int(m.body_jntnum[b]))
               if j in commanded]
        vertical = all(int(m.jnt_type[j]) == HINGE and abs(float(d.xaxis[j][2])) > VERTICAL for j in own)
        moved[b] = bool(own) or moved[parent]
        out[b] = moved[b] and vertical and (out[parent] or not moved[parent])
    return out


def _colliding_geoms(m: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) bool: geoms the model lets collide (``contype`` or ``conaffinity`` non-zero)."""
    return (m.geom_contype != 0) | (m.geom_conaffinity != 0)


def _capsule_segments(m: mujoco.MjModel, bodies) -> dict[int, list[np.ndarray]]:
    """For each body of ``bodies`` (ids) without a colliding geom: the offsets (in its frame) of
    its children's origins that are longer than :data:`MIN_SEGMENT` (the capsules' far ends)."""
    has_geom = np.zeros(m.nbody, dtype=bool)
    has_geom[m.geom_bodyid[_colliding_geoms(m)]] = True
    out: dict[int, list[np.ndarray]] = {}
    for b in bodies:
        if has_geom[b]:
            continue
        ends = [m.body_pos[c].copy() for c in range(1, m.nbody)
                if int(m.body_parentid[c]) == b and c != b and np.linalg.norm(m.body_pos[c]) > MIN_SEGMENT]
        if ends:
            out[int(b)] = ends
    return out


def _add_obstacles(spec: mujoco.MjSpec, params: SceneParams, margin: float) -> None:
    """The floor (a plane facing +z at ``params.floor``) and the boxes as geoms of the world body
    of ``spec`` (named :data:`FLOOR_NAME`, :data:`BOX_NAME`), contype :data:`FLOOR_BIT` (the
    floor) or :data:`OBSTACLE` (boxes), conaffinity 0, geom margin ``margin``; massless, grey."""
    common = dict(conaffinity=0, margin=float(margin), gap=0.0, density=0.0, rgba=[0.5, 0.5, 0.5, 0.4])
    if params.floor is not None:
        spec.worldbody.add_geom(name=FLOOR_NAME, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 1.0],
                                pos=[0.0, 0.0, params.floor], contype=FLOOR_BIT, **common)
    for k, box in enumerate(params.boxes):
        spec.worldbody.add_geom(name=BOX_NAME.format(k + 1), type=mujoco.mjtGeom.mjGEOM_BOX, size=list(box[3:]),
                                pos=list(box[:3]), contype=OBSTACLE, **common)


def _link_bits(b: int, moving: np.ndarray, level: np.ndarray, self_collision: bool) -> tuple[int, int]:
    """(contype, conaffinity) of a geom of robot body ``b`` (see the module docstring)."""
    links = MOVING | STATIC if self_collision else 0
    if moving[b]:
        return MOVING, OBSTACLE | links | (0 if level[b] else FLOOR_BIT)
    return (STATIC, 0) if self_collision else (0, 0)


def _set_robot_filters(spec: mujoco.MjSpec, m: mujoco.MjModel, moving: np.ndarray, level: np.ndarray,
                      self_collision: bool) -> None:
    """Every geom of ``spec`` (compiled as ``m``; its ``id``s valid) gets the contype/conaffinity of
    its body's role (:func:`_link_bits`; ``level``: the bodies that never meet the floor); the
    world body's geoms and geoms the model marks as never colliding meet nothing. Robot geoms get
    margin and gap 0 (a contact among links is an overlap)."""
    colliding = _colliding_geoms(m)
    for g in spec.geoms:
        i = g.id
        if i < 0 or i >= m.ngeom:
            continue  # (added after m was compiled: the scene's own)
        b = int(m.geom_bodyid[i])
        g.contype, g.conaffinity = (0, 0) if b == 0 or not colliding[i] else _link_bits(b, moving, level,
                                                                                      self_collision)
        g.margin, g.gap = 0.0, 0.0


def _add_capsules(spec: mujoco.MjSpec, segments: dict[int, list[np.ndarray]], moving: np.ndarray,
                 level: np.ndarray, radius: float, self_collision: bool) -> None:
    """A massless capsule of ``radius`` from each body's origin to each of its ``segments`` ends
    (bodies by compiled id), with the collision bits of :func:`_link_bits`."""
    bodies = {b.id: b for b in spec.bodies}
    for b, ends in segments.items():
        body = bodies[b]
        bits = _link_bits(b, moving, level, self_collision)
        for k, end in enumerate(ends):
            g = body.add_geom(name=CAPSULE_NAME.format(b, k), type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                              size=[float(radius), 0.0, 0.0], density=0.0, margin=0.0, gap=0.0,
                              contype=bits[0], conaffinity=bits[1], rgba=[0.9, 0.6, 0.2, 0.5])
            g.fromto = [0.0, 0.0, 0.0, *map(float, end)]


def add_scene_physics(spec: mujoco.MjSpec, m: mujoco.MjModel, jids, qpos_rest: np.ndarray,
                      params: SceneParams) -> None:
    """A simulator's physics meets the scene: the floor and boxes added to ``spec`` with margin 0
    (they push back on contact), capsules for links without collision geometry (massless: the
    dynamics are unchanged), and contacts only between the links the commanded joints move and
    those obstacles, with the checker's filters (links turning only about vertical axes ignore the
    floor); no self-collision in the physics (the servos would fight it; the checker counts it).
    The caller enables contacts and compiles.

    Parameters
    ----------
    spec : mujoco.MjSpec
        The simulator's model, edited in place.
    m : mujoco.MjModel
        ``spec`` compiled (its elements' ``id`` valid), before this edit.
    jids : sequence of int
        The commanded joints' ids.
    qpos_rest : (nq,) float ndarray
        The rest posture (where the vertical axes are found).
    params : SceneParams
        The scene (a floor or boxes declared).
    """
    moving = _moved_bodies(m, jids)
    level = _level_bodies(m, jids, qpos_rest)
    segments = _capsule_segments(m, range(1, m.nbody))
    _set_robot_filters(spec, m, moving, level, False)
    _add_capsules(spec, segments, moving, level, params.link_radius, False)
    _add_obstacles(spec, params, 0.0)


def body_name(m: mujoco.MjModel, b: int) -> str:
    """A body's name for a message.

    Parameters
    ----------
    m : mujoco.MjModel
        The model.
    b : int
        Body id.

    Returns
    -------
    str
        Its name, or ``body <id>`` when it has none.
    """
    return m.body(b).name or f"body {b}"


class SceneModel:
    """The collision model of ``robot`` in the scene ``params`` (see the module docstring).

    Attributes: ``model`` (MjModel; same bodies, joints and qpos layout as ``robot.model``),
    ``moving`` ((nbody,) bool), ``level`` ((nbody,) bool: moving bodies that never meet the floor,
    :func:`_level_bodies`), ``geom_cause`` ((ngeom,) int: :data:`LINK`, :data:`STATIC_LINK`,
    :data:`FLOOR`, :data:`BOX`, :data:`NONE`), ``geom_box`` ((ngeom,) int: box index from 0, -1),
    ``capsule_links`` (names of the links given capsules), ``excluded`` (pairs of link names left
    out because they touch at rest), ``rest_contacts`` (obstacle contacts at rest, as words),
    ``notices``. Read-only once built; shared by every :class:`.scene.SceneChecker` of the robot."""

    def __init__(self, robot: RobotModel, params: SceneParams):
        self.params = params
        path = robot.path
        prefixes = robot.prefixes if robot.prefixes is not None else ament_prefixes()
        spec, _ = load_spec(path, robot.package_paths, prefixes, True)
        for pair in list(spec.pairs):  # explicit pairs would bypass the filters below
            spec.delete(pair)
        spec.option.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        spec.option.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_FILTERPARENT)
        m0 = compile_spec(spec, path)
        if m0.nq != robot.model.nq or m0.njnt != robot.model.njnt:
            raise ConfigError(f"parameter arm.model: {path} compiles to another joint layout for collision checking "
                              f"({m0.njnt} joints, nq {m0.nq}) than for kinematics ({robot.model.njnt}, "
                              f"{robot.model.nq})")
        for b in spec.bodies:  # exclude pairs name their bodies
            if b.id > 0 and not b.name:
                b.name = f"sagg_body_{b.id}"
        moving = _moved_bodies(m0, robot.jids)
        level = _level_bodies(m0, robot.jids, robot.qpos_rest)
        segments = _capsule_segments(m0, range(1, m0.nbody))
        _set_robot_filters(spec, m0, moving, level, params.self_collision)
        _add_capsules(spec, segments, moving, level, params.link_radius, params.self_collision)
        _add_obstacles(spec, params, params.clearance)
        m1 = compile_spec(spec, path)
        self.moving, self.level = moving, level
        self.capsule_links = tuple(body_name(m0, b) for b in segments)
        # ---- pairs of links touching at rest: excluded
        excluded: list[tuple[str, str]] = []
        rest_contacts: list[str] = []
        if params.self_collision or params.obstacles:
            d = mujoco.MjData(m1)
            d.qpos[:] = robot.qpos_rest
            mujoco.mj_kinematics(m1, d)
            mujoco.mj_collision(m1, d)
            seen = set()
            cause = _geom_causes(m1)
            for i in range(d.ncon):
                g1, g2 = (int(x) for x in d.contact.geom[i])
                c1, c2 = cause[g1], cause[g2]
                if c1 in (FLOOR, BOX) or c2 in (FLOOR, BOX):
                    link, obst = (g2, g1) if c1 in (FLOOR, BOX) else (g1, g2)
                    what = "the floor" if cause[obst] == FLOOR else m1.geom(obst).name.replace("sagg_scene_", "")
                    rest_contacts.append(f"{body_name(m1, int(m1.geom_bodyid[link]))} within "
                                         f"{params.clearance:g} m of {what.replace('_', ' ')}")
                    continue
                pair = tuple(sorted((int(m1.geom_bodyid[g1]), int(m1.geom_bodyid[g2]))))
                if pair not in seen:
                    seen.add(pair)
                    names = (body_name(m1, pair[0]), body_name(m1, pair[1]))
                    spec.add_exclude(bodyname1=names[0], bodyname2=names[1])
                    excluded.append(names)
        self.excluded = tuple(excluded)
        self.rest_contacts = tuple(dict.fromkeys(rest_contacts))
        self.model = compile_spec(spec, path) if excluded else m1
        self.geom_cause = _geom_causes(self.model)
        self.geom_box = np.array([_box_index(self.model, g) for g in range(self.model.ngeom)], dtype=np.int64)
        self.notices = self._notices(path)

    def _notices(self, path: str) -> list[str]:
        out = []
        if self.capsule_links:
            out.append(f"scene: {len(self.capsule_links)} link(s) of {path} have no collision geometry; "
                       f"capsules of radius {self.params.link_radius:g} m stand for them (origin to each child's "
                       f"origin): {', '.join(self.capsule_links)}")
        level = [body_name(self.model, b) for b in np.unique(self.model.geom_bodyid[self.geom_cause == LINK])
                 if self.level[b]]
        if level and self.params.floor is not None:
            out.append("scene: link(s) that only turn about vertical axes keep their height and are not checked "
                       f"against the floor: {', '.join(level)}")
        if self.excluded:
            out.append("scene: self-collision leaves out the link pairs that touch at the rest posture (as "
                       "MoveIt's 'default in collision'): " + ", ".join(f"{a}-{b}" for a, b in self.excluded))
        if self.rest_contacts:
            out.append("scene: the rest posture itself is in collision (a move from it is allowed only on its "
                       "way out): " + "; ".join(self.rest_contacts))
        return out


def _geom_causes(m: mujoco.MjModel) -> np.ndarray:
    """(ngeom,) cause code of each geom (see :class:`SceneModel`)."""
    out = np.full(m.ngeom, NONE, dtype=np.int64)
    for g in range(m.ngeom):
        name = m.geom(g).name
        if name == FLOOR_NAME:
            out[g] = FLOOR
        elif _box_index(m, g) >= 0:
            out[g] = BOX
        elif m.geom_contype[g] == MOVING:
            out[g] = LINK
        elif m.geom_contype[g] == STATIC:
            out[g] = STATIC_LINK
    return out


def _box_index(m: mujoco.MjModel, g: int) -> int:
    """The box index (from 0) of a scene box geom, else -1."""
    name = m.geom(g).name
    prefix = BOX_NAME.format("")
    if int(m.geom_bodyid[g]) == 0 and name.startswith(prefix) and name[len(prefix):].isdigit():
        return int(name[len(prefix):]) - 1
    return -1


def motion_radii(m: mujoco.MjModel, jids, geoms: np.ndarray, slide_stroke: dict[int, float]) -> np.ndarray:
    """For each joint of ``jids``: a bound, valid for every posture, on how far a point of the
    geoms ``geoms`` ((ngeom,) bool) that the joint moves can be from it.

    A hinge (or ball) turns a point about its anchor, so the point's distance to the anchor never
    changes; the distance from a geom's point to the joint is then at most the geom's bounding
    radius plus the chain of constant lengths from the geom's centre through the anchors of the
    joints in between (each turning about its own anchor) and the fixed body offsets up to the
    joint's anchor, plus the stroke of each slide joint on the way (``slide_stroke[j]``: its
    largest travel from ``qpos0``). A straight joint-space move by ``dq`` then moves no point by
    more than ``sum_j |dq_j| R_j`` (a hinge's R_j) + ``sum_j |dq_j|`` (a slide's R_j = 1): the speed
    of a point is at most the sum over joints of the joint speed times its distance to the axis.

    Parameters
    ----------
    m : mujoco.MjModel
        The collision model.
    jids : sequence of int, length n
        Joint ids (hinge or slide).
    geoms : (ngeom,) bool ndarray
        The geoms that count.
    slide_stroke : dict of int to float
        For every slide joint on the chains: its largest travel (m).

    Returns
    -------
    (n,) float ndarray
        R_j (m per rad for a hinge; 1 for a slide).
    """
    out = np.zeros(len(jids))
    for i, j in enumerate(int(x) for x in jids):
        if int(m.jnt_type[j]) == SLIDE:
            out[i] = 1.0
            continue
        top = int(m.jnt_bodyid[j])
        best = 0.0
        for g in np.flatnonzero(geoms):
            b = int(m.geom_bodyid[g])
            if not _descends(m, b, top):
                continue
            best = max(best, _bound_to_joint(m, g, j, slide_stroke))
        out[i] = best
    return out


def _descends(m: mujoco.MjModel, b: int, top: int) -> bool:
    while b != 0 and b != top:
        b = int(m.body_parentid[b])
    return b == top


def _bound_to_joint(m: mujoco.MjModel, g: int, j: int, slide_stroke: dict[int, float]) -> float:
    """Largest distance from a point of geom ``g`` to the anchor of hinge ``j`` (an ancestor's
    or its own body's joint), for any posture (see :func:`motion_radii`)."""
    y = m.geom_pos[g].astype(float).copy()        # a point fixed in the current body's frame
    dist = float(m.geom_rbound[g])
    b = int(m.geom_bodyid[g])
    while b != 0:
        j0, nj = int(m.body_jntadr[b]), int(m.body_jntnum[b])
        # the last joint of a body acts last; a free joint (a root's, above every commanded joint) is never reached
        for k in range(j0 + nj - 1, j0 - 1, -1):
            kind = int(m.jnt_type[k])
            if kind in (HINGE, BALL):
                anchor = m.jnt_pos[k]
                dist += float(np.linalg.norm(y - anchor))
                if k == j:
                    return dist
                y = anchor.astype(float).copy()
            elif kind == SLIDE:
                dist += float(slide_stroke.get(k, 0.0))
        y = m.body_pos[b] + quat_matrix(m.body_quat[b]) @ y
        b = int(m.body_parentid[b])
    raise AssertionError(f"joint {j} does not move geom {g}")
