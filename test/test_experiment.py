"""In-process experiments on the MuJoCo arm: `sagg experiment` end to end (paper Sec. 3.7)."""
import json
from pathlib import Path

import pytest

from sagg_bringup.cli.cli import main as cli_main
from sagg_bringup.inprocess.experiment import InProcessRun
from sagg_bringup.graph.setups import load_experiment_config, run_experiment
from sagg_common.params import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SMALL = {"arm.dof": 7, "task_space.lower": [0.0, -60.0], "task_space.upper": [60.0, 60.0]}


@pytest.mark.parametrize("strategy", ["sagg-riac", "sagg-random", "actuator-random", "actuator-riac"])
def test_experiment_writes_complete_result(tmp_path, strategy):
    res = run_experiment(ROOT / "config/arm15.yaml", strategy, 1, 1200, 400, tmp_path,
                         progress=False, overrides=SMALL)
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["strategy"] == strategy and data["seed"] == 1
    assert [c["micro_actions"] for c in data["curve"]] == [0, 400, 800, 1200]
    assert data["memory"]["samples"] == data["micro_actions"] == 1200
    assert data["config"]["sagg_sim_bridge"]["arm.dof"] == 7
    assert data["micro_actions_per_second"] > 0
    # the model learns: test error after 1200 micro-actions is below the initial one
    assert data["curve"][-1]["mean_error"] < data["curve"][0]["mean_error"]
    if strategy.startswith("sagg"):
        assert len(data["goals"]) > 3 and all("competence" in g for g in data["goals"])
        assert len(data["regions"]) >= 2
        assert 0 < data["goal_stats"]["reachable_share_of_Y"] < 1
    assert res["final_mean_error"] == data["final_mean_error"]


def test_same_seed_same_run_other_seed_other_run():
    def run(seed):
        cfg = load_experiment_config(ROOT / "config/arm15.yaml", {**SMALL, "seed": seed})
        r = InProcessRun(cfg)
        r.step_until(800)
        return r.learner.memory.digest(), [g.position.tolist() for g in r.generator.goals]
    assert run(5) == run(5)
    assert run(5)[0] != run(6)[0]


def test_stepping_in_pieces_equals_one_go():
    cfg = load_experiment_config(ROOT / "config/arm15.yaml", SMALL)
    a, b = InProcessRun(cfg), InProcessRun(cfg)
    a.step_until(700)
    for t in (1, 2, 250, 699, 700):
        b.step_until(t)
    assert a.learner.memory.digest() == b.learner.memory.digest()


def test_dynamic_mode_with_motor_noise_learns():
    res = run_experiment(ROOT / "config/arm8.yaml", None, 0, 1000, 1000, None, progress=False)
    assert res["config"]["sagg_sim_bridge"]["arm.mode"] == "dynamic"
    assert res["curve"][-1]["mean_error"] < 0.8 * res["curve"][0]["mean_error"]


def test_bad_config_values_name_the_parameter(tmp_path):
    with pytest.raises(ConfigError, match="'v'"):
        load_experiment_config(ROOT / "config/arm15.yaml", {"v": -1.0})
    with pytest.raises(ConfigError, match="arm.dof"):
        load_experiment_config(ROOT / "config/arm15.yaml", {"arm.dof": 0})
    with pytest.raises(ConfigError, match="nope"):
        load_experiment_config(ROOT / "config/arm15.yaml", {"nope": 1})
    bad = tmp_path / "bad.yaml"
    bad.write_text("sagg_learner:\n  ros__parameters:\n    q: [1, 2\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_experiment_config(bad)
    bad.write_text("sagg_learner:\n  ros__parameters:\n    qq: 3\n")
    with pytest.raises(ConfigError, match="qq"):
        load_experiment_config(bad)
    # the CLI turns it into a one-line error and exit code 2
    assert cli_main(["experiment", "--config", str(bad), "--out", str(tmp_path / "o"),
                     "--micro-actions", "10"]) == 2


@pytest.mark.parametrize("name", sorted(p.name for p in (ROOT / "config").glob("*.yaml")))
def test_every_shipped_config_loads(name):
    cfg = load_experiment_config(ROOT / "config" / name)
    assert set(cfg) == {"sagg_goal_generator", "sagg_learner", "sagg_sim_bridge"}


def test_resume_of_a_synergy_run_is_refused_by_name(tmp_path, capsys):
    # a synergy run's directory (its params.yaml names the set-up): no checkpoints to resume from
    (tmp_path / "params.yaml").write_text(
        "sagg_sim_bridge:\n  ros__parameters:\n    setup: quadruped\n"
        "sagg_learner:\n  ros__parameters:\n    max_micro_actions: 50\n")
    assert cli_main(["run", "--resume", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "is a run of set-up 'quadruped'" in err and "start a new run" in err
