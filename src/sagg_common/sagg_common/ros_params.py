"""ROS 2 glue shared by the sagg nodes: parameters from a schema, and the node main loop.

Parameters: every :class:`~sagg_common.params.Param` of a node's schema is declared with a
``ParameterDescriptor`` (type, description, allowed values in ``additional_constraints``,
``FloatingPointRange``/``IntegerRange`` for bounded scalars, read-only: values are read once at
start). The value from the parameter file or ``-p`` is validated with :meth:`Param.validate`
*before* declaring, which also coerces what ROS parameter files give (``v: 2`` is an integer for
ROS but a float parameter here, ``[0, -150]`` an integer array for a float list) exactly as the
in-process config loader does. A bad value raises :class:`ConfigError`; :func:`run_node` turns it
into one log line naming the parameter and the allowed values, and exit code 2.

Spinning: :func:`spin` runs a node until shutdown with a manual ``spin_once`` loop
(``EventsExecutor.spin()`` hangs in this build and ``spin_until_future_complete`` is slow,
docs/architecture.md).
"""
from __future__ import annotations

import array
import json
import os
import signal
import sys
import time
from typing import Any, Callable

import yaml

from sagg_common.params import ConfigError, Param, Schema, flatten

FLOAT_MAX = sys.float_info.max
INT64_MIN, INT64_MAX = -(2**63), 2**63 - 1


def _types():
    # lazy (heavy): ROS
    from rcl_interfaces.msg import ParameterType

    return {
        "float": ParameterType.PARAMETER_DOUBLE,
        "int": ParameterType.PARAMETER_INTEGER,
        "bool": ParameterType.PARAMETER_BOOL,
        "str": ParameterType.PARAMETER_STRING,
        "float_list": ParameterType.PARAMETER_DOUBLE_ARRAY,
        "int_list": ParameterType.PARAMETER_INTEGER_ARRAY,
        "str_list": ParameterType.PARAMETER_STRING_ARRAY,
    }


def descriptor(param: Param):
    """The ``ParameterDescriptor`` of one schema parameter."""
    # lazy (heavy): ROS
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    d = ParameterDescriptor(
        name=param.name,
        type=_types()[param.kind],
        description=param.description,
        additional_constraints="allowed: " + param.allowed(),
        read_only=True,
    )
    bounded = param.low is not None or param.high is not None
    if bounded and param.kind == "float":
        # ROS ranges are closed; an open lower bound (low_open) is enforced by Param.validate and
        # stated in additional_constraints.
        d.floating_point_range = [FloatingPointRange(
            from_value=-FLOAT_MAX if param.low is None else float(param.low),
            to_value=FLOAT_MAX if param.high is None else float(param.high), step=0.0)]
    elif bounded and param.kind == "int":
        d.integer_range = [IntegerRange(
            from_value=INT64_MIN if param.low is None else int(param.low),
            to_value=INT64_MAX if param.high is None else int(param.high), step=1)]
    return d


def _plain(value: Any) -> Any:
    """ROS parameter values as plain Python (arrays become lists)."""
    if isinstance(value, (array.array, tuple)):
        return list(value)
    if type(value).__module__ == "numpy" and hasattr(value, "tolist"):
        return value.tolist()
    return value


_ARGS: list[str] | None = None  # the command line given to run_node (for the parameter files)


def params_files(args: list[str]) -> list[str]:
    """The ``--params-file`` paths of a ROS command line (after ``--ros-args``)."""
    out, ros = [], False
    for i, a in enumerate(args):
        if a == "--ros-args":
            ros = True
        elif a == "--":
            ros = False
        elif ros and a == "--params-file" and i + 1 < len(args):
            out.append(args[i + 1])
    return out


def params_dir() -> str | None:
    """The directory of the last ``--params-file`` of this node's command line (None without one):
    what relative file parameters (a robot's model file) are relative to, as in a config file."""
    files = params_files(_ARGS or sys.argv)
    return os.path.dirname(os.path.abspath(files[-1])) if files else None


def _file_sections(args: list[str], sections: tuple[str, ...]):
    """``(path, section, parameters)`` of the given sections in the parameter files of ``args``."""
    for path in params_files(args):
        try:
            with open(path) as fh:
                data = yaml.safe_load(fh)
        except (OSError, yaml.YAMLError):
            continue  # rclpy reports unreadable files itself
        if not isinstance(data, dict):
            continue
        for section in sections:
            body = data.get(section)
            if isinstance(body, dict) and isinstance(body.get("ros__parameters"), dict):
                yield path, section, body["ros__parameters"]


def check_own_sections(node, schema: Schema, args: list[str]) -> None:
    """Unknown parameters in this node's own section of a parameter file are an error (most
    likely a typo), as for in-process configs; ``/**`` entries for other nodes are not."""
    known = {p.name for p in schema}
    name = node.get_name()
    for path, section, params in _file_sections(args, (name, "/" + name)):
        unknown = sorted(
            n for n in flatten(params)
            if n not in known and not node.has_parameter(n) and not n.startswith("qos_overrides."))
        if unknown:
            raise ConfigError(
                f"unknown parameter(s) {', '.join(unknown)} in section '{section}' of {path}; "
                f"allowed: {', '.join(sorted(known))}")


def wildcard_params(args: list[str]) -> set[str]:
    """The parameter names of the ``/**`` sections of the parameter files of ``args``."""
    return {n for _, _, params in _file_sections(args, ("/**",)) for n in flatten(params)}


def declare_schema(node, schema: Schema, args: list[str] | None = None) -> dict[str, Any]:
    """Declare every parameter of ``schema`` on ``node`` and return the validated values.

    The value is the override (parameter file / ``-p``) if given, else the schema default; it is
    validated and coerced by :meth:`Param.validate` and then declared with that exact value.
    Raises :class:`ConfigError` naming the first bad parameter, or the unknown parameters of the
    node's own section in a parameter file of ``args`` (default: the command line of
    :func:`run_node`, else ``sys.argv``).
    """
    args = args if args is not None else (_ARGS or sys.argv)
    check_own_sections(node, schema, args)
    values: dict[str, Any] = {}
    for p in schema:
        raw = _override(node, p.name, _UNSET)
        if p.deprecated and raw is not _UNSET:
            node.get_logger().warning(f"parameter '{p.name}' is deprecated: {p.deprecated}")
        value = p.validate(_plain(p.default if raw is _UNSET else raw))
        node.declare_parameter(p.name, value, descriptor(p), ignore_override=True)
        values[p.name] = value
    # '/**' parameters are meant for every node that declares them (seed, strategy, task_space.*):
    # not worth a line in the nodes that do not
    shared = wildcard_params(args)
    unused = sorted(n for n in file_parameters(node, args) if not node.has_parameter(n) and n not in shared)
    if unused:
        # They may come from the '/**' section meant for other nodes: not an error (as in ROS).
        node.get_logger().info(f"parameters not used by this node: {', '.join(unused)}")
    return values


_UNSET = object()  # no override given


def _override(node, name: str, default: Any) -> Any:
    """The raw override of parameter ``name`` (parameter file, ``-p``, or the node's
    ``parameter_overrides``), else ``default``; public rclpy API only: the parameter is declared
    dynamically typed (so an integer where the schema wants a float is taken as given, for
    :meth:`Param.validate` to coerce), read, and undeclared again."""
    # lazy (heavy): ROS
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.parameter import Parameter

    declared = node.declare_parameter(name, None, ParameterDescriptor(dynamic_typing=True))
    node.undeclare_parameter(name)
    return default if declared.type_ == Parameter.Type.NOT_SET else declared.value


def file_parameters(node, args: list[str]) -> list[str]:
    """The parameter names that the parameter files of ``args`` give this node (its own section
    and ``/**``)."""
    name = node.get_name()
    return sorted({n for _, _, params in _file_sections(args, ("/**", name, "/" + name)) for n in flatten(params)})


def spin(node, executor=None, should_stop: Callable[[], bool] | None = None) -> None:
    """Spin ``node`` until the context shuts down (or ``should_stop()``), with ``spin_once``."""
    if executor is None:
        executor = make_executor()
    executor.add_node(node)
    ctx = node.context
    try:
        while ctx.ok() and not (should_stop is not None and should_stop()):
            executor.spin_once(timeout_sec=0.1)
    finally:
        try:
            executor.remove_node(node)
        except Exception:  # noqa: BLE001 - best effort at shutdown
            pass


def make_executor(kind: str = "events"):
    """``events`` (rclpy.experimental.EventsExecutor, driven by spin_once) or ``single``."""
    # lazy (heavy): ROS
    import rclpy.executors

    if kind == "events":
        # lazy (heavy): ROS
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    if kind == "single":
        return rclpy.executors.SingleThreadedExecutor()
    raise ValueError(f"executor: got {kind!r}; allowed: 'events' or 'single'")


def run_node(name: str, factory: Callable[[], Any], args: list[str] | None = None,
             executor: str = "events") -> int:
    """Init rclpy, build the node with ``factory()``, spin it, shut down. Returns the exit code:
    0 normally, 2 for a bad parameter (one log line naming it and the allowed values)."""
    # lazy (heavy): ROS
    import rclpy
    from rclpy.executors import ExternalShutdownException

    global _ARGS
    if args is None:
        args = sys.argv
    _ARGS = list(args)
    try:
        rclpy.init(args=args, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: BLE001 - e.g. an unreadable parameter file
        print(f"[ERROR] cannot start: {str(exc).splitlines()[0] if str(exc) else exc!r}", file=sys.stderr)
        return 2
    stop = {"flag": False}

    def on_signal(signum, frame):  # noqa: ARG001
        stop["flag"] = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    node = None
    code = 0
    try:
        try:
            node = factory()
        except (ConfigError, ValueError) as exc:
            # lazy (heavy): ROS
            import rclpy.logging

            rclpy.logging.get_logger(name).error(str(exc).replace("\n", " "))
            return 2
        try:
            spin(node, make_executor(executor), should_stop=lambda: stop["flag"] or getattr(node, "done", False))
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        code = getattr(node, "exit_code", 0)
    finally:
        if node is not None:
            try:
                if hasattr(node, "close"):
                    node.close()
                flush_publishers(node)
                if getattr(node, "published", None) is not None:  # (what a bag must hold)
                    node.get_logger().info("published counts: " + json.dumps(node.published, sort_keys=True))
                node.destroy_node()
            except Exception:  # noqa: BLE001
                pass
        if rclpy.ok():
            rclpy.shutdown()
    return code


def flush_publishers(node, seconds: float = 1.0) -> None:
    """Before a node goes: wait (at most ``seconds`` in all) until every reliable subscription has
    acknowledged what the node's publishers sent (``Publisher.wait_for_all_acked``). A node that
    exits first may take its last messages with it: seen on a loaded machine, the bridge's answer
    to the last command missing from the bag (published 820 joint states, the bag 819). Bounded
    short: a subscriber that left without being unmatched yet never acknowledges, and the
    orchestrator kills a node that takes longer than its stop timeout to exit."""
    # lazy (heavy): ROS
    from rclpy.duration import Duration
    t_end = time.monotonic() + seconds
    for pub in list(node.publishers):
        left = t_end - time.monotonic()
        if left <= 0:
            break
        pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))


# History depth of the hardware-contract topics (commands, joint states, task point) published by our
# nodes: deep enough that a slow reader such as the bag recorder never loses a reliable message
# (shallower histories lost messages to a recorder falling behind under load).
HW_DEPTH = 10000


def reliable(depth: int, transient_local: bool = False):
    """Reliable, keep-last ``depth`` QoS (transient_local for latched topics such as /sagg/regions)."""
    # lazy (heavy): ROS
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient_local else DurabilityPolicy.VOLATILE)
