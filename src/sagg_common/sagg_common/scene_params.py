"""The scene's parameters (``scene.*``): what the arm must never meet (ROS-free).

Declared in a config's ``/**`` section, so that the learner (which checks every move before it
sends it, :class:`sagg_common.scene.SceneChecker`) and the simulated bridge (whose physics meets the
same obstacles and which counts the contacts) read the same scene. Lengths in metres, in the
robot model's world frame (z up).

No floor is ``scene.floor: -1000.0`` (:data:`NO_FLOOR`, the default), so that ``floor: 0.0``
alone declares a table at z = 0. Not NaN: a NaN default passes a ROS parameter file but not the
JSON of a graph run's ``-p`` values, and compares unequal to itself where two runs' parameter sets
are compared (a comparison's restart would see a changed setting). Not a separate on/off switch:
a floor given without it would be silently ignored.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

from .params import ConfigError, Param, Schema

BOX_FIELDS = 6      # centre x y z, half sizes x y z
NO_FLOOR = -1000.0  # m: scene.floor's "no floor"

SCENE_PARAMS: Schema = (
    Param("scene.floor", "float", NO_FLOOR,
          "Height (m, world z of the robot model) of the floor or table top the arm is mounted on: no moving "
          "link may come below it, nor within scene.clearance of it. The robot's base and every body no "
          "commanded joint moves never count (the arm is mounted on the table). -1000.0 (the default) = no "
          "floor.", low=NO_FLOOR, high=100.0),
    Param("scene.boxes", "float_list", [],
          "Obstacles as boxes, 6 numbers each in one flat list: centre x y z, then half sizes x y z (m, "
          "world frame of the robot model, axis-aligned). Empty (default) = no box. A box is named by its "
          "place in this list, from 1 (box 1, box 2, ...). Write every number with a decimal point (0.0, "
          "not 0): a ROS parameter file refuses a list that mixes integers and decimals.",
          empty_ok=True, low=-100.0, high=100.0),
    Param("scene.link_radius", "float", 0.05,
          "Radius (m) of the capsules that stand for a link whose collision geometry is missing (a URDF "
          "whose meshes are not found, a link without <collision>): one capsule from the link's origin "
          "to each child link's origin (said once, naming the links).",
          low=0.0, high=1.0, low_open=True),
    Param("scene.margin", "float", 0.02,
          "The largest motion (m) of any point of any link between two checked postures of a move: a move "
          "is checked at as many postures as this needs (a posture-independent bound, docs/safety.md). "
          "Keep it below twice scene.clearance, so that no link can pass through an obstacle between "
          "two checked postures.", low=0.001, high=1.0),
    Param("scene.clearance", "float", 0.03,
          "A moving link closer than this (m) to the floor or a box counts as a collision: it covers the "
          "gaps between the model and the real arm and scene (calibration, cables, a model's simplified "
          "shapes). Links among themselves collide only when they overlap.", low=0.0, high=1.0),
    Param("scene.self_collision", "bool", True,
          "With a scene declared (a floor or a box), check the arm against itself too: links that are not "
          "parent and child, nor already touching at the rest posture (the pairs left out are said once). "
          "Without a floor or a box there is no scene: nothing is checked (the paper's simulated arms)."),
)

_BY_NAME = {p.name: p for p in SCENE_PARAMS}


@dataclass(frozen=True)
class SceneParams:
    """The scene, validated (:meth:`from_params`). Hashable: a simulated arm's spec holds one.

    ``floor``: the floor's z (m), None = no floor; ``boxes``: one (cx, cy, cz, hx, hy, hz) per
    box; ``link_radius``, ``margin``, ``clearance`` (m) and ``self_collision`` as the parameters
    ``scene.*`` say."""

    floor: float | None = None
    boxes: tuple[tuple[float, float, float, float, float, float], ...] = ()
    link_radius: float = 0.05
    margin: float = 0.02
    clearance: float = 0.03
    self_collision: bool = True

    @classmethod
    def from_params(cls, p: Mapping[str, Any]) -> "SceneParams":
        """The scene from parameters ``scene.*`` (missing ones take their defaults).

        Parameters
        ----------
        p : mapping of str to value
            Parameters by full name (``scene.floor``, ...), e.g. a node's resolved parameters;
            other names are ignored.

        Returns
        -------
        SceneParams
            Validated. ConfigError names the parameter, the value and the allowed values (a
            ``scene.boxes`` whose length is not a multiple of 6, a half size not > 0, ...).
        """
        v = {name: param.validate(p[name]) if name in p else param.default for name, param in _BY_NAME.items()}
        flat = v["scene.boxes"]
        if len(flat) % BOX_FIELDS:
            raise ConfigError(f"parameter 'scene.boxes': got {flat!r} (length {len(flat)}); allowed: 6 numbers per "
                              "box (centre x y z, half sizes x y z), so a length that is a multiple of 6")
        boxes = tuple(tuple(float(x) for x in flat[i:i + BOX_FIELDS]) for i in range(0, len(flat), BOX_FIELDS))
        for k, box in enumerate(boxes):
            if not all(h > 0.0 for h in box[3:]):
                raise ConfigError(f"parameter 'scene.boxes': got {flat!r}; box {k + 1} has half sizes "
                                  f"{list(box[3:])}; allowed: half sizes > 0")
        return cls(floor=float(v["scene.floor"]) if v["scene.floor"] > NO_FLOOR else None, boxes=boxes,
                   link_radius=float(v["scene.link_radius"]), margin=float(v["scene.margin"]),
                   clearance=float(v["scene.clearance"]), self_collision=bool(v["scene.self_collision"]))

    @property
    def obstacles(self) -> bool:
        """Whether a floor or a box is declared: a scene (the arm against it and, with
        ``self_collision``, against itself), else nothing to check."""
        return self.floor is not None or bool(self.boxes)

    def describe(self) -> str:
        """What the scene holds, for the notice said at start.

        Returns
        -------
        str
            One line (``scene: floor at z=0.000 m, 2 box(es), self-collision on, ...``).
        """
        parts = [f"floor at z={self.floor:.3f} m" if self.floor is not None else "no floor",
                 f"{len(self.boxes)} box(es)" if self.boxes else "no box",
                 f"self-collision {'on' if self.self_collision else 'off'}",
                 f"clearance {self.clearance:g} m", f"margin {self.margin:g} m"]
        return "scene: " + ", ".join(parts)


def box_distance(point, box) -> float:
    """Signed distance from a point to an axis-aligned box.

    Parameters
    ----------
    point : (k,) float array-like
        The point's coordinates on k axes (m).
    box : (2k,) float array-like
        The box on the same axes: its centre's k coordinates, then its k half sizes.

    Returns
    -------
    float
        > 0 outside (the Euclidean distance to the box), < 0 inside (minus the depth to the
        nearest face), m.
    """
    n = len(point)
    d = [abs(float(point[i]) - box[i]) - box[n + i] for i in range(n)]
    outside = math.sqrt(sum(max(x, 0.0) ** 2 for x in d))
    return outside if outside > 0.0 else max(d)
