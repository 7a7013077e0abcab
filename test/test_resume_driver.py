"""A run that learned on a robot is never continued as anything else, and a simulated bridge is never
started where a robot's driver is:

- every `sagg run` writes DIR/run.json (driver, timing, domain, budget, config, overrides) before its
  nodes start, external-driver runs included;
- `sagg run --resume DIR` takes the driver from there: a `--driver external` run is refused (no
  external resume yet), and so is a directory whose settings cannot be read;
- `sagg run` with the simulated bridge refuses a domain where another node publishes /joint_states
  or subscribes to the command topic, naming it.

The driver is test/fake_driver.py (a 250 Hz arm with latency and reading noise): its count of the
commands it received is what proves that nothing reached it."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import time
from pathlib import Path

import pytest

from sagg_bringup.graph.processes import pick_domain_id
from sagg_bringup.graph.run_file import RUN_FILE, read_run_file, write_run_file
from sagg_common.params import ConfigError
from sagg_low_level.checkpoint import published
from installed import SAGG
from test_external_driver import config, env_for, start_driver, stop

ROOT = Path(__file__).resolve().parents[1]


def commands_received(log: Path) -> int:
    """The driver's count of the commands it received (test/fake_driver.py's last line)."""
    m = re.search(r"fake driver: (\d+) commands", log.read_text())
    assert m, log.read_text()[-2000:]
    return int(m.group(1))


# ------------------------------------------------------------------------------ run.json, ROS-free
def test_run_file_round_trip_and_the_refusals_of_resume(tmp_path):
    write_run_file(tmp_path, setup="arm", driver="sim", timing="realtime", domain_id=17, domain_private=True,
                   micro_actions=500, eval_every=100, config="/x/arm8.yaml", overrides={"seed": 3})
    s = read_run_file(tmp_path)
    assert (s["driver"], s["timing"], s["domain_id"], s["micro_actions"], s["overrides"]) == \
        ("sim", "realtime", 17, 500, {"seed": 3})
    assert read_run_file(tmp_path)["eval_every"] == 100

    write_run_file(tmp_path, setup="arm", driver="external", timing="realtime", domain_id=95,
                   domain_private=False, micro_actions=5000, eval_every=1000, config="/x/arm3.yaml", overrides={},
                   robot_eval_goals=4)
    s = read_run_file(tmp_path)
    assert (s["driver"], s["domain_id"], s["domain_private"], s["robot_eval_goals"]) == ("external", 95, False, 4)

    cases = {
        "missing": None,
        "not JSON": "{",
        "not an object": "[1, 2]",
        "no driver": json.dumps({"format": "sagg.run/2", "timing": "lockstep", "micro_actions": 5}),
        "unknown driver": json.dumps({"format": "sagg.run/2", "driver": "robot", "timing": "lockstep",
                                      "micro_actions": 5, "eval_every": 5}),
        "unknown format": json.dumps({"format": "sagg.run/9", "driver": "sim"}),
        "bad budget": json.dumps({"format": "sagg.run/2", "driver": "sim", "timing": "lockstep",
                                  "micro_actions": -1, "eval_every": 5}),
    }
    for what, text in cases.items():
        d = tmp_path / what.replace(" ", "_")
        d.mkdir()
        if text is not None:
            (d / RUN_FILE).write_text(text)
        with pytest.raises(ConfigError, match="--resume") as e:
            read_run_file(d)
        assert "refus" in str(e.value) or "not found" in str(e.value), (what, str(e.value))

    # the first format was written by the simulated-bridge runner only: its driver is known
    old = tmp_path / "old"
    old.mkdir()
    (old / RUN_FILE).write_text(json.dumps({"format": "sagg.run/1", "micro_actions": 300, "eval_every": 100,
                                            "timing": "lockstep"}))
    assert read_run_file(old)["driver"] == "sim"


# ------------------------------------------------------------------------------ through the graph
def test_a_killed_external_driver_run_resumes_on_its_robot(tmp_path):
    """SIGKILL of a whole `sagg run --driver external` mid-run, then `--resume`: it goes on on the
    robot (its driver, its domain) to the full budget, never with the simulated bridge; without the
    driver the resume waits for it and gives up, sending nothing anywhere."""
    domain = pick_domain_id()
    env = env_for(domain)
    cfg = config(tmp_path / "arm3.yaml")
    run = tmp_path / "run"
    driver = start_driver(env, tmp_path / "driver.log")
    log = open(tmp_path / "first.log", "w")
    try:
        p = subprocess.Popen([SAGG, "run", str(cfg), "--driver", "external", "--micro-actions", "5000",
                              "--out", str(run), "--quiet", "--no-report", "--domain-id", str(domain),
                              "--driver-timeout", "60", "--robot-eval-goals", "1"],
                             env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        try:
            end = time.monotonic() + 180
            while ((published(run / "checkpoint") or {}).get("samples") or 0) < 100:  # learning on the robot
                assert p.poll() is None and time.monotonic() < end, (tmp_path / "first.log").read_text()
                time.sleep(0.2)
            settings = json.loads((run / RUN_FILE).read_text())  # written before the nodes started
        finally:
            os.killpg(p.pid, signal.SIGKILL)  # as a crash, an OOM kill or a power cut would
            p.wait(timeout=30)
            log.close()
    finally:
        stop(driver)
    assert settings["driver"] == "external" and settings["domain_id"] == domain
    assert settings["micro_actions"] == 5000 and settings["config"] == str(cfg.resolve())
    assert not (run / "summary.json").exists()
    assert commands_received(tmp_path / "driver.log") > 0  # the run did command the robot

    # no driver on the domain: the resume waits for it (--driver-timeout) and sends nothing
    r = subprocess.run([SAGG, "run", "--resume", str(run), "--micro-actions", "300", "--quiet",
                        "--domain-id", str(domain), "--driver-timeout", "3"],
                       env=env, capture_output=True, text=True, timeout=120)
    # (--driver-timeout given to the resume wins over the run's own 60 s)
    assert r.returncode != 0 and "did not come up in 3 s" in r.stderr, r.stdout + r.stderr
    assert not list((run / "logs").glob("mujoco_bridge*")), sorted(p.name for p in (run / "logs").iterdir())

    # a fresh driver on the same domain, as the robot would still be there; then --resume to 200
    # (the run's own settings: one test goal on the robot at the end)
    driver = start_driver(env, tmp_path / "driver2.log")
    try:
        time.sleep(1.0)  # the driver is up and publishing
        r = subprocess.run([SAGG, "run", "--resume", str(run), "--micro-actions", "200", "--quiet",
                            "--no-report", "--domain-id", str(domain)],
                           env=env, capture_output=True, text=True, timeout=300)
    finally:
        stop(driver)
    assert r.returncode == 0, r.stdout + r.stderr
    summary = json.loads((run / "summary.json").read_text())
    assert summary["micro_actions"] >= 200 and summary["driver"] == "external", summary.get("driver")
    assert len(summary["robot_evaluation"]["goals"]) == 1  # the run's own settings (run.json)
    assert commands_received(tmp_path / "driver2.log") > 0
    assert not list((run / "logs").glob("mujoco_bridge*")), sorted(p.name for p in (run / "logs").iterdir())
    learner_logs = sorted((run / "logs").glob("learner*.log"))
    assert any("resumed from" in f.read_text() for f in learner_logs), [f.name for f in learner_logs]
    assert json.loads((run / RUN_FILE).read_text())["driver"] == "external"


def test_the_simulated_bridge_is_not_started_where_a_driver_publishes(tmp_path):
    """`sagg run` (simulated bridge) on a domain where a robot driver publishes /joint_states and
    subscribes to the command topic: refused before any node starts, the driver named."""
    domain = pick_domain_id()
    env = env_for(domain)
    driver = start_driver(env, tmp_path / "driver.log")
    out = tmp_path / "run"
    try:
        time.sleep(1.0)
        r = subprocess.run([SAGG, "run", str(ROOT / "config/arm8.yaml"), "--micro-actions", "200", "--quiet",
                            "--no-report", "--out", str(out), "--domain-id", str(domain)],
                           env=env, capture_output=True, text=True, timeout=120)
    finally:
        stop(driver)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "fake_arm_driver" in r.stderr and "/joint_states" in r.stderr, r.stderr
    assert "/forward_position_controller/commands" in r.stderr, r.stderr
    assert commands_received(tmp_path / "driver.log") == 0
    assert not list((out / "logs").glob("*.log")) or all(
        f.stat().st_size == 0 for f in (out / "logs").glob("*.log"))  # no node was started
