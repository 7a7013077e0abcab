"""One parameter schema per node, in its package's ROS-free ``schema`` module:
the node declares exactly that schema, ``sagg params`` documents it, the in-process loaders
validate configs against it, and node-only settings (topics, controllers, frames, waits) are not
in the ROS-free cores."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_layers import heavy_roots  # noqa: E402

import sagg_goal_generator.core as gen_core
import sagg_goal_generator.node as gen_node
import sagg_goal_generator.schema as gen_schema
import sagg_low_level.fixed_context as fixed_core
import sagg_low_level.learner as learner_core
import sagg_low_level.node as learner_node
import sagg_low_level.schema as learner_schema
import sagg_low_level.fixed_node as fixed_learner_node
import sagg_sim_bridge.node as bridge_node
import sagg_sim_bridge.params as arm_core
import sagg_sim_bridge.schema as bridge_schema
import sagg_sim_bridge.synergy_node as synergy_bridge_node
import sagg_sim_bridge.synergy_params as synergy_core
from sagg_bringup.cli.cli import node_schemas

# node module -> (its schema, the cores' parameters inside it)
NODES = {
    gen_node: (gen_schema.SCHEMA, gen_core.SCHEMA),
    learner_node: (learner_schema.LEARNER_SCHEMA, learner_core.SCHEMA),
    fixed_learner_node: (learner_schema.FIXED_LEARNER_SCHEMA, fixed_core.SCHEMA + fixed_core.SYNERGY_SCHEMA),
    bridge_node: (bridge_schema.BRIDGE_SCHEMA, arm_core.SCHEMA),
    synergy_bridge_node: (bridge_schema.SYNERGY_BRIDGE_SCHEMA, synergy_core.SCHEMA),
}
NODE_ONLY = ("controller", "task_topic", "frame_id", "timing", "publish_rate", "min_goal_subscribers",
             "min_sample_subscribers", "response_timeout", "regions_period")


@pytest.mark.parametrize("node", list(NODES), ids=lambda m: m.__name__)
def test_the_node_declares_its_packages_schema(node):
    schema, core = NODES[node]
    assert node.SCHEMA is schema
    assert schema[:len(core)] == core  # the core's parameters first, then the node's own
    names = [p.name for p in schema]
    assert len(names) == len(set(names)), "a parameter declared twice"


def test_schema_modules_are_ros_free_and_node_settings_stay_out_of_the_cores():
    roots = heavy_roots()
    for mod in ("sagg_goal_generator.schema", "sagg_low_level.schema", "sagg_sim_bridge.schema"):
        assert "ROS" not in roots[mod], mod
    for _, core in NODES.values():
        assert not {p.name for p in core} & set(NODE_ONLY)
    for schema, core in NODES.values():
        assert {p.name for p in schema} & set(NODE_ONLY)  # each node has some of its own


def test_sagg_params_documents_every_nodes_schema():
    documented = list(node_schemas().values())
    for schema, _ in NODES.values():
        assert any(s is schema for s in documented)
