"""End to end, an arm from its model file (config/arm6_mjcf.yaml: a UR5's kinematics in
MJCF, its tool's (x, y, z) the task point) learns through the three nodes in a 3-D task space, and
everything of the 2-D arms holds in 3-D: the lockstep graph equals the in-process run, goals,
regions and tip points are recorded with three coordinates, `sagg relearn` of the bag rebuilds the
run's memory and tree, the live markers are 3-D boxes and points, `sagg reach` reaches a 3-D goal.
"""
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from sagg_bringup.bags.bags import relearn
from sagg_bringup.graph.setups import run_experiment
from test_run_graph import read_bag
from installed import SAGG

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config/arm6_mjcf.yaml"
N, EVERY = 600, 300


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("model_graph") / "run"
    proc = subprocess.run([SAGG, "run", str(CONFIG), "--micro-actions", str(N), "--eval-every", str(EVERY),
                           "--out", str(out), "--quiet", "--no-report"], capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out, json.loads((out / "summary.json").read_text())


def test_model_arm_graph_equals_in_process_run_in_3d(run):
    out, s = run
    assert s["micro_actions"] == N and s["error"] is None
    r = run_experiment(CONFIG, None, None, N, EVERY, None, progress=False)
    assert s["memory"]["digest"] == r["memory"]["digest"]
    assert s["curve"] == r["curve"]
    assert [g["position"] for g in s["goals"]] == [g["position"] for g in r["goals"]]
    assert len(s["goals"]) >= 3 and all(len(g["position"]) == 3 for g in s["goals"])
    # the tree splits Y in all three dimensions' terms: 3-D leaves
    assert len(s["regions"]) >= 2 and all(len(g["lower"]) == len(g["upper"]) == 3 for g in s["regions"])
    # (the generator's own history, from its last checkpoint: equal whatever the load)
    assert s["splits"] == json.loads(json.dumps(r["splits"])) and len(s["splits"]) >= 1
    # the model arm learns: the test error falls from the empty model's
    assert s["curve"][-1]["mean_error"] < 0.7 * s["curve"][0]["mean_error"], s["curve"]


def test_3d_bag_round_trip_and_relearn(run, tmp_path):
    out, s = run
    types, msgs = read_bag(out / "bag")
    # the bridge publishes the model arm's joints by name and its tool point in 3-D
    js = msgs["/joint_states"][0]
    assert list(js.name) == s["node_params"]["sagg_learner"]["joints"] and len(js.name) == 6
    tips = np.array([[p.point.x, p.point.y, p.point.z] for p in msgs["/tip_position"]])
    assert np.ptp(tips[:, 2]) > 0.01  # the tool moves in z
    goals = msgs["/sagg/goal"]
    assert all(len(g.position) == 3 for g in goals)
    assert [list(g.position) for g in goals] == [g["position"] for g in s["goals"]]
    assert all(len(m.delta_y) == 3 for m in msgs["/sagg/sample"])
    tree = msgs["/sagg/regions"][-1]
    assert all(len(r.lower) == 3 for r in tree.regions)
    # relearning from the bag: the run's memory and region tree, bit for bit
    re = relearn([out / "bag"], tmp_path / "re", out=lambda _: None)
    assert re["memory"]["digest"] == s["memory"]["digest"] and re["memory"]["samples"] == N
    relearned = json.loads((tmp_path / "re" / "regions.json").read_text())
    leaves = relearned["regions"] if isinstance(relearned, dict) else relearned
    assert [g["lower"] for g in leaves] == [g["lower"] for g in s["regions"]]


def test_3d_markers_are_boxes_and_points_in_space(run):
    out, s = run
    from sagg_bringup.graph.markers import marker_arrays_from_bag
    last = marker_arrays_from_bag(out / "bag")[-1]
    boxes = [m for m in last.markers if m.ns == "regions"]
    assert len(boxes) == len(s["regions"])
    for m, g in zip(boxes, s["regions"]):
        lo, hi = np.array(g["lower"]), np.array(g["upper"])
        assert np.allclose([m.scale.x, m.scale.y, m.scale.z], hi - lo)
        assert np.allclose([m.pose.position.x, m.pose.position.y, m.pose.position.z], (lo + hi) / 2)
    edges = next(m for m in last.markers if m.ns == "region_edges")
    assert len(edges.points) == 24 * len(boxes)  # 12 edges of every box
    tg = next(m for m in last.markers if m.ns == "test_goals")
    assert np.allclose([[p.x, p.y, p.z] for p in tg.points], np.array(s["test_goals"])[:len(tg.points)])
    path = next(m for m in last.markers if m.ns == "tip_path")
    assert np.ptp([p.z for p in path.points]) > 0.0


def test_sagg_reach_reaches_a_3d_goal(run, tmp_path):
    out, s = run
    goal = s["test_goals"][0]
    p = subprocess.run([SAGG, "reach", str(out), *map(str, goal), "--out", str(tmp_path / "reach")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:] + p.stdout[-2000:]
    res = json.loads((tmp_path / "reach" / "reach.json").read_text())
    (g,) = res["goals"]
    assert g["goal"] == goal and len(g["reached"]) == 3
    assert g["outcome"] in ("reached", "budget") and np.isfinite(g["error"])
    # the frozen model does about as well through the graph as the run's own evaluation (reached
    # from the learner's posture, not from rest: a loose bound), and far better than not moving
    _, msgs = read_bag(out / "bag")
    rest = msgs["/tip_position"][0].point  # the tool at the rest posture, before the first command
    rest_error = float(np.linalg.norm(np.array(goal) - [rest.x, rest.y, rest.z]))
    assert g["error"] < 0.5 * rest_error, (g, rest_error)


def test_sagg_reach_test_goals_equal_the_offline_evaluation(run, tmp_path):
    """Kinematic arm, lockstep bridge: each test goal reached from rest through the graph
    (/sagg/reach) ends where the run's offline evaluation of the same model ends."""
    out, s = run
    p = subprocess.run([SAGG, "reach", str(out), "--test-goals", "3", "--out", str(tmp_path / "reach")],
                       capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:] + p.stdout[-2000:]
    res = json.loads((tmp_path / "reach" / "reach.json").read_text())
    assert [g["goal"] for g in res["goals"]] == s["test_goals"][:3]
    graph = np.array([g["error"] for g in res["goals"]])
    assert np.allclose(graph, res["offline_errors"], rtol=0, atol=1e-9), (graph, res["offline_errors"])
    assert "the same goals reached offline in simulation" in p.stdout
