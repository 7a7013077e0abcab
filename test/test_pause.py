"""A pause never ends a run: `sagg run --stall-timeout 4` with the learner paused by /sagg/pause for
three times that long is still running and completes once released, whatever else holds during the
pause; a hold that is not a pause (a second source on /joint_states, in test_sources) still ends a
run after the stall timeout."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import SetBool

from sagg_bringup.graph.processes import pick_domain_id
from sagg_bringup.graph.run_state import RunState
from sagg_low_level.holds import PAUSED_BY_SERVICE
from sagg_msgs.msg import LearnerStatus
from installed import SAGG

ROOT = Path(__file__).resolve().parents[1]
STALL = 4.0


def test_a_user_pause_is_told_from_a_stall():
    st = RunState()
    st.status = {"paused": True, "pause_reason": PAUSED_BY_SERVICE}
    assert st.paused_by_user()
    # another hold beside the pause (the recorder catching up, a driver restarted meanwhile): still
    # the user's pause, no stall; without the pause the same hold is one
    for other in ("waiting for the recorder (10 of 40 samples acknowledged on /sagg/recorded)",
                  "no valid joint_states for more than 1 s (driver stopped or disconnected?)"):
        st.status = {"paused": True, "pause_reason": f"{other}; {PAUSED_BY_SERVICE}"}
        assert st.paused_by_user()
        st.status = {"paused": True, "pause_reason": other}
        assert not st.paused_by_user()
    st.status = {"paused": False, "pause_reason": ""}
    assert not st.paused_by_user()


def test_a_pause_longer_than_the_stall_timeout_does_not_end_the_run(tmp_path):
    domain = pick_domain_id()
    out = tmp_path / "run"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.Popen([SAGG, "run", str(ROOT / "config/arm8.yaml"), "--micro-actions", "3000",
                             "--eval-every", "3000", "--out", str(out), "--quiet", "--no-report", "--domain-id",
                             str(domain), "--stall-timeout", str(STALL)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("pausing_user", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    status: list = []
    node.create_subscription(LearnerStatus, "/sagg/status", status.append, 10)
    pause = node.create_client(SetBool, "/sagg/pause")

    def call(flag: bool) -> None:
        fut = pause.call_async(SetBool.Request(data=flag))
        end = time.monotonic() + 30
        while not fut.done() and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        assert fut.done() and fut.result().success

    try:
        end = time.monotonic() + 120
        while not (status and status[-1].micro_actions > 100) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.1)  # learning
        assert status and status[-1].micro_actions > 100 and pause.wait_for_service(timeout_sec=30)
        call(True)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 3 * STALL:
            ex.spin_once(timeout_sec=0.1)
            assert proc.poll() is None, (proc.communicate()[1][-2000:],  # paused three stall timeouts: running
                                         sorted({m.pause_reason for m in status}))
        assert status[-1].paused and PAUSED_BY_SERVICE in status[-1].pause_reason
        held_at = status[-1].micro_actions
        call(False)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    assert proc.returncode == 0, stderr[-3000:]
    s = json.loads((out / "summary.json").read_text())
    assert s["micro_actions"] == 3000 > held_at and s["error"] is None
