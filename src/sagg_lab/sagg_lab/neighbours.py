"""``python -m sagg_lab.neighbours``: ``sagg run`` beside the ordinary neighbours of a real
ROS graph, paired with the same run without them, in one command.

A neighbour here is a gripper driver that publishes only its own joint on ``/joint_states``
(``sensor_msgs/JointState`` named ``gripper_finger``, 20 Hz, reliable), alive from the nodes' start,
optionally with idle publishers (sending nothing) on every topic the graph watches. The runs of a
pair differ only in the neighbours (same config, seed, timing, budget, each on its own private
ROS domain); the order alternates from pair to pair (ABBA), so a drift of the machine's speed
weighs on both. Printed: per run the exit code, micro-actions per second and the test error
curve; per pair the rate with the neighbours as a share of the rate without (the target is
>= 0.9: they must not slow learning). Written: ``OUT/neighbours.json``.

    python -m sagg_lab.neighbours --config config/arm8.yaml --timing realtime \\
        --micro-actions 1500 --pairs 1 --out runs/neighbours
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

from sagg_common.params import parse_set
from sagg_common.ros_params import reliable

from sagg_bringup.inprocess.arm_params import graph_params, load_graph_config

from sagg_bringup.graph.processes import find_node_executable, pick_domain_id
from sagg_bringup.bags.recorder import TopicSpec, msg_class
from sagg_bringup.bags.topics import watched_topics

GRIPPER_RATE = 20.0  # Hz: an ordinary gripper driver's joint-state rate


class Neighbours:
    """A gripper driver (and publishers that send nothing on the ``idle`` topics) on ``domain``,
    published from a thread of this process until :meth:`stop`."""

    def __init__(self, domain: int, idle: list[TopicSpec] = ()):
        # lazy (heavy): ROS
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from sensor_msgs.msg import JointState

        self.rclpy, self.ctx = rclpy, Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("gripper_driver", context=self.ctx)
        self.pub = self.node.create_publisher(JointState, "/joint_states", reliable(10))
        self.idle = [self.node.create_publisher(msg_class(t.msgtype), t.name, reliable(10, t.transient_local))
                     for t in idle]
        self.sent = 0
        self._msg = JointState
        self.node.create_timer(1.0 / GRIPPER_RATE, self._tick)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _tick(self) -> None:
        m = self._msg()
        m.header.stamp = self.node.get_clock().now().to_msg()
        m.name = ["gripper_finger"]
        m.position = [0.002 * (self.sent % 20)]
        m.velocity = [0.0]
        self.pub.publish(m)
        self.sent += 1

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.ex.spin_once(timeout_sec=0.05)

    def stop(self) -> None:
        self._stop.set()
        self.thread.join(timeout=5.0)
        self.ex.shutdown()
        self.node.destroy_node()
        self.rclpy.shutdown(context=self.ctx)


def one_run(config: str, out: Path, timing: str, micro_actions: int, eval_every: int, neighbours: bool,
            idle: bool, sets: list[str]) -> dict:
    """One ``sagg run`` (with or without the neighbours); its summary's key numbers."""
    domain = pick_domain_id()
    cmd = [str(find_node_executable("sagg_bringup", "sagg")), "run", config, "--timing", timing, "--micro-actions",
           str(micro_actions), "--eval-every", str(eval_every), "--out", str(out), "--domain-id", str(domain),
           "--quiet"] + [a for s in sets for a in ("--set", s)]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    lp = graph_params(load_graph_config(config, parse_set(sets)), 1, timing)["sagg_learner"]
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    nb = None
    try:
        if neighbours:
            # a simulated run refuses a domain where another node publishes /joint_states (it may be
            # a robot's driver): the neighbours join once the run has checked its domain and created
            # its bag, before its nodes start
            while not (out / "bag").exists() and proc.poll() is None:
                time.sleep(0.05)
            nb = Neighbours(domain, watched_topics(lp) if idle else ())
        _, stderr = proc.communicate()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        sent = nb.sent if nb is not None else 0
        if nb is not None:
            nb.stop()
    row = {"neighbours": neighbours, "idle_publishers": idle and neighbours, "exit_code": proc.returncode,
           "wall_seconds": round(time.monotonic() - t0, 1), "gripper_messages": sent, "out": str(out)}
    summary = out / "summary.json"
    if summary.is_file():
        s = json.loads(summary.read_text())
        row.update(micro_actions=s["micro_actions"], rate=s["micro_actions_per_second"],
                   curve=[(c["micro_actions"], round(c["mean_error"], 3)) for c in s["curve"]],
                   error=s.get("error"))
    if proc.returncode:
        row["stderr"] = stderr[-1500:]
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="config/arm8.yaml")
    ap.add_argument("--timing", choices=["lockstep", "realtime"], default="realtime")
    ap.add_argument("--micro-actions", type=int, default=1500)
    ap.add_argument("--eval-every", type=int, default=500)
    ap.add_argument("--pairs", type=int, default=1)
    ap.add_argument("--idle", action="store_true", help="also idle publishers on every watched topic")
    ap.add_argument("--out", default=f"runs/neighbours-{time.strftime('%Y%m%d-%H%M%S')}")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, pairs = [], []
    for k in range(a.pairs):
        order = (False, True) if k % 2 == 0 else (True, False)
        pair = {}
        for nb in order:
            name = f"pair{k}-{'with' if nb else 'without'}"
            row = one_run(a.config, out / name, a.timing, a.micro_actions, a.eval_every, nb, a.idle, a.set)
            rows.append(row)
            pair[nb] = row
            print(f"{name}: exit {row['exit_code']}, {row.get('micro_actions')} micro-actions at "
                  f"{row.get('rate', float('nan')):.2f}/s, errors {row.get('curve')}, "
                  f"{row['gripper_messages']} gripper messages", flush=True)
        share = pair[True].get("rate", float("nan")) / pair[False].get("rate", float("nan"))
        pairs.append(round(share, 3))
        print(f"pair {k}: rate with the neighbours / without = {share:.3f} (target >= 0.9)", flush=True)
    doc = {"config": a.config, "timing": a.timing, "micro_actions": a.micro_actions, "idle": a.idle,
           "runs": rows, "rate_shares": pairs, "load_at_end": os.getloadavg()}
    (out / "neighbours.json").write_text(json.dumps(doc, indent=1))
    ok = all(r["exit_code"] == 0 for r in rows) and all(s >= 0.9 for s in pairs)
    print(f"{'OK' if ok else 'NOT OK'}: shares {pairs} -> {out / 'neighbours.json'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
