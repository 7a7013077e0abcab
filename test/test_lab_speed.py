"""Smoke tests of the before/after speed tools (tiny budgets): the two trees are stepped and compared,
the bit-identity check sees equal runs as equal, and the parts table is printed."""
from pathlib import Path

import pytest

from sagg_lab import eval_cost, time_parts, window_speed
from sagg_lab.base_tree import repo_root

SRC = Path(__file__).resolve().parents[1] / "src"


def test_window_speed_steps_both_trees_and_checks_identity():
    lines = []
    res = window_speed.compare(SRC, SRC, "config/arm15.yaml", {"strategy": "actuator-riac", "seed": 0},
                               micro_actions=400, window=200, out=lines.append)
    assert [r["micro_actions"] for r in res["rows"]] == [200, 400]
    assert res["identical"] and res["ends"]["new"]["samples"] == 400
    assert any(line.startswith("| whole run |") for line in lines)
    # the check can fail: another seed for the new child is a different run
    res = window_speed.compare(SRC, SRC, "config/arm15.yaml", {"strategy": "actuator-riac", "seed": 0},
                               micro_actions=200, window=200, out=lines.append, new_overrides={"seed": 1})
    assert not res["identical"] and lines[-1].count("bit-identical: NO") == 1


def test_eval_cost_against_a_commit_gives_the_same_errors(capsys):
    assert repo_root() == SRC.parent
    rows = eval_cost.compare_base("HEAD", ["arm7_ratio15"], "sagg-riac", 300, 0, 1)
    assert rows[0]["same"] and rows[0]["new"]["after"] > 0
    assert "| arm7_ratio15 |" in capsys.readouterr().out


def test_time_parts_prints_learning_and_evaluation_parts(capsys):
    from sagg_low_level import learner, memory_search, reach_batch
    before = (memory_search.KnnSearch._knn_approx, learner.jacobian, reach_batch.neighbours_many)
    assert time_parts.main(["--config", "config/arm7_ratio15.yaml", "--start", "0", "--stop", "600"]) == 0
    out = capsys.readouterr().out
    assert "neighbour search (approximate)" in out and "micro-actions per CPU-s" in out
    assert time_parts.main(["--config", "config/arm7_ratio15.yaml", "--start", "0", "--stop", "300", "--eval"]) == 0
    assert "least squares (one per distinct set)" in capsys.readouterr().out
    # the counters are gone afterwards
    assert (memory_search.KnnSearch._knn_approx, learner.jacobian, reach_batch.neighbours_many) == before


def test_time_parts_prints_the_fixed_context_parts(capsys):
    from sagg_low_level import fixed_context, stored_knn, tree_knn
    before = (stored_knn.StoredKnn.query, tree_knn.TreeKnn._update, fixed_context.least_spread_set)
    assert time_parts.main(["--config", "config/arm7_ratio15.yaml", "--set", "context=fixed",
                            "--start", "300", "--stop", "900"]) == 0
    out = capsys.readouterr().out
    assert "experiments per CPU-s" in out and "us per experiment" in out
    for part in ("θ searches", "outcome searches", "least-spread set", "local inverse", "the experiment"):
        row = next(line for line in out.splitlines() if line.startswith(f"| {part}"))
        assert int(row.rsplit("|", 2)[1]) > 0   # called and counted
    assert (stored_knn.StoredKnn.query, tree_knn.TreeKnn._update, fixed_context.least_spread_set) == before
    with pytest.raises(SystemExit):  # the evaluation's parts are the evolving arm's only
        time_parts.main(["--config", "config/arm7_ratio15.yaml", "--set", "context=fixed", "--eval"])


def test_floors_times_every_part_alone(capsys):
    from sagg_lab import floors
    assert floors.main(["--config", "config/arm7_ratio15.yaml", "--micro-actions", "300", "--repeat", "20"]) == 0
    out = capsys.readouterr().out
    for part in ("forward kinematics", "neighbour search", "least-squares Jacobian", "reaching step",
                 "coroutine request/answer", "region tree point", "memory add"):
        assert part in out
    assert "| 0.00 |" not in out.split("coroutine")[0]   # every numeric part took measurable time
    assert floors.main(["--config", "config/arm7_ratio15.yaml", "--set", "context=fixed", "--micro-actions", "300",
                        "--repeat", "10"]) == 0
    out = capsys.readouterr().out
    for part in ("experiment", "outcome search", "θ searches", "least-spread set", "local inverse", "goal choice"):
        assert part in out


def test_equivalence_tells_equal_runs_from_shifted_ones(tmp_path):
    import json
    from sagg_lab import equivalence

    def write(root, shift):
        for cell in ("evolving/config/sagg-riac", "fixed/wide/sagg-random"):
            for seed in range(6):
                d = tmp_path / root / cell / f"seed-{seed}"
                d.mkdir(parents=True)
                errs = [1.0, 0.1 + 0.01 * seed, 0.05 + 0.01 * seed + shift]
                (d / "result.json").write_text(json.dumps({"curve": [
                    {"micro_actions": x, "mean_error": e} for x, e in zip((0, 5000, 20000), errs)]}))

    write("a", 0.0)
    write("b", 0.0)
    write("c", 1.0)
    same = equivalence.compare_dirs(tmp_path / "a", tmp_path / "b")
    assert len(same) == 4 and all(r["identical"] and r["within"] for r in same)
    shifted = {(r["cell"], r["point"]): r for r in equivalence.compare_dirs(tmp_path / "a", tmp_path / "c")}
    assert shifted[("fixed/wide/sagg-random", 20000)]["mannwhitney_p"] < 0.01
    assert not shifted[("fixed/wide/sagg-random", 20000)]["within"]
    assert shifted[("fixed/wide/sagg-random", 5000)]["identical"]
    assert "with a two-sided Mann-Whitney p <= 0.2" in equivalence.table(list(shifted.values()), 0.2)
