"""Bare rclpy topic ping-pong between two processes: the transport's round-trip floor.

The graph's cost per micro-action is compared with this: one lockstep micro-action is at least one
topic round trip (command out, observation back). :func:`measure` starts an echo process and a ping
process (both ``python -m sagg_lab.pingpong``) on a private ``ROS_DOMAIN_ID`` and returns the
ping side's result. The message is the learner's command type (std_msgs/Float64MultiArray with
``size`` doubles), echoed back on a second topic; reliable QoS, depth 10, as in the graph.

``--pattern lockstep`` is the hardware contract's exchange with no work on either side: the ping
side publishes a command (Float64MultiArray, ``size`` doubles) and waits for both answers, a
sensor_msgs/JointState (``size`` named joints, positions and velocities) and a
geometry_msgs/PointStamped, which the echo side publishes, prebuilt, on every command. It is the
floor of any lockstep graph that speaks the contract: three messages per micro-action where a
round trip has two. With ``--work-us W`` the echo side also computes for W µs (a busy loop) before
it answers each command: zero-overhead nodes doing a given amount of work per micro-action.

    python -m sagg_lab.pingpong --count 3000 --executor events
    python -m sagg_lab.pingpong --count 3000 --pattern lockstep --raw
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time

from sagg_common.ros_params import make_executor

from sagg_bringup.graph.processes import pick_domain_id

PING, PONG = "/sagg_pingpong/ping", "/sagg_pingpong/pong"
JS, TIP = "/sagg_pingpong/joint_states", "/sagg_pingpong/tip"
PATTERNS = ("pingpong", "lockstep")


def _answers(size: int, raw: bool):
    """The lockstep pattern's prebuilt answers: a JointState of ``size`` joints and a PointStamped
    (serialized when ``raw``)."""
    # lazy (heavy): ROS
    from geometry_msgs.msg import PointStamped
    from sensor_msgs.msg import JointState

    js = JointState()
    js.name = [f"joint_{i}" for i in range(size)]
    js.position = [0.1] * size
    js.velocity = [0.0] * size
    tip = PointStamped()
    tip.point.x = 1.0
    if raw:
        # lazy (heavy): ROS
        from rclpy.serialization import serialize_message

        return serialize_message(js), serialize_message(tip)
    return js, tip


def _busy(seconds: float) -> None:
    """Compute (spin on the clock) for ``seconds``: stands for the simulator's and learner's work."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def _echo(executor_kind: str, raw: bool = False, pattern: str = "pingpong", size: int = 8,
          work: float = 0.0) -> None:
    # lazy (heavy): ROS
    import rclpy
    from geometry_msgs.msg import PointStamped
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray


    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = Node("sagg_pingpong_echo")
    if pattern == "lockstep":
        js_pub = node.create_publisher(JointState, JS, 10)
        tip_pub = node.create_publisher(PointStamped, TIP, 10)
        js, tip = _answers(size, raw)

        def on_command(_):
            if work > 0.0:
                _busy(work)
            js_pub.publish(js)
            tip_pub.publish(tip)

        node.create_subscription(Float64MultiArray, PING, on_command, 10, raw=raw)
    else:
        pub = node.create_publisher(Float64MultiArray, PONG, 10)
        node.create_subscription(Float64MultiArray, PING, pub.publish, 10, raw=raw)
    stop = []
    signal.signal(signal.SIGINT, lambda *a: stop.append(1))
    signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
    ex = make_executor(executor_kind)
    ex.add_node(node)
    while not stop and rclpy.ok():
        ex.spin_once(timeout_sec=0.1)
    node.destroy_node()
    rclpy.shutdown()


def _ping(executor_kind: str, count: int, warmup: int, size: int, timeout: float, raw: bool = False,
          pattern: str = "pingpong") -> dict:
    # lazy (heavy): ROS
    import rclpy
    from geometry_msgs.msg import PointStamped
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray


    rclpy.init(signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    node = Node("sagg_pingpong_ping")
    pub = node.create_publisher(Float64MultiArray, PING, 10)
    state = {"received": 0}
    msg = Float64MultiArray()
    msg.data = [0.0] * size
    if raw:
        # lazy (heavy): ROS
        from rclpy.serialization import serialize_message

        msg = serialize_message(msg)

    def on_pong(_):
        state["received"] += 1
        pub.publish(msg)

    if pattern == "lockstep":  # the next command once both answers to the last one are in
        got = {"js": False, "tip": False}

        def answer(key):
            def on_answer(_):
                got[key] = True
                if got["js"] and got["tip"]:
                    got["js"] = got["tip"] = False
                    on_pong(None)
            return on_answer

        node.create_subscription(JointState, JS, answer("js"), 10, raw=raw)
        node.create_subscription(PointStamped, TIP, answer("tip"), 10, raw=raw)
        answer_topics = (JS, TIP)
    else:
        node.create_subscription(Float64MultiArray, PONG, on_pong, 10, raw=raw)
        answer_topics = (PONG,)
    ex = make_executor(executor_kind)
    ex.add_node(node)
    deadline = time.monotonic() + timeout
    # wait until the echo's subscription and publishers are matched both ways
    while ((pub.get_subscription_count() < 1 or any(node.count_publishers(t) < 1 for t in answer_topics))
           and time.monotonic() < deadline):
        ex.spin_once(timeout_sec=0.05)
    time.sleep(0.3)  # let the echo side match our subscription too
    t0 = None
    pub.publish(msg)
    while state["received"] < warmup + count and time.monotonic() < deadline:
        if t0 is None and state["received"] >= warmup:
            t0 = time.perf_counter()
            n0 = state["received"]
        ex.spin_once(timeout_sec=0.5)
    done = state["received"] - (n0 if t0 is not None else 0)
    elapsed = time.perf_counter() - t0 if t0 is not None else float("nan")
    node.destroy_node()
    rclpy.shutdown()
    ok = t0 is not None and done >= count
    return {"executor": executor_kind, "raw": raw, "pattern": pattern, "round_trips": done, "seconds": elapsed,
            "rate": done / elapsed if ok else float("nan"),
            "rtt_ms": 1000.0 * elapsed / done if ok and done else float("nan"), "complete": ok}


def measure(count: int = 3000, warmup: int = 300, executor: str = "events", size: int = 8,
            timeout: float = 120.0, domain_id: int | None = None, raw: bool = False,
            pattern: str = "pingpong", work: float = 0.0) -> dict:
    """Round trips per second between two fresh processes. Returns ``{"rate", "rtt_ms", ...}``.
    ``raw``: both sides exchange serialized bytes (no message conversion in Python).
    ``pattern``: ``pingpong`` (one message each way) or ``lockstep`` (a command out, a joint
    state and a task point back: the hardware contract's exchange with no work).
    ``work``: seconds the echo side computes before answering each command (lockstep only)."""
    if pattern not in PATTERNS:
        raise ValueError(f"pattern: got {pattern!r}; allowed: {', '.join(PATTERNS)}")
    if not (0.0 <= work <= 1.0) or (work and pattern != "lockstep"):
        raise ValueError(f"work: got {work!r} s; allowed: 0 to 1 s, with pattern 'lockstep' only")
    env = dict(os.environ)
    if domain_id is None:

        domain_id = pick_domain_id()
    env["ROS_DOMAIN_ID"] = str(domain_id)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    cmd = ([sys.executable, "-m", "sagg_lab.pingpong", "--executor", executor, "--pattern", pattern,
            "--size", str(size), "--work-us", repr(work * 1e6)] + (["--raw"] if raw else []))
    echo = subprocess.Popen(cmd + ["--echo"], env=env)
    try:
        out = subprocess.run(cmd + ["--ping", "--count", str(count), "--warmup", str(warmup),
                                    "--timeout", str(timeout)],
                             env=env, capture_output=True, text=True, timeout=timeout + 30)
    finally:
        stop_process(echo)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if out.returncode != 0 or not lines:
        raise RuntimeError(f"pingpong failed (exit {out.returncode}): {out.stderr[-500:]}")
    return json.loads(lines[-1])


def stop_process(proc: subprocess.Popen, grace: float = 5.0) -> int | None:
    """SIGINT, then SIGKILL after ``grace`` seconds. Returns the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(grace)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--echo", action="store_true", help="run the echo side (internal)")
    ap.add_argument("--executor", choices=["events", "single"], default="events")
    ap.add_argument("--count", type=int, default=3000)
    ap.add_argument("--warmup", type=int, default=300)
    ap.add_argument("--size", type=int, default=8, help="doubles per message")
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--ping", action="store_true", help="run the ping side only (internal)")
    ap.add_argument("--raw", action="store_true", help="exchange serialized bytes (raw subscriptions)")
    ap.add_argument("--pattern", choices=PATTERNS, default="pingpong",
                    help="pingpong: one message each way; lockstep: a command out, a joint state and a "
                         "task point back (the hardware contract with no work)")
    ap.add_argument("--work-us", type=float, default=0.0,
                    help="lockstep: microseconds the echo side computes before answering each command")
    a = ap.parse_args(argv)
    if a.echo:
        _echo(a.executor, a.raw, a.pattern, a.size, a.work_us * 1e-6)
        return 0
    if a.ping:
        print(json.dumps(_ping(a.executor, a.count, a.warmup, a.size, a.timeout, a.raw, a.pattern)))
        return 0
    res = measure(a.count, a.warmup, a.executor, a.size, a.timeout, raw=a.raw, pattern=a.pattern,
                  work=a.work_us * 1e-6)
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
