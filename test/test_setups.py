"""The set-up registry (sagg_bringup.graph.setups): every config is one entry, the entry
names its nodes, schemas, topics and report rows, and what a set-up cannot do is refused by name
before anything starts."""
from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from sagg_bringup.graph import setups
from sagg_bringup.graph.launch_params import launch_plan
from sagg_common.params import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "sagg_bringup" / "sagg_bringup"


@pytest.mark.parametrize("config, overrides, name, bridge", [
    ("arm8.yaml", None, "arm", "mujoco_bridge"),
    ("arm15.yaml", None, "arm", "mujoco_bridge"),
    ("arm8.yaml", {"context": "fixed"}, "arm-fixed", "mujoco_bridge"),
    ("quadruped.yaml", None, "quadruped", "synergy_bridge"),
    ("fishing.yaml", None, "fishing", "synergy_bridge"),
])
def test_each_config_is_one_setup_with_its_nodes_and_schemas(config, overrides, name, bridge):
    s = setups.setup_of(ROOT / "config" / config, overrides)
    assert s.name == name and s.context == ("evolving" if name == "arm" else "fixed")
    assert s.nodes["sagg_sim_bridge"] == ("sagg_sim_bridge", bridge)
    assert s.nodes["sagg_learner"][1] == ("learner" if name == "arm" else "fixed_learner")
    schemas = s.node_schemas()
    assert set(schemas) == set(s.nodes)
    # the graph config resolves against exactly these schemas, the in-process one against the cores
    full = s.graph_config(ROOT / "config" / config, overrides)
    for section, schema in schemas.items():
        assert set(full[section]) == {p.name for p in schema} or section == "sagg_learner"
    cfg = s.load_config(ROOT / "config" / config, overrides)
    assert set(cfg) == {"sagg_goal_generator", "sagg_learner", "sagg_sim_bridge"}


def test_topics_follow_the_contract_of_the_setup():
    arm = {t.name: t.msgtype for t in setups.recorded_topics(ROOT / "config/arm8.yaml")}
    assert arm["/forward_position_controller/commands"] == "std_msgs/msg/Float64MultiArray"
    quad = {t.name: t.msgtype for t in setups.recorded_topics(ROOT / "config/quadruped.yaml")}
    assert quad["/joint_trajectory_controller/joint_trajectory"] == "trajectory_msgs/msg/JointTrajectory"
    assert quad["/body_pose"] == "geometry_msgs/msg/PoseStamped"
    # the fixed-context arm speaks the arm's position contract (not trajectories)
    fixed = setups.SETUPS["arm-fixed"]
    lp = fixed.graph_config(ROOT / "config/arm8.yaml", {"context": "fixed"})["sagg_learner"]
    names = {t.name for t in fixed.topics(lp)}
    assert "/forward_position_controller/commands" in names and "/tip_position" in names
    assert not any(n.endswith("joint_trajectory") for n in names)


def test_what_a_setup_cannot_do_is_refused_by_name(tmp_path):
    with pytest.raises(ConfigError, match="set-up 'quadruped' is not supported"):
        setups.run_graph(ROOT / "config/quadruped.yaml", 10, tmp_path / "x", driver="external")
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "params.yaml").write_text(
        "sagg_learner:\n  ros__parameters:\n    context: fixed\n")
    with pytest.raises(ConfigError, match="set-up 'arm-fixed', which keeps no checkpoints"):
        setups.resume_graph(tmp_path / "run", 10)
    with pytest.raises(ConfigError, match="relearn: the run is of set-up 'arm-fixed'"):
        setups.relearn([tmp_path / "run" / "bag"], tmp_path / "re")
    assert not (tmp_path / "x").exists() and not (tmp_path / "re").exists()  # refused before anything


def test_node_tables_list_every_node_once():
    tables = setups.node_tables()
    assert list(tables) == ["sagg_goal_generator", "sagg_learner", "sagg_sim_bridge",
                            "sagg_learner (fixed_learner)", "sagg_sim_bridge (synergy_bridge)",
                            "sagg_model_server (model_server)"]
    assert tables["sagg_learner (fixed_learner)"] is setups.SETUPS["quadruped"].node_schemas()["sagg_learner"]


def test_launch_plan_names_the_setup_and_its_nodes():
    for config, name in (("arm8.yaml", "arm"), ("fishing.yaml", "fishing")):
        plan = launch_plan(str(ROOT / "config" / config))
        assert plan.setup == name
        assert [(pkg, exe) for pkg, exe, _ in plan.nodes] == list(setups.SETUPS[name].nodes.values())


def test_report_rows_come_from_the_setup(tmp_path):
    result = {"strategy": "sagg-riac", "seed": 0, "micro_actions": 0, "curve": [],
              "config": {"sagg_learner": {"task_space.lower": [0, 0], "task_space.upper": [1, 1],
                                          "context": "fixed"},
                         "sagg_sim_bridge": {"arm.dof": 8, "arm.link_profile": "equal", "arm.total_length": 50,
                                             "arm.mode": "kinematic", "arm.motor_noise": 0.0}}}
    assert setups.setup_of_result(result).name == "arm-fixed"
    text = setups.write_report(result, tmp_path / "r").read_text()
    assert "| arm | 8 DOF, equal links" in text and "| context | fixed (θ = joint targets" in text
    (tmp_path / "result.json").write_text(json.dumps(result))
    assert setups.write_report(tmp_path / "result.json", tmp_path / "r2").read_text() == text


def _setup_branches(path: Path) -> list[int]:
    """Lines of ``path`` that compare something with a set-up name or the learner context
    (``== 'fixed'``, ``config_setup(...)``, ``if ... .get('setup')``): the registry's job."""
    names = {"fixed", "evolving", "quadruped", "fishing", "arm-fixed"}
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Compare) and any(isinstance(c, ast.Constant) and c.value in names
                                                 for c in [node.left, *node.comparators]):
            out.append(node.lineno)
        if isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) == "config_setup":
            out.append(node.lineno)
        if isinstance(node, (ast.If, ast.IfExp)):  # a condition on the config's `setup` parameter
            for sub in ast.walk(node.test):
                if (isinstance(sub, ast.Call) and getattr(sub.func, "attr", "") == "get" and sub.args
                        and isinstance(sub.args[0], ast.Constant) and sub.args[0].value == "setup"):
                    out.append(sub.lineno)
    return out


def test_no_setup_branches_outside_the_registry():
    runners = ["cli/cli.py", "inprocess/experiment.py", "inprocess/fixed_experiment.py", "graph/graph.py",
               "graph/fixed_graph.py", "graph/external.py", "graph/record.py", "graph/launch_params.py",
               "bags/bags.py", "report/report.py", "experiments/compare.py", "bags/topics.py", "graph/session.py"]
    found = {f: _setup_branches(SRC / f) for f in runners}
    assert {f: lines for f, lines in found.items() if lines} == {}
    assert _setup_branches(SRC / "graph/setups.py")  # (the check sees branches where they are)
