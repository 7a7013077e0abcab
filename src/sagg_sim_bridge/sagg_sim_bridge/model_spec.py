"""Shared plumbing of the generated MuJoCo models (quadruped, fishing rod): spec field checks, the
parameter descriptions (``<prefix>.<field>``; the schema by :func:`sagg_common.params.dataclass_schema`),
a spec from resolved parameters, and the rest-state simulator base."""
from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from sagg_common.params import ConfigError


def validate_fields(spec, prefix: str, ints: tuple[str, ...], non_negative: tuple[str, ...],
                    max_timestep: float) -> None:
    """Every int field of ``ints`` in [1, 1000]; every other field a finite number, > 0 (or >= 0
    for ``non_negative``); ``timestep`` at most ``max_timestep``. ValueError names the field."""
    for f in dataclasses.fields(spec):
        v = getattr(spec, f.name)
        if f.name in ints:
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 1000:
                raise ValueError(f"{prefix}.{f.name}: got {v!r}; allowed: an integer in [1, 1000]")
            continue
        zero_ok = f.name in non_negative
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or \
                (v < 0 if zero_ok else v <= 0):
            raise ValueError(f"{prefix}.{f.name}: got {v!r}; allowed: a finite number {'>=' if zero_ok else '>'} 0")
    if spec.timestep > max_timestep:
        raise ValueError(f"{prefix}.timestep: got {spec.timestep}; allowed: (0, {max_timestep}]")


def model_doc(what: str, module: str):
    """The description of a generated model's spec field (no per-field text: see the module)."""
    return lambda name: f"{what}: {name.replace('_', ' ')} (see {module}; our choice)."


def spec_from_params(params: dict, prefix: str, cls):
    """The spec from resolved parameters; ConfigError names a bad field."""
    fields = {k[len(prefix) + 1:]: v for k, v in params.items() if k.startswith(prefix + ".")}
    spec = cls(**fields)
    try:
        spec.validate()
    except ValueError as exc:
        raise ConfigError(f"parameter {exc}") from exc
    return spec


class RestStateSim:
    """What the synergy simulators share: the generated model, their joints' addresses, the fixed
    rest state (the rest posture commanded and settled for ``settle_time`` at build time) and the
    reset to it before every experiment (Alg. 4: 'Reset the current context: s_t = s_rest')."""

    def _build(self, xml: str, joint_names, rest_posture, settle_time: float, timestep: float) -> None:
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.rest = np.array(rest_posture)
        self.n_joints = len(joint_names)
        jid = [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in joint_names]
        self._qadr = np.array([self.model.jnt_qposadr[j] for j in jid])
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self._qadr] = self.rest
        self.data.ctrl[:] = self.rest
        steps = int(round(settle_time / timestep))
        if steps:
            mujoco.mj_step(self.model, self.data, nstep=steps)
        self.data.time = 0.0
        self._rest_qpos = self.data.qpos.copy()
        self._rest_qvel = self.data.qvel.copy()

    def reset(self) -> None:
        """Restore the fixed rest state."""
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = self._rest_qpos
        self.data.qvel[:] = self._rest_qvel
        self.data.ctrl[:] = self.rest
        mujoco.mj_forward(self.model, self.data)
