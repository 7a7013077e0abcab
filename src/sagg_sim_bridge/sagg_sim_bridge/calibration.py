"""A calibration gap: the simulated arm differs from the model file the learner knows, as a real
arm differs from its URDF (ROS-free).

A real arm is not its URDF: its joint encoders' zeros are off by a fraction of a degree to a few
degrees (a UR arm ships a per-robot calibration that corrects offsets of that order; an arm without
it, or after a collision or a motor swap, carries them), and its links differ from the nominal
lengths by manufacturing tolerances (tenths of a millimetre to millimetres). The tool then lands
millimetres to centimetres from where the model says (a few millimetres for a calibrated industrial
arm, a centimetre or more without one). To measure what a prior from simulation is worth on such an
arm without one, the simulated bridge can be such an arm (``arm.calibration.*``):

- ``length_scale``: every translation of the kinematic chain (body positions, joint anchors,
  sites, geoms: the link lengths and the tool offset) times this factor; collision shapes keep
  their size;
- ``joint_offsets``: one per commanded joint, in ``arm.joints`` order: the joint's true angle is
  the reported (encoder) one plus the offset. The arm reports, is commanded in and is limited in
  encoder angles, as a real driver is; only where the links go differs.

The learner's model (its ``task_source: model``, the scene checker it reads from the model file)
and a prior learned on the nominal simulator do not know the gap; the task point the simulated bridge
publishes, and the evaluation on the simulator, are the true arm's.

:func:`test_gap` is the gap the prior's measurements use (docs/notes/prior.md): larger than a
calibrated arm's, so that it shows.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

from sagg_common.params import ConfigError

__all__ = ["Calibration", "apply_calibration", "test_gap"]

# the default test gap (test_gap(n, 1.0)): links 3% long, joint zeros off by ±0.03 rad (1.7°),
# alternating in sign along the chain (so that the offsets do not cancel into a rotation of the base)
TEST_GAP_SCALE = 0.03
TEST_GAP_OFFSET = 0.03


@dataclass(frozen=True)
class Calibration:
    """How the simulated arm differs from its model file (the module's two terms).

    ``length_scale``: factor on every translation of the chain, in [0.5, 2]; ``joint_offsets``:
    rad (or m for a slide joint), one per commanded joint, or () for none."""

    length_scale: float = 1.0
    joint_offsets: tuple[float, ...] = ()

    @property
    def nominal(self) -> bool:
        """True when the arm is its model (no gap)."""
        return self.length_scale == 1.0 and not any(self.joint_offsets)

    def validate(self, n_joints: int) -> None:
        """ConfigError naming the parameter for a scale outside [0.5, 2], offsets not one per
        commanded joint (``n_joints``), or an offset beyond ±π/4 or not finite."""
        s = self.length_scale
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not math.isfinite(s) or not 0.5 <= s <= 2.0:
            raise ConfigError(f"parameter 'arm.calibration.length_scale': got {s!r}; allowed: a number in [0.5, 2]")
        off = self.joint_offsets
        if off and len(off) != n_joints:
            raise ConfigError(f"parameter 'arm.calibration.joint_offsets': got {len(off)} value(s); allowed: none "
                              f"([]) or one per commanded joint ({n_joints})")
        bad = [v for v in off if not (isinstance(v, (int, float)) and math.isfinite(v) and abs(v) <= math.pi / 4)]
        if bad:
            raise ConfigError(f"parameter 'arm.calibration.joint_offsets': got {bad[0]!r}; allowed: finite values "
                              "in [-π/4, π/4]")


def test_gap(n_joints: int, factor: float = 1.0) -> Calibration:
    """The test calibration gap times ``factor`` (0 = none, 1 = the default test gap, 2 = twice it):
    links ``1 + 0.03·factor`` times their length, joint zeros off by ``±0.03·factor`` rad,
    alternating in sign from the first joint (+, -, +, ...).

    Parameters
    ----------
    n_joints : int
        Commanded joints.
    factor : float
        How many default gaps.

    Returns
    -------
    Calibration
    """
    sign = np.where(np.arange(n_joints) % 2 == 0, 1.0, -1.0)
    return Calibration(1.0 + TEST_GAP_SCALE * factor, tuple(float(v) for v in TEST_GAP_OFFSET * factor * sign))


def apply_calibration(mjspec: mujoco.MjSpec, calibration: Calibration, joint_names: list[str]) -> None:
    """Make the model in ``mjspec`` (before it is compiled) the calibrated arm: every body's,
    frame's, joint anchor's, site's and geom's position times ``length_scale``; the joint ``ref``
    of each commanded joint (``joint_names``, in command order) at minus its offset, so that MuJoCo
    turns it by (reported angle + offset) (a hinge turns by qpos − ref).

    Parameters
    ----------
    mjspec : mujoco.MjSpec
        The loaded model, not yet compiled; changed in place.
    calibration : Calibration
        Validated against ``len(joint_names)``.
    joint_names : list of str
        The commanded joints, in command order.
    """
    calibration.validate(len(joint_names))
    s = float(calibration.length_scale)
    if s != 1.0:
        for group in (mjspec.bodies, mjspec.frames, mjspec.joints, mjspec.sites, mjspec.geoms):
            for element in group:
                element.pos = np.asarray(element.pos, dtype=float) * s
    for name, offset in zip(joint_names, calibration.joint_offsets):
        joint = mjspec.joint(name)
        joint.ref = float(joint.ref) - float(offset)
