"""Shared plumbing of the generated MuJoCo models' specs (quadruped, fishing rod): field checks,
the parameter schema (``<prefix>.<field>``) and building a spec from resolved parameters."""
from __future__ import annotations

import dataclasses
import math

from sagg_common.params import ConfigError, Param, Schema


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


def spec_schema(prefix: str, cls, ints: tuple[str, ...], what: str, module: str) -> Schema:
    """One parameter per field of the spec dataclass ``cls`` (``<prefix>.<field>``)."""
    return tuple(
        Param(f"{prefix}.{f.name}", "int" if f.name in ints else "float", f.default,
              f"{what}: {f.name.replace('_', ' ')} (see {module}; our choice).")
        for f in dataclasses.fields(cls))


def spec_from_params(params: dict, prefix: str, cls):
    """The spec from resolved parameters; ConfigError names a bad field."""
    fields = {k[len(prefix) + 1:]: v for k, v in params.items() if k.startswith(prefix + ".")}
    spec = cls(**fields)
    try:
        spec.validate()
    except ValueError as exc:
        raise ConfigError(f"parameter {exc}") from exc
    return spec
