"""sagg_lab.digests: the digests of a run change with any bit of its samples, goals or
curve, and not with what is not behaviour (timings, summary.json's rebuilt splits)."""
from __future__ import annotations

import json

import numpy as np

from sagg_lab.digests import main, run_digests


def _result(position=(1.0, 2.0), mean=0.5, seconds=3.0, splits=()):
    return {"memory": {"samples": 10, "digest": "abc"}, "learn_seconds": seconds, "splits": list(splits),
            "goals": [{"seq": 1, "position": list(position), "mode": 1, "competence": -0.25}],
            "curve": [{"micro_actions": 10, "mean_error": mean, "median_error": 0.25}]}


def _digests(tmp_path, name, result):
    (tmp_path / name).mkdir()
    (tmp_path / name / "result.json").write_text(json.dumps(result))
    return run_digests(tmp_path / name)


def test_digests_see_every_bit_and_ignore_timing(tmp_path):
    base = _digests(tmp_path, "a", _result())
    assert base["samples"] == 10 and base["memory"] == "abc" and base["final_mean_error"] == 0.5
    same = _digests(tmp_path, "b", _result(seconds=9.0, splits=[{"region": 0}]))
    assert {k: v for k, v in same.items() if k != "file"} == {k: v for k, v in base.items() if k != "file"}
    one_ulp = float(np.nextafter(2.0, 3.0))
    moved = _digests(tmp_path, "c", _result(position=(1.0, one_ulp)))
    assert moved["goals_sha"] != base["goals_sha"] and moved["curve_sha"] == base["curve_sha"]
    curve = _digests(tmp_path, "d", _result(mean=float(np.nextafter(0.5, 1.0))))
    assert curve["curve_sha"] != base["curve_sha"] and curve["goals_sha"] == base["goals_sha"]


def test_generator_checkpoint_state_is_digested(tmp_path, capsys):
    run = tmp_path / "run"
    (run / "checkpoint").mkdir(parents=True)
    (run / "summary.json").write_text(json.dumps(_result()))
    (run / "checkpoint" / "generator.json").write_text(json.dumps({"state_file": "generator_state_1.npz"}))
    np.savez(run / "checkpoint" / "generator_state_1.npz", split_value=np.array([0.5, 1.5]))
    first = run_digests(run)["generator_state_sha"]
    np.savez(run / "checkpoint" / "generator_state_1.npz", split_value=np.array([1.5, 0.5]))
    assert run_digests(run)["generator_state_sha"] != first
    assert main([str(run)]) == 0 and "generator_state_sha" in capsys.readouterr().out
