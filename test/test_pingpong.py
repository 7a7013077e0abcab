"""The transport baselines of `sagg bench graph`: the bare ping-pong and the contract's lockstep
exchange (command out, joint state and task point back), each between two real processes."""
import math

import pytest

from sagg_lab.pingpong import measure


@pytest.mark.parametrize("pattern,raw", [("pingpong", False), ("lockstep", True), ("lockstep", False)])
def test_exchange_completes_between_two_processes(pattern, raw):
    res = measure(count=200, warmup=20, pattern=pattern, raw=raw, timeout=60.0)
    assert res["pattern"] == pattern and res["raw"] is raw
    assert res["complete"] and res["round_trips"] >= 200
    assert math.isfinite(res["rtt_ms"]) and res["rtt_ms"] > 0.0
    assert res["rate"] == pytest.approx(1000.0 / res["rtt_ms"])


def test_unknown_pattern_is_refused_by_name():
    with pytest.raises(ValueError, match=r"pattern: got 'ring'; allowed: pingpong, lockstep"):
        measure(pattern="ring")


def test_bench_graph_reports_all_four_measurements_and_their_ratios():
    from pathlib import Path

    from sagg_lab.bench import bench_graph

    lines = []
    res = bench_graph(Path(__file__).resolve().parents[1] / "config/arm8.yaml", micro_actions=300, repeats=1,
                      pingpong_count=200, out=lines.append)
    for key in ("graph_rate", "inprocess_rate", "roundtrip_s", "floor_s"):
        assert math.isfinite(res[key]) and res[key] > 0.0, key
    assert res["added_s"] == pytest.approx(1 / res["graph_rate"] - 1 / res["inprocess_rate"])
    assert res["ratio"] == pytest.approx(res["added_s"] / res["roundtrip_s"])
    assert res["floor_ratio"] == pytest.approx(res["floor_s"] / res["roundtrip_s"])
    assert res["nodes_s"] == pytest.approx(res["added_s"] - res["floor_s"])
    assert math.isfinite(res["ideal_added_s"]) and res["ideal_ratio"] == pytest.approx(
        res["ideal_added_s"] / res["roundtrip_s"])
    assert any(f"{res['ratio']:.2f} x the round trip" in s for s in lines)
    assert any("contract floor" in s and f"{res['floor_ratio']:.2f} x the round trip" in s for s in lines)
    assert any("ideal nodes" in s and f"{res['ideal_ratio']:.2f} x the round trip" in s for s in lines)


def test_lockstep_work_is_done_before_each_answer():
    # 2 ms of work per command: an exchange cannot take less
    res = measure(count=100, warmup=10, pattern="lockstep", raw=True, work=0.002, timeout=60.0)
    assert res["complete"] and res["rtt_ms"] >= 2.0
    with pytest.raises(ValueError, match=r"work: got 0.5 s; allowed: 0 to 1 s, with pattern 'lockstep' only"):
        measure(pattern="pingpong", work=0.5)


def test_domain_in_use_sees_a_real_participant_and_pick_avoids_busy_domains(monkeypatch):
    import os
    import socket
    import subprocess
    import sys
    import time

    from sagg_bringup.graph.processes import domain_in_use, pick_domain_id
    from sagg_lab.pingpong import stop_process

    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    # a real DDS participant (an rclpy node in another process) makes its domain busy
    d = pick_domain_id()
    env = dict(os.environ, ROS_DOMAIN_ID=str(d), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.Popen([sys.executable, "-c", "import rclpy, time; rclpy.init(); "
                             "n = rclpy.create_node('sagg_domain_probe'); print('up', flush=True); time.sleep(60)"],
                            env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "up"
        deadline = time.monotonic() + 10
        while not domain_in_use(d) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert domain_in_use(d)
    finally:
        stop_process(proc)
    # with every domain but one busy, the pick is that one
    free = next(x for x in range(1, 201) if x != d and not domain_in_use(x))
    held = []
    try:
        for x in range(1, 201):
            if x != free:
                s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                try:
                    s.bind(("0.0.0.0", 7410 + 250 * x))
                except OSError:
                    s.close()  # already busy: fine
                    continue
                held.append(s)
        assert all(pick_domain_id() == free for _ in range(5))
    finally:
        for s in held:
            s.close()
