"""Parameter schemas and experiment configuration files (ROS-free).

One schema (a tuple of :class:`Param`) per node is the single source of truth for a parameter's
name, type, default, allowed range and description. The same schema validates YAML configs for
in-process experiments and declares ROS parameters with descriptors in the nodes.

Config files use the ROS 2 parameter-file form::

    /**:                       # applies to every node
      ros__parameters:
        seed: 0
    sagg_learner:              # one section per node
      ros__parameters:
        v: 2.0

Nested mappings under ``ros__parameters`` are flattened with dots, as ROS does
(``task_space: {lower: [..]}`` is the parameter ``task_space.lower``).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import numpy as np
import yaml

NODE_NAMES = ("sagg_goal_generator", "sagg_learner", "sagg_sim_bridge")
WILDCARD = "/**"


class ConfigError(ValueError):
    """A configuration or parameter value is invalid; the message names the field."""


def is_int(x: Any) -> bool:
    """An integer (Python or numpy), not a bool."""
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


def is_real(x: Any) -> bool:
    """A real number (Python or numpy int/float), not a bool."""
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, (bool, np.bool_))


@dataclass(frozen=True)
class Param:
    """One parameter: its name, type, default, allowed values and documentation.

    ``kind`` is one of ``float``, ``int``, ``bool``, ``str``, ``float_list``, ``int_list``,
    ``str_list``. ``low``/``high`` bound numbers (and every element of numeric lists),
    ``choices`` restricts strings, ``length`` fixes a list's length (None = any non-empty; with
    ``empty_ok`` any, the empty list included: a list of items whose "none" is no item).
    """

    name: str
    kind: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] | None = None
    length: int | None = None
    low_open: bool = False  # True: value must be > low instead of >= low
    deprecated: str = ""    # non-empty: kept so that old parameter files load; why, said once when set
    empty_ok: bool = False  # a list parameter may be empty

    def allowed(self) -> str:
        """Human-readable description of the allowed values."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        if self.kind == "bool":
            return "true or false"
        parts = []
        if self.low is not None or self.high is not None:
            lo = "(" if self.low_open else "["
            parts.append(
                f"{lo}{'-inf' if self.low is None else self.low}, "
                f"{'inf' if self.high is None else self.high}]"
            )
        base = {"float": "a number", "int": "an integer", "str": "a string",
                "float_list": "a list of numbers", "int_list": "a list of integers",
                "str_list": "a list of strings"}[self.kind]
        if self.kind.endswith("_list") and self.length is not None:
            base += f" of length {self.length}"
        elif self.kind.endswith("_list") and self.empty_ok:
            base += " (empty allowed)"
        return base + (" in " + parts[0] if parts else "")

    def _fail(self, value: Any, why: str = "") -> ConfigError:
        return ConfigError(
            f"parameter '{self.name}': got {value!r}{' (' + why + ')' if why else ''}; "
            f"allowed: {self.allowed()}"
        )

    def _number(self, value: Any, integer: bool) -> float | int:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self._fail(value, "not a number")
        if integer:
            if isinstance(value, float) and not value.is_integer():
                raise self._fail(value, "not an integer")
            value = int(value)
        else:
            value = float(value)
            if not math.isfinite(value):
                raise self._fail(value, "not finite")
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            raise self._fail(value, "below range")
        if self.high is not None and value > self.high:
            raise self._fail(value, "above range")
        return value

    def validate(self, value: Any) -> Any:
        """Return ``value`` coerced to this parameter's type, or raise :class:`ConfigError`."""
        k = self.kind
        if k == "bool":
            if not isinstance(value, bool):
                raise self._fail(value, "not a boolean")
            return value
        if k == "str":
            if not isinstance(value, str):
                raise self._fail(value, "not a string")
            if self.choices is not None and value not in self.choices:
                raise self._fail(value)
            return value
        if k in ("float", "int"):
            return self._number(value, k == "int")
        if k.endswith("_list"):
            if not isinstance(value, (list, tuple)) or (len(value) == 0 and not self.empty_ok):
                raise self._fail(value, "not a list" if self.empty_ok else "not a non-empty list")
            if self.length is not None and len(value) != self.length:
                raise self._fail(value, f"length {len(value)}")
            if k == "str_list":
                if not all(isinstance(v, str) for v in value):
                    raise self._fail(value, "not all strings")
                return list(value)
            return [self._number(v, k == "int_list") for v in value]
        raise AssertionError(f"unknown parameter kind {k}")


Schema = tuple[Param, ...]

# The strategies (shared by the generator and the learner): one list of names. Goal strategies: the
# learner asks the goal generator for goals, which chooses them with that strategy's teacher
# (sagg_goal_generator.core.TEACHERS, whose keys are GOAL_STRATEGIES; test_teachers.py checks).
# Actuator strategies: no goals (the generator is idle).
GOAL_STRATEGIES = ("sagg-riac", "sagg-random", "alp-gmm", "discretized-progress")
ACTUATOR_STRATEGIES = ("actuator-random", "actuator-riac")
# the four of paper Sec. 3.7: what the benchmarks compare unless told otherwise
PAPER_STRATEGIES = ("sagg-riac", "sagg-random", "actuator-random", "actuator-riac")
STRATEGIES = PAPER_STRATEGIES + tuple(s for s in GOAL_STRATEGIES if s not in PAPER_STRATEGIES)

# Parameters every learning node declares; set them once under ``/**`` in a config.
SHARED_SCHEMA: Schema = (
    Param("seed", "int", 0, "Run seed; every random stream is derived from it.", low=0),
    Param("strategy", "str", "sagg-riac",
          "Exploration strategy (Sec. 3.7): sagg-riac (goals by competence progress), sagg-random "
          "(goals uniform in Y), actuator-random, actuator-riac; beyond the paper (docs/notes/teachers.md): "
          "alp-gmm (Portelas et al. 2019: goals from a Gaussian mixture over absolute learning progress), "
          "discretized-progress (explauto's grid of competence progress). The generator is idle for the "
          "actuator strategies.", choices=STRATEGIES),
    Param("task_space.lower", "float_list", [0.0, -150.0], "Lower corner of the task space Y."),
    Param("task_space.upper", "float_list", [150.0, 150.0], "Upper corner of the task space Y."),
)


def dataclass_schema(prefix: str, cls, doc: Mapping[str, str] | Callable[[str], str],
                     choices: Mapping[str, tuple[str, ...]] | None = None) -> Schema:
    """The parameters of a simulator's spec dataclass ``cls``: one ``<prefix>.<field>`` per field,
    its kind from the default's type, its description ``doc[field]`` (or ``doc(field)``),
    ``choices[field]`` restricting a string. No ranges: the spec's own ``validate`` checks the
    values, naming the parameter (the spec is the one place its fields are defined)."""
    kinds = {bool: "bool", int: "int", float: "float", str: "str"}
    choices = choices or {}
    return tuple(
        Param(f"{prefix}.{f.name}", kinds[type(f.default)], f.default,
              doc(f.name) if callable(doc) else doc.get(f.name, f.name), choices=choices.get(f.name))
        for f in dataclasses.fields(cls))


def schema_defaults(schema: Schema) -> dict[str, Any]:
    """Every parameter's default, but a deprecated one's (it is in a config only when given)."""
    return {p.name: p.default for p in schema if not p.deprecated}


def resolve(schema: Schema, values: Mapping[str, Any], where: str = "") -> dict[str, Any]:
    """Defaults of ``schema`` overridden by ``values``, all validated.

    Unknown names raise :class:`ConfigError` naming them and the section ``where``.
    """
    by_name = {p.name: p for p in schema}
    unknown = sorted(set(values) - set(by_name))
    if unknown:
        raise ConfigError(
            f"unknown parameter(s) {', '.join(unknown)}{' in ' + where if where else ''}; "
            f"known: {', '.join(sorted(by_name))}"
        )
    out = schema_defaults(schema)
    for name, value in values.items():
        out[name] = by_name[name].validate(value)
    return out


def flatten(mapping: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """Flatten nested mappings with dots, as ROS 2 does for parameter files."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if not isinstance(key, str):
            raise ConfigError(f"parameter name {key!r} under '{prefix or 'ros__parameters'}' is not a string")
        name = f"{prefix}.{key}" if prefix else key
        if isinstance(value, Mapping):
            out.update(flatten(value, name))
        else:
            out[name] = value
    return out


def read_config(path: str | Path) -> dict[str, dict[str, Any]]:
    """Read a ROS 2 parameter file into ``{section: {param: value}}`` (raw, unvalidated).

    Sections are node names or ``/**``; each must hold a ``ros__parameters`` mapping.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"config file '{path}': cannot read ({exc.strerror})") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"config file '{path}': not valid YAML ({exc})") from exc
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"config file '{path}': top level must be a mapping of node sections")
    sections: dict[str, dict[str, Any]] = {}
    for section, body in data.items():
        if section != WILDCARD and section not in NODE_NAMES:
            raise ConfigError(
                f"config file '{path}': unknown section {section!r}; allowed: "
                f"{', '.join([WILDCARD, *NODE_NAMES])}"
            )
        if not isinstance(body, Mapping) or set(body) != {"ros__parameters"} or not isinstance(
            body["ros__parameters"], (Mapping, type(None))
        ):
            raise ConfigError(
                f"config file '{path}': section {section!r} must contain exactly one key "
                f"'ros__parameters' holding a mapping"
            )
        sections[section] = flatten(body["ros__parameters"] or {})
    return sections


def node_params(
    sections: Mapping[str, Mapping[str, Any]], node: str, schema: Schema,
    overrides: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Resolved parameters of ``node``: schema defaults < ``/**`` < node section < overrides.

    Parameters under ``/**`` that this node does not declare are ignored (as in ROS);
    unknown parameters in the node's own section are an error.
    """
    names = {p.name for p in schema}
    merged = {k: v for k, v in sections.get(WILDCARD, {}).items() if k in names}
    merged.update(sections.get(node, {}))
    if overrides:
        merged.update({k: v for k, v in overrides.items() if k in names})
    return resolve(schema, merged, where=f"section '{node}'")


def is_given(sections: Mapping[str, Mapping[str, Any]], node: str, name: str,
             overrides: Mapping[str, Any] | None = None) -> bool:
    """Whether ``name`` of ``node`` is set by the config (``/**`` or the node's section) or an
    override, i.e. does not come from the schema's default (the precedence of :func:`node_params`)."""
    return name in (overrides or {}) or any(name in sections.get(s, {}) for s in (WILDCARD, node))


def check_wildcard(sections: Mapping[str, Mapping[str, Any]], schemas: Iterable[Schema]) -> None:
    """Raise if a ``/**`` parameter is declared by none of the given schemas (a likely typo)."""
    known = {p.name for s in schemas for p in s}
    unknown = sorted(set(sections.get(WILDCARD, {})) - known)
    if unknown:
        raise ConfigError(f"unknown parameter(s) {', '.join(unknown)} in section '{WILDCARD}'")


SHARED_BETWEEN_LEVELS = ("seed", "strategy", "task_space.lower", "task_space.upper")


def resolve_nodes(path: str | Path, schemas: Mapping[str, Schema],
                  overrides: Mapping[str, Any] | None = None) -> dict[str, dict[str, Any]]:
    """Every node's parameters from one config file: schema defaults < ``/**`` < node section <
    ``overrides`` (applied to each node that declares them). ConfigError for a ``/**`` or
    override parameter no node declares, and for a shared parameter (seed, strategy, task space)
    that differs between the goal generator and the learner."""
    sections = read_config(path)
    check_wildcard(sections, schemas.values())
    known = {p.name for s in schemas.values() for p in s}
    unknown = sorted(set(overrides or {}) - known)
    if unknown:
        raise ConfigError(f"unknown parameter(s) {', '.join(unknown)} in overrides (--set); "
                          "see `sagg params` for every parameter")
    out = {name: node_params(sections, name, schema, overrides) for name, schema in schemas.items()}
    g, l = out["sagg_goal_generator"], out["sagg_learner"]
    for key in SHARED_BETWEEN_LEVELS:
        if g[key] != l[key]:
            raise ConfigError(f"parameter '{key}' differs between sagg_goal_generator ({g[key]!r}) and "
                              f"sagg_learner ({l[key]!r}); set it once under '/**'")
    return out


def schema_markdown(schema: Schema) -> str:
    """A Markdown table documenting a schema (used for the README's parameter tables)."""
    rows = ["| parameter | type | default | allowed | description |", "|---|---|---|---|---|"]
    for p in schema:
        rows.append(f"| `{p.name}` | {p.kind} | `{p.default!r}` | {p.allowed()} | {p.description} |")
    return "\n".join(rows)


def parse_set(items: list[str] | None) -> dict:
    """``--set name=value`` overrides; values are parsed as YAML (numbers, lists, booleans)."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise ConfigError(f"--set {item!r}: expected name=value")
        name, value = item.split("=", 1)
        try:
            out[name.strip()] = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise ConfigError(f"--set {name}: value {value!r} is not valid YAML ({exc})") from exc
    return out
