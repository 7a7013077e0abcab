"""The model server: a finished run's model serving /sagg/compute_ik, started on a run directory as
`ros2 run sagg_low_level model_server --ros-args -p run:=DIR` does and by `sagg serve BAG` (the model
rebuilt from the bag), each called from this separate client process; bad requests answered with a
clear error. One short run, one server process of each kind, several requests each."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from sagg_bringup.graph.processes import pick_domain_id
from installed import SAGG, executable

ROOT = Path(__file__).resolve().parents[1]
TARGET = [30.0, 10.0]
BAD = [([30.0], "target at [30.0]: allowed: 2 finite values"),                 # wrong dimension
       ([float("nan"), 10.0], "target at [nan, 10.0]: allowed: 2 finite values"),  # NaN
       ([1e9, 0.0], "within task_space")]                                      # outside Y


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("model") / "run"
    subprocess.run([SAGG, "run", "config/arm8.yaml", "--micro-actions", "600", "--eval-every", "600",
                    "--out", str(out), "--quiet", "--no-report"], cwd=ROOT, check=True, capture_output=True,
                   timeout=300)
    return out


def start(cmd: list[str], domain: int, log: Path) -> subprocess.Popen:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=open(log, "wb"), stderr=subprocess.STDOUT,
                            start_new_session=True)


def stop(proc: subprocess.Popen) -> int:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            return proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode


def ask(domain: int) -> dict:
    """The answer to TARGET, the bad requests' answers and the latencies, from this process."""
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    from sagg_bringup.graph.reach_client import OwnReachClient
    client = OwnReachClient(domain)
    try:
        client.wait_for_ik(120.0)
        good, seconds = client.compute_ik(TARGET)
        bad = [client.compute_ik(t)[0] for t, _ in BAD]
        times = [client.compute_ik(TARGET)[1] for _ in range(5)]
    finally:
        client.close()
    return {"good": good, "bad": bad, "seconds": [seconds] + times}


def check_answers(a: dict) -> None:
    good = a["good"]
    assert good.outcome in ("reached", "budget"), good.message
    assert len(good.joints) == len(good.joint_names) == 8 and np.all(np.abs(good.joints) <= np.pi / 2 + 1e-9)
    assert np.isfinite(good.nearest_sample) and good.nearest_sample >= 0.0 and len(good.predicted) == 2
    for resp, (_, words) in zip(a["bad"], BAD):
        assert not resp.success and resp.outcome == "invalid" and words in resp.message, resp.message
        assert len(resp.joints) == 0
    assert np.median(a["seconds"]) < 1.0, a["seconds"]


def test_model_server_on_a_run_directory_and_sagg_serve_on_its_bag(run, tmp_path):
    domain = pick_domain_id()
    log = tmp_path / "model_server.log"
    server = start([executable("model_server"), "--ros-args", "-p", f"run:={run}"], domain, log)
    try:
        from_dir = ask(domain)
    finally:
        code = stop(server)
    text = log.read_text()
    assert code == 0, text[-2000:]
    check_answers(from_dir)
    assert "600 samples from the learner checkpoint" in text and "rest point [" in text
    assert "rejected input [compute_ik.invalid] /sagg/compute_ik: target at [30.0]" in text  # logged, counted

    # sagg serve on the bag alone: the model rebuilt from it, the rest point from its reports
    domain = pick_domain_id()
    log = tmp_path / "serve.log"
    serve = start([SAGG, "serve", str(run / "bag"), "--out", str(tmp_path / "served"), "--domain-id", str(domain)],
                  domain, log)
    try:
        t_end = time.monotonic() + 120
        while "ready" not in log.read_text() and time.monotonic() < t_end and serve.poll() is None:
            time.sleep(0.2)
        from_bag = ask(domain)
    finally:
        code = stop(serve)
    text = log.read_text()
    assert code == 0, text[-2000:]
    assert "model: rebuilt from" in text and "rest point: the start of the first goal's attempt" in text
    check_answers(from_bag)
    # the same samples and rest point: the same answer, bit for bit
    assert list(from_bag["good"].joints) == list(from_dir["good"].joints)
    model = json.loads((tmp_path / "served" / "model.json").read_text())
    assert model["rest_point"] == json.loads((run / "checkpoint" / "model.json").read_text())["rest_point"]


def test_model_server_without_a_model_says_why(tmp_path):
    p = subprocess.run([executable("model_server"), "--ros-args", "-p", f"run:={tmp_path}"], cwd=ROOT,
                       capture_output=True, text=True, timeout=60,
                       env=dict(os.environ, ROS_DOMAIN_ID=str(pick_domain_id())))
    assert p.returncode == 2 and "parameter 'run'" in p.stderr + p.stdout and "params.yaml" in p.stderr + p.stdout
