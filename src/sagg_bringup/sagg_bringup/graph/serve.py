"""``sagg serve RUN_DIR|BAG [--driver none|sim|external]``: serve what a run learned, until Ctrl-C.

The run's model is prepared as ``sagg reach`` prepares it (:func:`.reach.frozen_model`: its learner
checkpoint, or rebuilt from its bag(s); its rest point) into a model directory ``OUT`` (params.yaml,
memory.npz, model.json), then served on the ROS domain of ``--domain-id`` (default: the
environment's, where your own clients run):

- ``--driver none`` (default): the model server (``sagg_low_level`` / ``model_server``, the same
  node as ``ros2 run sagg_low_level model_server --ros-args -p run:=OUT``): ``/sagg/compute_ik``;
- ``--driver sim``: the learner with the frozen model (``frozen_memory``) and the run's simulated
  bridge: ``/sagg/reach`` and ``/sagg/compute_ik``, the arm simulated;
- ``--driver external``: the learner with the frozen model next to your robot's driver (running):
  ``/sagg/reach`` moves the robot, ``/sagg/compute_ik`` moves nothing.

Learning is off in every case: nothing is stored.
"""
from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

from sagg_common.params import ConfigError, flatten

from ..inprocess.arm_params import NODES
from .params_files import write_params_file
from .processes import GraphError, NodeGroup, check_domain_id, node_processes
from .reach import _env_domain, frozen_model
from .reach_client import OwnReachClient

MODEL_SERVER = ("sagg_low_level", "model_server")
READY_TIMEOUT = 120.0  # s for the served nodes to come up


def model_directory(source: str | Path, out: Path, driver: str, say=print) -> dict[str, dict]:
    """The model directory ``out`` of the run ``source`` (the module docstring) and the nodes'
    parameters written to ``out/params.yaml``: the learner's with its frozen model, never learning."""
    doc, memory = frozen_model(Path(source), out, say)
    params = {name: flatten((body or {}).get("ros__parameters") or {}) for name, body in doc.items()}
    lp = params.setdefault("sagg_learner", {})
    lp.update({"frozen_memory": str(out.resolve()), "max_micro_actions": 0, "min_sample_subscribers": 0})
    lp.pop("checkpoint_dir", None)
    if driver == "external":
        lp["rest_return"] = "stepped"
    keep = {"/**", "sagg_learner"} | ({"sagg_sim_bridge"} if driver == "sim" else set())
    params = {k: v for k, v in params.items() if k in keep}
    write_params_file(out / "params.yaml", params)
    return params


def serve(source: str | Path, out_dir: str | Path | None = None, driver: str = "none",
          domain_id: int | None = None, say=print, should_stop=lambda: False) -> None:
    """Serve the model of ``source`` (the module docstring) until SIGINT (Ctrl-C), SIGTERM or
    ``should_stop()`` (its own handlers: a shell starting it in the background ignores SIGINT)."""
    if driver not in ("none", "sim", "external"):
        raise ConfigError(f"--driver: got {driver!r}; allowed: none, sim, external")
    check_domain_id(domain_id)
    out = Path(out_dir or f"runs/serve-{time.strftime('%Y%m%d-%H%M%S')}")
    out.mkdir(parents=True, exist_ok=True)
    model_directory(source, out, driver, say)
    if driver == "none":
        nodes = {"sagg_model_server": MODEL_SERVER}
    else:
        nodes = {k: v for k, v in NODES.items() if k == "sagg_learner" or (driver == "sim" and k == "sagg_sim_bridge")}
    group = NodeGroup(node_processes(nodes, out / "logs"), _env_domain(domain_id), localhost=False)
    client = None
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(True))
    try:
        group.start(out / "params.yaml", {"sagg_model_server": {"run": str(out.resolve())}})
        client = OwnReachClient(group.domain, group.check)
        client.wait_for_ik(READY_TIMEOUT)
        served = "/sagg/compute_ik" + ("" if driver == "none" else " and /sagg/reach")
        say(f"serving {served} on ROS_DOMAIN_ID {group.domain} (model {out}; logs {out / 'logs'}): ready. "
            "Ctrl-C stops")
        while not (stop or should_stop()):
            group.check()
            time.sleep(0.2)
    finally:
        if client is not None:
            client.close()
        group.stop()


def main_serve(args) -> int:
    try:
        serve(args.source, args.out, args.driver, args.domain_id)
    except GraphError as exc:
        print(f"sagg: error: {exc}", file=sys.stderr)
        return exc.code
    return 0
