"""sagg_common.ros_params: a schema declared as ROS parameters (descriptors, coercion, errors), in
one process with a private rclpy context (no graph needed)."""
from __future__ import annotations

import sys

import numpy as np
import pytest
import yaml

import rclpy
from rcl_interfaces.msg import ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter

from sagg_bringup.graph.processes import pick_domain_id
from sagg_common.params import ConfigError, Param
from sagg_common.ros_params import declare_schema, descriptor, file_parameters

SCHEMA = (
    Param("v", "float", 2.0, "speed", low=0.0, high=10.0, low_open=True),
    Param("q", "int", 20, "count", low=1, high=100),
    Param("seed", "int", 0, "seed", low=0),
    Param("strategy", "str", "a", "strategy", choices=("a", "b")),
    Param("flag", "bool", True, "flag"),
    Param("task_space.lower", "float_list", [0.0, -1.0], "lower corner"),
    Param("names", "str_list", ["j0"], "names"),
)


@pytest.fixture
def ctx():
    c = rclpy.Context()
    rclpy.init(context=c, domain_id=pick_domain_id(), signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    yield c
    c.try_shutdown()


def node_with(ctx, **overrides) -> Node:
    return Node("sagg_param_test", context=ctx,
                parameter_overrides=[Parameter(k.replace("__", "."), value=v) for k, v in overrides.items()])


def test_defaults_declared_with_descriptors(ctx):
    node = node_with(ctx)
    values = declare_schema(node, SCHEMA)
    assert values == {p.name: p.default for p in SCHEMA}
    d = node.describe_parameter("v")
    assert d.type == ParameterType.PARAMETER_DOUBLE and d.read_only
    assert d.floating_point_range[0].from_value == 0.0 and d.floating_point_range[0].to_value == 10.0
    assert "(0.0, 10.0]" in d.additional_constraints and d.description == "speed"
    q = node.describe_parameter("q")
    assert q.type == ParameterType.PARAMETER_INTEGER
    assert (q.integer_range[0].from_value, q.integer_range[0].to_value) == (1, 100)
    assert node.describe_parameter("seed").integer_range[0].to_value == 2**63 - 1
    s = node.describe_parameter("strategy")
    assert "'a', 'b'" in s.additional_constraints and not s.floating_point_range
    assert node.describe_parameter("task_space.lower").type == ParameterType.PARAMETER_DOUBLE_ARRAY
    assert node.describe_parameter("names").type == ParameterType.PARAMETER_STRING_ARRAY
    assert node.get_parameter("flag").value is True


def test_ints_coerced_where_floats_expected(ctx):
    node = node_with(ctx, v=3, task_space__lower=[0, -150])
    values = declare_schema(node, SCHEMA)
    assert values["v"] == 3.0 and isinstance(values["v"], float)
    assert values["task_space.lower"] == [0.0, -150.0]
    assert all(isinstance(x, float) for x in values["task_space.lower"])
    assert node.get_parameter("v").type_ == Parameter.Type.DOUBLE
    assert list(node.get_parameter("task_space.lower").value) == [0.0, -150.0]


@pytest.mark.parametrize("name,value,allowed", [
    ("v", 0.0, "(0.0, 10.0]"),          # open lower bound: stricter than a ROS range
    ("v", 11.5, "(0.0, 10.0]"),
    ("q", 2.5, "an integer"),
    ("strategy", "c", "one of 'a', 'b'"),
    ("flag", 1, "true or false"),
    ("v", "fast", "a number"),
])
def test_bad_value_names_parameter_and_allowed(ctx, name, value, allowed):
    node = node_with(ctx, **{name: value})
    with pytest.raises(ConfigError) as exc:
        declare_schema(node, SCHEMA)
    msg = str(exc.value)
    assert f"'{name}'" in msg and allowed in msg and "\n" not in msg


def test_overrides_from_a_parameter_file(tmp_path):
    """Values of a ROS parameter file (own section and '/**', integers where floats are expected)
    reach the schema through rclpy's public parameter API; '/**' entries for other nodes are
    listed as unused and not declared."""
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"v": 3, "for_another_node": 1}},
        "sagg_param_test": {"ros__parameters": {"q": 7, "task_space": {"lower": [0, -150]}}}}))
    args = ["--ros-args", "--params-file", str(path)]
    c = rclpy.Context()
    rclpy.init(args=args, context=c, domain_id=pick_domain_id(),
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        node = Node("sagg_param_test", context=c)
        values = declare_schema(node, SCHEMA, args)
        assert values["v"] == 3.0 and isinstance(values["v"], float) and values["q"] == 7
        assert values["task_space.lower"] == [0.0, -150.0] and values["strategy"] == "a"
        assert node.get_parameter("q").value == 7
        assert file_parameters(node, args) == ["for_another_node", "q", "task_space.lower", "v"]
        assert not node.has_parameter("for_another_node")
    finally:
        c.try_shutdown()


BOX = [0.5, 0.0, 0.2, 0.1, 0.1, 0.1]


@pytest.mark.parametrize("given,expected", [(None, []), ([], []), (BOX, BOX)])
def test_a_list_that_may_be_empty_through_a_parameter_file(tmp_path, given, expected):
    """A float list whose default is [] (scene.boxes): not given, given as [] (which rclpy's
    parameter file reader takes as not set) and given with values, it reads as expected."""
    schema = (Param("scene.boxes", "float_list", [], "boxes", empty_ok=True),)
    path = tmp_path / "params.yaml"
    body = {} if given is None else {"scene": {"boxes": given}}
    path.write_text(yaml.safe_dump({"/**": {"ros__parameters": body}}))
    args = ["--ros-args", "--params-file", str(path)]
    c = rclpy.Context()
    rclpy.init(args=args, context=c, domain_id=pick_domain_id(),
               signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    try:
        node = Node("sagg_param_test", context=c)
        values = declare_schema(node, schema, args)
        assert values["scene.boxes"] == expected
        assert list(node.get_parameter("scene.boxes").value) == expected
    finally:
        c.try_shutdown()


def test_declared_parameters_are_read_only(ctx):
    node = node_with(ctx)
    declare_schema(node, SCHEMA)
    res = node.set_parameters([Parameter("v", value=5.0)])
    assert not res[0].successful
    assert node.get_parameter("v").value == 2.0


def test_descriptor_of_one_sided_float_range():
    d = descriptor(Param("x", "float", 1.0, "x", low=0.5))
    assert d.floating_point_range[0].from_value == 0.5
    assert d.floating_point_range[0].to_value == sys.float_info.max


def test_learner_node_defaults_match_default_simulated_arm():
    """The learner node's joint defaults describe sagg_sim_bridge's default arm."""
    from sagg_low_level.node import SCHEMA as LEARNER_NODE_SCHEMA
    from sagg_sim_bridge.arm import ArmSpec

    spec = ArmSpec()
    defaults = {p.name: p.default for p in LEARNER_NODE_SCHEMA}
    lower, upper = spec.limits()
    assert defaults["joints"] == spec.joint_names()
    assert np.array_equal(defaults["joint_limits.lower"], lower)
    assert np.array_equal(defaults["joint_limits.upper"], upper)
    assert np.array_equal(defaults["rest_posture"], spec.rest_posture())


def test_node_schemas_extend_core_schemas_without_clashes():
    from sagg_goal_generator.node import SCHEMA as GEN_NODE
    from sagg_low_level.node import SCHEMA as LEARNER_NODE
    from sagg_sim_bridge.node import SCHEMA as BRIDGE_NODE

    for schema in (GEN_NODE, LEARNER_NODE, BRIDGE_NODE):
        names = [p.name for p in schema]
        assert len(names) == len(set(names))
        for p in schema:
            assert p.validate(p.default) == p.default  # defaults are valid
