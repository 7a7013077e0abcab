"""The one dispatch point between the evolving-context arms (ROS-free): the generated planar arm
(:mod:`.arm`) and a robot from its model file (:mod:`.model_arm`). Callers build a spec with
:func:`arm_spec_from_params` and then never branch on the arm kind: a small registry keyed by the
spec's type gives its simulator, reachable set, test goals, reach and base point.

Adding an arm kind = one spec/simulator module plus one :data:`ARM_KINDS` line."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from sagg_common.scene import SceneChecker

from .arm import ArmSim, ArmSpec, ReachableArea, reachable_area, test_goals
from .model_arm import ModelArmSim, ModelArmSpec, model_reachable_area, model_test_goals
from .params import arm_spec_from_params

__all__ = ["ARM_KINDS", "ArmKind", "arm_base_point", "arm_kind", "arm_reach", "arm_reachable_area",
           "arm_scene_checker", "arm_spec_from_params", "arm_task_dim", "arm_test_goals", "make_arm_sim"]


@dataclass(frozen=True)
class ArmKind:
    """What every runner needs of one kind of arm."""

    simulator: Callable[[Any, int], ArmSim]
    reachable_area: Callable[..., ReachableArea]
    test_goals: Callable[..., np.ndarray]
    reach: Callable[[Any], float]          # task-unit scale of the arm (for task-unit defaults)
    base_point: Callable[[Any], np.ndarray]  # the arm's base in task coordinates (metric bands)
    task_dim: Callable[[Any], int]
    scene_checker: Callable[[Any], Any]     # a learner's collision checker in the arm's scene, or None


def _model_scene_checker(spec: ModelArmSpec):
    """The arm's own SceneChecker in its scene (the collision model shared with its simulators)."""
    if spec.scene is None:
        return None
    arm = spec.loaded()
    return SceneChecker(arm, spec.scene, model=arm.scene_model())


ARM_KINDS: dict[type, ArmKind] = {
    # planar: reach = total length (the tip's farthest distance from the base at the origin)
    ArmSpec: ArmKind(ArmSim, reachable_area, test_goals, lambda s: float(s.total_length),
                     lambda s: np.zeros(2), lambda s: ArmSim.task_dim, lambda s: None),
    ModelArmSpec: ArmKind(ModelArmSim, model_reachable_area, model_test_goals, ModelArmSpec.reach,
                          ModelArmSpec.base_point, lambda s: s.task_dim, _model_scene_checker),
}


def arm_kind(spec) -> ArmKind:
    kind = ARM_KINDS.get(type(spec))
    if kind is None:
        raise ValueError(f"unknown arm spec {type(spec).__name__}; known: {[t.__name__ for t in ARM_KINDS]}")
    return kind


def make_arm_sim(spec, seed: int) -> ArmSim:
    """The simulator of ``spec`` (ArmSim protocol), its motor noise seeded by ``seed``."""
    return arm_kind(spec).simulator(spec, seed)


def arm_reachable_area(spec, lower, upper, seed: int = 0, **kw) -> ReachableArea:
    """The reachable set of ``spec`` inside the box [lower, upper] (2-D or 3-D grid)."""
    return arm_kind(spec).reachable_area(spec, lower, upper, seed=seed, **kw)


def arm_test_goals(spec, lower, upper, n: int = 100, seed: int = 0, area: ReachableArea | None = None) -> np.ndarray:
    """n test goals of ``spec`` in [lower, upper] (reached effector positions, Sec. 3.7)."""
    return arm_kind(spec).test_goals(spec, lower, upper, n=n, seed=seed, area=area)


def arm_reach(spec) -> float:
    return float(arm_kind(spec).reach(spec))


def arm_base_point(spec) -> np.ndarray:
    return np.asarray(arm_kind(spec).base_point(spec), dtype=float)


def arm_task_dim(spec) -> int:
    return int(arm_kind(spec).task_dim(spec))


def arm_scene_checker(spec):
    """The learner's collision checker of ``spec`` in its scene (``scene.*``: a floor or boxes), as
    the learner node builds it from the same model; None without a scene (or for the planar arm)."""
    return arm_kind(spec).scene_checker(spec)
