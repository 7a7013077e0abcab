"""Use what was learned. The learner's /sagg/reach action (sagg_msgs/action/Reach)
and `sagg reach RUN_DIR`: a goal of Y reached with the frozen model through the graph, under the
rules of learning; during learning, learning pauses for it and goes on afterwards, nothing of the
reach stored."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np

from sagg_bringup.graph.processes import pick_domain_id
from installed import SAGG

ROOT = Path(__file__).resolve().parents[1]


def test_reach_during_learning_pauses_it_and_stores_nothing(tmp_path):
    from sagg_bringup.graph.reach_client import OwnReachClient
    domain = pick_domain_id()
    out = tmp_path / "run"
    # the reach goes out at the first status (every 0.5 s) past 400 micro-actions; n leaves that
    # status time to come before learning ends even at ~2,500 micro-actions/s (at n = 1,500 a
    # fast run once ended first)
    n = 3000
    proc = subprocess.Popen([SAGG, "run", "config/arm8.yaml", "--micro-actions", str(n), "--eval-every", str(n),
                             "--out", str(out), "--domain-id", str(domain), "--quiet", "--no-report"], cwd=ROOT,
                            env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    client = OwnReachClient(domain)
    try:
        from sagg_msgs.msg import LearnerStatus
        status = []
        client.node.create_subscription(LearnerStatus, "/sagg/status", status.append, 10)
        client.wait_for_server(120.0)
        t_end = time.monotonic() + 120
        while not (status and status[-1].micro_actions >= 400) and time.monotonic() < t_end:
            client.ex.spin_once(timeout_sec=0.1)
        before = status[-1].micro_actions
        r = client.reach([30.0, 10.0], 600.0)                    # inside Y, reachable, from where the arm is
        assert r["outcome"] in ("reached", "budget") and np.isfinite(r["error"]) and r["steps"] >= 1
        # (from where learning left the arm the model may know nothing: no bound on that error. From
        # rest it is bounded: in-process, arm8's model reaches this goal from rest within 0.9 at every
        # 50th micro-action from 400 to 1,500; the pause lands within one status period of 400,
        # below 1,500 at the graph's ~1,000-2,000 micro-actions/s)
        r = client.reach([30.0, 10.0], 600.0, from_rest=True)
        assert r["outcome"] in ("reached", "budget") and r["error"] < 5.0, r
        assert len(r["joints"]) == 8                                # the measured final joints
        # /sagg/compute_ik while it learns: the model as it is now, nothing moves; a bad request says why
        ik, _ = client.compute_ik([30.0, 10.0])
        assert ik.outcome in ("reached", "budget") and len(ik.joints) == 8 and ik.nearest_sample >= 0.0, ik.message
        ik, _ = client.compute_ik([30.0, 10.0], start=[0.0] * 3)
        assert not ik.success and ik.outcome == "invalid" and ik.message.startswith("start [0.0, 0.0, 0.0]: allowed")
        bad = client.client.send_goal_async(client.Reach.Goal(target=[1e9, 0.0]))
        client.wait_until(bad.done, 30.0, "no answer")
        assert not bad.result().accepted                            # outside Y: rejected
        huge = client.client.send_goal_async(client.Reach.Goal(target=[30.0, 10.0], max_steps=4_000_000_000))
        client.wait_until(huge.done, 30.0, "no answer")
        assert not huge.result().accepted                           # a budget beyond the limit: rejected
        # learning paused by /sagg/pause: a reach asked for meanwhile is a request of its own and
        # runs (the evaluation on the robot pauses learning, then reaches its goals); a second one is
        # refused while it does; then learning resumes
        from std_srvs.srv import SetBool
        pause = client.node.create_client(SetBool, "/sagg/pause")
        call = pause.call_async(SetBool.Request(data=True))
        client.wait_until(call.done, 30.0, "no answer to /sagg/pause")
        first = client.client.send_goal_async(client.Reach.Goal(target=[20.0, -10.0]))
        client.wait_until(first.done, 30.0, "no answer")
        held = first.result()
        assert held.accepted
        second = client.client.send_goal_async(client.Reach.Goal(target=[25.0, 0.0]))
        client.wait_until(second.done, 30.0, "no answer")
        assert not second.result().accepted                         # one reach at a time
        res = held.get_result_async()
        client.wait_until(res.done, 60.0, "a reach asked for during a pause never answered")
        assert res.result().result.outcome in ("reached", "budget") and res.result().result.steps > 0
        call = pause.call_async(SetBool.Request(data=False))
        client.wait_until(call.done, 30.0, "no answer to /sagg/pause")
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        client.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, stderr[-2000:]
    s = json.loads((out / "summary.json").read_text())
    # learning went on to its budget; the reach's steps were not micro-actions and stored nothing
    assert s["micro_actions"] == n == s["memory"]["samples"] and before < n
    log = (out / "logs" / "learner.log").read_text()
    assert "reach of [30.0, 10.0]" in log and "reach hold released" in log
    assert "rejected input [reach.invalid]" in log and "rejected input [reach.busy]" in log
    assert "rejected input [compute_ik.invalid]" in log
    assert "reach of [20.0, -10.0]: " in log and "paused by the /sagg/pause service" in log


def test_sagg_reach_of_a_finished_run_from_rest(tmp_path):
    # (a run of its own: lockstep, never paused, so its model and the bound below are the same every
    # time; a run paused for reaches takes another path after each)
    run = tmp_path / "run"
    subprocess.run([SAGG, "run", "config/arm8.yaml", "--micro-actions", "600", "--eval-every", "600",
                    "--out", str(run), "--quiet", "--no-report"],
                   cwd=ROOT, check=True, capture_output=True, timeout=300)
    p = subprocess.run([SAGG, "reach", str(run), "--test-goals", "4", "--out", str(tmp_path / "reach")],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-2000:] + p.stdout[-2000:]
    res = json.loads((tmp_path / "reach" / "reach.json").read_text())
    s = json.loads((run / "summary.json").read_text())
    assert res["from_rest"] and [g["goal"] for g in res["goals"]] == s["test_goals"][:4]
    assert all(g["outcome"] in ("reached", "budget") for g in res["goals"])
    # the same model reaches the same goals about as well through the graph as offline
    assert res["mean_error"] < 3 * s["final_mean_error"] + 1.0, (res["mean_error"], s["final_mean_error"])
    assert "the run's test error" in p.stdout
    # a goal with the wrong number of coordinates: one clear error
    q = subprocess.run([SAGG, "reach", str(run), "1", "2", "3", "--out", str(tmp_path / "r2")], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert q.returncode == 2 and "3 coordinates; allowed: 2" in q.stderr
