"""The arm in the fixed context (learner parameter context: fixed): the Alg. 4 fixed-context learner
drives the simulated arm with absolute joint targets θ, one position command from rest per
experiment, and learns an inverse model; in-process here (the graph: test_fixed_graph.py)."""
import numpy as np
import pytest

from sagg_bringup.graph.setups import load_experiment_config, run_experiment
from sagg_bringup.graph.setups import in_process_run, setup_of
from sagg_bringup.inprocess.fixed_experiment import ARM_FIXED
from sagg_common.params import ConfigError, GOAL_STRATEGIES, STRATEGIES

# noise-free kinematic 8-DOF arm (config/arm8.yaml is dynamic with 20 % motor noise)
KIN = {"context": "fixed", "arm.mode": "kinematic", "arm.motor_noise": 0.0, "eval.goals": 40}


def test_context_chooses_the_learner():
    assert setup_of("config/arm8.yaml").name == "arm"
    assert setup_of("config/arm8.yaml", {"context": "fixed"}).name == ARM_FIXED
    assert setup_of("config/arm8.yaml", {"context": "evolving"}).name == "arm"
    assert setup_of("config/quadruped.yaml", {"context": "fixed"}).name == "quadruped"
    with pytest.raises(ConfigError, match="context"):
        setup_of("config/arm8.yaml", {"context": "both"})


def test_fixed_arm_config_drops_the_evolving_parameters_and_takes_the_arm():
    cfg = load_experiment_config("config/arm8.yaml", {"context": "fixed"})
    lp = cfg["sagg_learner"]
    assert "subgoals" not in lp and "v" not in lp and "reset_every" not in lp  # evolving only
    assert lp["q"] == 20  # the config's q: the exploration budget of both learners
    assert lp["synergy.kind"] == "posture" and lp["context"] == "fixed"
    assert lp["joints"] == [f"joint_{i}" for i in range(8)]
    assert lp["controller"] == "forward_position_controller" and lp["task_topic"] == "/tip_position"
    # the evolving learner still refuses what it does not know, the fixed one too
    with pytest.raises(ConfigError, match="unknown"):
        load_experiment_config("config/arm8.yaml", {"context": "fixed", "lambdda": 1.0})


def test_fixed_arm_is_metric_and_explores_per_arm_length():
    """The fixed-context arm's defaults: competence on plain distances (its Y is metric, Sec. 3.5)
    and the exploration's D per arm length (explore_length = total_length, whatever Y) unless the
    config or an override gives explore_length. The synergy set-ups keep the rescaled units (Sec. 4.3)."""
    lp = load_experiment_config("config/arm8.yaml", {"context": "fixed"})["sagg_learner"]
    assert lp["competence_rescale"] is False and lp["explore_length"] == 50.0
    for box in ([-2.0, -2.0], [2.0, 2.0]), ([-0.5, -1.0], [1.0, 1.0]):
        lp = load_experiment_config("config/arm7_ratio15.yaml", {
            "context": "fixed", "task_space.lower": box[0], "task_space.upper": box[1]})["sagg_learner"]
        assert lp["explore_length"] == 1.0
    for given in (5.0, 0.0):  # given explicitly: kept (0 = the competence's units)
        lp = load_experiment_config("config/arm8.yaml", {"context": "fixed", "explore_length": given})["sagg_learner"]
        assert lp["explore_length"] == given
    lp = load_experiment_config("config/quadruped.yaml")["sagg_learner"]
    assert lp["competence_rescale"] is True and lp["explore_length"] == 0.0
    run = in_process_run("config/arm8.yaml", KIN)
    assert run.learner.distance([30.0, 40.0], [0.0, 0.0]) == 50.0
    assert run.learner.explore_distance([30.0, 40.0], [0.0, 0.0]) == 1.0


def test_each_experiment_is_theta_from_rest_and_its_settled_tip():
    """Kinematic arm: every stored outcome is the tip of its θ (forward kinematics), every θ within
    the joint limits, whatever the previous experiment: the context is fixed."""
    run = in_process_run("config/arm8.yaml", KIN)
    run.step_until(60)
    sim = run.setup.sim
    th, y = run.learner.thetas, run.learner.outcomes
    assert len(th) == 60
    assert np.all(th >= sim.lower) and np.all(th <= sim.upper)
    np.testing.assert_allclose(y, sim.tip_positions(th), atol=1e-9)
    np.testing.assert_allclose(run.learner.y_rest, sim.tip_positions(sim.rest), atol=1e-9)


def test_fixed_arm_learns_in_process():
    """SAGG-RIAC in the fixed context on the kinematic 8-DOF arm, the evolving arm's test goals:
    the mean test error falls at least 10-fold in 600 experiments (measured with the
    defaults blocking_w 3, outcome_competence 'goal', metric competence, explore_length 50:
    33.3 -> 2.87 at 300 -> 2.41 at 600, 173 goals; with the former defaults 33.3 -> 3.33 -> 2.38,
    41 goals)."""
    r = run_experiment("config/arm8.yaml", "sagg-riac", 0, 600, 300, None, progress=False, overrides=KIN)
    first, last = r["curve"][0]["mean_error"], r["curve"][-1]["mean_error"]
    assert r["synergy"]["setup"] == ARM_FIXED and r["micro_actions"] == 600
    assert last < first / 10, r["curve"]
    assert len(r["goals"]) > 100  # blocking ends the hopeless goals early: ~3.5 experiments per goal
    # where the experiments went (result.json "phases", both contexts): reach + explore = all of
    # them, split over the goals inside / outside the reachable area; every goal is attempted once
    ph = r["phases"]
    assert ph["reach"] + ph["explore"] == 600 and ph["babble"] == 0
    assert ph["reach"] >= len(r["goals"]) - 1  # the last goal may be cut by the budget
    inside, outside = ph["reachable_goals"], ph["unreachable_goals"]
    assert inside["goals"] + outside["goals"] == len(r["goals"])
    assert inside["reach"] + inside["explore"] + outside["reach"] + outside["explore"] == 600
    assert 0 <= r["coverage"]["median"] <= r["coverage"]["max"]
    syn = r["synergy"]  # how the attempts ended: reached, blocked (Sec. 3.7.6), or budget spent
    assert syn["goals_blocked"] > 0 and syn["goals_reached"] > 0
    assert syn["goals_reached"] + syn["goals_blocked"] <= syn["goals_done"] <= len(r["goals"])


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_every_strategy_learns_the_fixed_arm(strategy):
    """Every strategy runs in the fixed context and at least halves the error in 150 experiments."""
    r = run_experiment("config/arm8.yaml", strategy, 1, 150, 150, None, progress=False, overrides=KIN)
    first, last = r["curve"][0]["mean_error"], r["curve"][-1]["mean_error"]
    assert last < first / 2, (strategy, r["curve"])
    assert (len(r["goals"]) > 0) == (strategy in GOAL_STRATEGIES)


def test_the_evolving_learner_refuses_the_fixed_context():
    from sagg_common.params import resolve
    from sagg_low_level.learner import SCHEMA, EvolvingContextLearner, Robot
    robot = Robot(["a", "b"], [-1.0, -1.0], [1.0, 1.0], [0.0, 0.0])
    EvolvingContextLearner(resolve(SCHEMA, {}), robot, 2)  # evolving (default): fine
    with pytest.raises(ValueError, match="context"):
        EvolvingContextLearner(resolve(SCHEMA, {"context": "fixed"}), robot, 2)


def test_launch_plan_of_a_fixed_context_arm_config(tmp_path):
    """A config file with context: fixed launches the synergy learner (posture) with the MuJoCo arm
    bridge, as `sagg run` does."""
    import yaml
    from sagg_bringup.graph.launch_params import launch_plan
    doc = yaml.safe_load(open("config/arm8.yaml"))
    doc["sagg_learner"]["ros__parameters"]["context"] = "fixed"
    path = tmp_path / "arm8_fixed.yaml"
    path.write_text(yaml.safe_dump(doc))
    plan = launch_plan(str(path))
    assert plan.setup == ARM_FIXED
    scripts = {name: script for _, script, name in plan.nodes}
    assert scripts == {"sagg_goal_generator": "goal_generator", "sagg_learner": "fixed_learner",
                       "sagg_sim_bridge": "mujoco_bridge"}
    lp = plan.params["sagg_learner"]
    assert lp["synergy.kind"] == "posture" and lp["controller"] == plan.params["sagg_sim_bridge"]["controller"]
