"""Collision checking of the arm's postures and moves against its scene (ROS-free).

A real arm must never be commanded into the table, a wall or itself: every move is checked
before it is sent. What is checked (docs/safety.md, "The scene"):

- the scene declared in ``scene.*`` (:mod:`.scene_params`): a floor and boxes; nothing else
  exists for the checker (no perception);
- the robot's own geometry from its model file, capsules where a link has none
  (:mod:`.scene_model`), and, with ``scene.self_collision``, the links against each other;
- a link closer than ``scene.clearance`` to the floor or a box counts as a collision; links
  among themselves collide when they overlap.

:class:`SceneChecker` checks one posture (:meth:`SceneChecker.posture`) or a straight joint-space
move (:meth:`SceneChecker.segment`), sampled finely enough that no point of any link moves more
than ``scene.margin`` between two checked postures. :func:`task_point_refusal` is the check left
when there is no model (a tracker gives only the task point): the task point only.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import mujoco
import numpy as np

from .diagnostics import all_finite
from .model_kin import SLIDE
from .params import ConfigError
from .robot_model import RobotModel, robot_from_params
from .scene_model import BOX, FLOOR, LINK, STATIC_LINK, SceneModel, body_name, motion_radii
from .scene_params import SCENE_PARAMS, SceneParams, box_distance

__all__ = ["SCENE_PARAMS", "Refusal", "SceneChecker", "SceneParams", "scene_from_params", "task_point_refusal"]

CAUSES = ("self", "floor", "box")
# m: a sample of a way out (start in collision) may be this much closer than the start was
WAY_OUT_TOLERANCE = 1e-6


class Refusal(NamedTuple):
    """Why a posture or a move is refused.

    ``cause``: ``"self"``, ``"floor"`` or ``"box"``; ``detail``: in words (``"link5 and link7"``,
    ``"link4 0.01 m above the floor at z=0.000 (clearance 0.03)"``, ``"link6 in box 1"``; boxes
    are counted from 1 in the order of ``scene.boxes``); ``at``: the fraction of the move at the
    refused posture (0..1; 1 for a single posture or a task point); ``distance``: the signed
    distance (m) of the worst contact there (< 0: overlap; for the floor and boxes compare it with
    the clearance)."""

    cause: str
    detail: str
    at: float
    distance: float


class SceneChecker:
    """Checks postures and moves of ``robot``'s commanded joints against the scene ``params``.

    ``joints`` (default ``robot.joint_names``): the order of a posture's values, a subset of the
    robot's joints that move the effector; every other joint is held at its rest value
    (``robot.qpos_rest``). The collision model (:class:`.scene_model.SceneModel`) is built from
    the robot's file unless ``model`` gives one built before (it can be shared; each checker has
    its own MjData, so one checker is not for concurrent threads).

    Attributes: ``joint_names``, ``radii`` ((n,): the bound R_j of each joint, see
    :meth:`samples`), ``notices`` (what to say once about the model in its scene: the links given
    capsules, those that never meet the floor, the pairs left out, a rest posture in collision;
    :meth:`SceneParams.describe` says what the scene holds), ``scene`` (the :class:`SceneModel`)."""

    def __init__(self, robot: RobotModel, params: SceneParams, joints: Sequence[str] | None = None,
                 model: SceneModel | None = None):
        names = list(robot.joint_names if joints is None else joints)
        allowed = list(robot.moving_joints)
        bad = [j for j in names if j not in allowed]
        if bad or not names or len(set(names)) != len(names):
            raise ConfigError(f"parameter joints: got {names}; allowed: distinct names among the joints of "
                              f"{robot.path} that move the effector {allowed}")
        self.params = params
        self.scene = model if model is not None else SceneModel(robot, params)
        m = self.model = self.scene.model
        self.joint_names = tuple(names)
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, j) for j in names]
        self._qadr = np.array([m.jnt_qposadr[j] for j in jids], dtype=np.int64)
        self.data = mujoco.MjData(m)
        self.data.qpos[:] = robot.qpos_rest
        # the bound on motion: strokes of the slide joints (commanded: their limits; held: at rest)
        stroke = {}
        lo = dict(zip(robot.joint_names, robot.lower))
        hi = dict(zip(robot.joint_names, robot.upper))
        for k in range(m.njnt):
            if int(m.jnt_type[k]) != SLIDE:
                continue
            q0, name = float(m.qpos0[m.jnt_qposadr[k]]), m.joint(k).name
            if name in lo:
                stroke[k] = max(abs(lo[name] - q0), abs(hi[name] - q0))
            else:
                stroke[k] = abs(float(robot.qpos_rest[m.jnt_qposadr[k]]) - q0)
        links = (self.scene.geom_cause == LINK)
        self.radii = motion_radii(m, jids, links, stroke)
        self.radii.flags.writeable = False
        self.notices = list(self.scene.notices)
        self._cause = self.scene.geom_cause
        self._box = self.scene.geom_box

    # ------------------------------------------------------------------ checks
    def posture(self, alpha: np.ndarray) -> Refusal | None:
        """Check one posture.

        Parameters
        ----------
        alpha : (n,) float ndarray
            Values of the joints :attr:`joint_names` (rad, m for a slide joint); the other joints
            at rest.

        Returns
        -------
        Refusal or None
            None when the posture is free; else the worst contact (``at`` = 1). ValueError for a
            posture of another length or not finite.
        """
        contacts = self._contacts(self._posture(alpha))
        if not contacts:
            return None
        return self._refusal(min(contacts.values()), 1.0)

    def segment(self, alpha0: np.ndarray, alpha1: np.ndarray) -> Refusal | None:
        """Check the straight joint-space move from ``alpha0`` to ``alpha1``.

        The move is checked at :meth:`samples` postures evenly spaced after ``alpha0``, through
        ``alpha1`` inclusive, so that no point of any link moves more than ``scene.margin``
        between two checked postures (nor from ``alpha0`` to the first one). ``alpha0`` itself is
        where the arm is: it is checked only when a sample collides. If ``alpha0`` is in
        collision (an arm resting on the table through a calibration gap), the move is a way out
        and allowed when its end is free and no sample has a colliding pair (link and obstacle,
        or two links) that was not colliding at ``alpha0``, nor one closer than it was there.

        Parameters
        ----------
        alpha0, alpha1 : (n,) float ndarray
            Start and end postures of the joints :attr:`joint_names`.

        Returns
        -------
        Refusal or None
            None when the move is allowed; else the first refused sample's worst contact, ``at``
            its fraction of the move (in (0, 1]). ValueError for postures of another length or not
            finite.
        """
        a0 = self._posture(alpha0)
        dq = self._posture(alpha1) - a0
        n = self._count(dq)
        start: dict | None = None
        for i in range(1, n + 1):
            t = i / n
            contacts = self._contacts(a0 + t * dq)
            if not contacts:
                continue
            if start is None:
                start = self._contacts(a0)
            if not start or i == n:
                return self._refusal(min(contacts.values()), t)
            worse = [c for key, c in contacts.items()
                     if key not in start or c[0] < start[key][0] - WAY_OUT_TOLERANCE]
            if worse:
                return self._refusal(min(worse), t)
        return None

    def samples(self, alpha0: np.ndarray, alpha1: np.ndarray) -> int:
        """How many postures :meth:`segment` checks for a move.

        The bound: a straight move by ``dq`` moves no point of any link by more than
        ``D = sum_j |dq_j| R_j`` (:attr:`radii`: for a hinge, a posture-independent bound on the
        distance from its anchor to any point of the geometry it moves; 1 for a slide), so
        ``ceil(D / margin)`` evenly spaced samples (at least 1) move no point more than
        ``margin`` between two of them.

        Parameters
        ----------
        alpha0, alpha1 : (n,) float ndarray
            Start and end postures.

        Returns
        -------
        int
            The number of checked postures (>= 1).
        """
        return self._count(self._posture(alpha1) - self._posture(alpha0))

    def contacts(self, alpha: np.ndarray) -> list[Refusal]:
        """Every colliding pair of one posture, worst first (for a report or a test).

        Parameters
        ----------
        alpha : (n,) float ndarray
            Values of the joints :attr:`joint_names`.

        Returns
        -------
        list of Refusal
            One per colliding pair (link and obstacle, or two links), ``at`` = 1.
        """
        return [self._refusal(c, 1.0) for c in sorted(self._contacts(self._posture(alpha)).values())]

    # ------------------------------------------------------------------ inside
    def _posture(self, alpha) -> np.ndarray:
        a = alpha if type(alpha) is np.ndarray and alpha.dtype == np.float64 else np.asarray(alpha, dtype=float)
        if a.shape != self._qadr.shape or not all_finite(a):
            raise ValueError(f"a posture of {len(self._qadr)} finite values ({', '.join(self.joint_names)}); "
                             f"got {a.tolist() if a.ndim == 1 else a.shape}")
        return a

    def _count(self, dq: np.ndarray) -> int:
        d = float(np.abs(dq) @ self.radii)
        return max(1, math.ceil(d / self.params.margin - 1e-9))

    def _contacts(self, alpha: np.ndarray) -> dict:
        """The colliding pairs of a posture: {key: (excess, cause, body1, body2 or box index,
        distance)}, excess = distance minus the pair's threshold (clearance or 0), < 0."""
        m, d = self.model, self.data
        d.qpos[self._qadr] = alpha
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        if d.ncon == 0:
            return {}
        out: dict = {}
        cause, box = self._cause, self._box
        clearance = self.params.clearance
        for g, dist in zip(d.contact.geom[:d.ncon], d.contact.dist[:d.ncon]):
            g1, g2 = int(g[0]), int(g[1])
            c1, c2 = int(cause[g1]), int(cause[g2])
            dist = float(dist)
            if c1 in (FLOOR, BOX) or c2 in (FLOOR, BOX):
                obst, link = (g1, g2) if c1 in (FLOOR, BOX) else (g2, g1)
                kind = int(cause[obst])
                if dist >= clearance:
                    continue
                b = int(m.geom_bodyid[link])
                key = ("floor", b) if kind == FLOOR else ("box", int(box[obst]), b)
                entry = (dist - clearance, key[0], b, int(box[obst]), dist)
            elif c1 in (LINK, STATIC_LINK) and c2 in (LINK, STATIC_LINK):
                if dist >= 0.0:
                    continue
                b1, b2 = sorted((int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])))
                key = ("self", b1, b2)
                entry = (dist, "self", b1, b2, dist)
            else:
                continue
            if key not in out or entry < out[key]:
                out[key] = entry
        return out

    def _refusal(self, entry: tuple, at: float) -> Refusal:
        _, cause, b1, other, dist = entry
        m, p = self.model, self.params
        link = body_name(m, b1)
        if cause == "self":
            return Refusal("self", f"{link} and {body_name(m, other)}", at, dist)
        if cause == "floor":
            where = (f"{dist:.3f} m above the floor" if dist >= 0 else f"{-dist:.3f} m through the floor")
            return Refusal("floor", f"{link} {where} at z={p.floor:.3f} (clearance {p.clearance:g})", at, dist)
        box = other + 1
        if dist < 0:
            return Refusal("box", f"{link} in box {box}", at, dist)
        return Refusal("box", f"{link} {dist:.3f} m from box {box} (clearance {p.clearance:g})", at, dist)


def task_point_refusal(y: np.ndarray, params: SceneParams, axes: str = "xyz") -> Refusal | None:
    """The task point only, for a set-up without the robot's model (a tracker gives the effector's
    position): the point must be at least ``clearance`` above the floor and outside every box
    grown by ``clearance``. Nothing else of the arm is checked.

    Parameters
    ----------
    y : (m,) float ndarray
        The task point, one coordinate per letter of ``axes`` (world frame of the scene, m).
    params : SceneParams
        The scene.
    axes : str
        The world axes of ``y``'s coordinates (``"xyz"``, ``"xy"``, ...). The floor is checked
        when ``z`` is among them; a box on the axes given (a 2-D point is refused when its
        projection is in a box's: conservative, the missing coordinate being unknown).

    Returns
    -------
    Refusal or None
        None when the point is clear; else why (``at`` = 1).
    """
    y = np.asarray(y, dtype=float)
    if y.shape != (len(axes),):
        raise ValueError(f"task point of shape {y.shape}; allowed: ({len(axes)},) for axes {axes!r}")
    c = params.clearance
    if params.floor is not None and "z" in axes:
        dist = float(y[axes.index("z")]) - params.floor
        if dist < c:
            where = f"{dist:.3f} m above the floor" if dist >= 0 else f"{-dist:.3f} m below the floor"
            return Refusal("floor", f"the task point {where} at z={params.floor:.3f} (clearance {c:g})", 1.0, dist)
    idx = ["xyz".index(a) for a in axes]
    for k, box in enumerate(params.boxes):
        dist = box_distance(y, [box[i] for i in idx] + [box[3 + i] for i in idx])
        if dist < c:
            what = f"in box {k + 1}" if dist < 0 else f"{dist:.3f} m from box {k + 1} (clearance {c:g})"
            return Refusal("box", f"the task point {what}", 1.0, dist)
    return None


def scene_from_params(p: dict, joints: Sequence[str], base_dir: str) -> SceneChecker | None:
    """The scene checker of a learner from its parameters: ``scene.*`` and the robot's model
    ``task_model.*`` (loaded as :func:`.robot_model.task_from_params` does, relative paths
    relative to ``base_dir``), its commanded ``joints`` in the learner's order.

    Parameters
    ----------
    p : dict
        The learner's resolved parameters (``scene.*``, ``task_model.*``, ``joint_limits.*``,
        ``rest_posture``).
    joints : sequence of str
        The learner's joint names, in command order.
    base_dir : str
        The parameter file's directory.

    Returns
    -------
    SceneChecker or None
        None when there is no model (``task_model.file`` empty: only :func:`task_point_refusal`
        can check then) or no scene (no floor, no box).
    """
    params = SceneParams.from_params(p)
    if not p.get("task_model.file") or not params.obstacles:
        return None
    robot = robot_from_params(p, joints, base_dir)
    return SceneChecker(robot, params, joints)

