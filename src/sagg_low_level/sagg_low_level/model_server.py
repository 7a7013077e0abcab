"""The model server (``model_server``): a finished run's model, learning off, serving ``/sagg/compute_ik``.

::

    ros2 run sagg_low_level model_server --ros-args -p run:=DIR

``DIR`` is a run directory (its ``params.yaml`` and learner checkpoint) or the model directory that
``sagg serve`` writes (also from a run's bag). The node (``sagg_model_server``) builds the learner
of the run's parameters around the stored samples (the run's joints, limits, rest posture, scene and
reaching parameters; nothing is ever stored), and answers ``/sagg/compute_ik``
(:mod:`.ik_service`) in its one thread; bad requests are counted on ``/diagnostics``. It moves
nothing: ``/sagg/reach`` needs a robot, and is served by the learner with the same model
(``frozen_memory``: ``sagg serve DIR --driver sim|external``, or ``ros2 run sagg_low_level learner
--ros-args --params-file DIR/params.yaml -p frozen_memory:=DIR``), which answers ``/sagg/compute_ik``
as well.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticArray

from sagg_common.diagnostics import InputGuard, diagnostic_array
from sagg_common.params import ConfigError, read_config, resolve
from sagg_common.ros_params import declare_schema, reliable, run_node
from sagg_msgs.srv import ComputeIK

from .evaluate import reach_steps_limit
from .ik import load_model
from .ik_service import SERVICE, answer_ik
from .known_points import KnownPoints
from .learner import EvolvingContextLearner
from .move_check import build_move_check
from .node import robot_from_params
from .schema import LEARNER_CORE_SCHEMA, LEARNER_SCHEMA, MODEL_SERVER_SCHEMA

NODE_NAME = "sagg_model_server"


def run_learner_params(params_file: Path) -> dict:
    """The learner node's parameters of a run (``params_file``: its ``sagg_learner`` section over the
    ``/**`` entries the learner declares, over the defaults), checked; ConfigError naming the file."""
    try:
        sections = read_config(params_file)
    except ConfigError as exc:
        raise ConfigError(f"parameter 'run': {exc}") from exc
    known = {p.name for p in LEARNER_SCHEMA}
    values = {**{k: v for k, v in sections.get("/**", {}).items() if k in known}, **sections.get("sagg_learner", {})}
    values.pop("frozen_memory", None)
    return resolve(LEARNER_SCHEMA, values, f"{params_file} (sagg_learner)")


def served_learner(run: str, rest_point=()) -> tuple[EvolvingContextLearner, np.ndarray | None, list[str]]:
    """``(learner, rest point or None, what to say)`` of the model in ``run`` (the module docstring):
    the learner of the run's parameters around its stored samples, with its scene; ``rest_point``
    (non-empty) replaces the files'. ConfigError naming the parameter."""
    directory = Path(run)
    if not run or not directory.is_dir():
        raise ConfigError(f"parameter 'run': {run!r}; allowed: a run directory (params.yaml, checkpoint/) or the "
                          "model directory of `sagg serve`")
    if not (directory / "params.yaml").is_file():
        raise ConfigError(f"parameter 'run': no params.yaml in '{directory}' (the run's parameters)")
    p = run_learner_params(directory / "params.yaml")
    robot = robot_from_params(p)
    m = len(p["task_space.lower"])
    try:
        memory, stored, what = load_model(directory)
    except (OSError, ValueError) as exc:
        raise ConfigError(f"parameter 'run': {exc}") from exc
    if (memory.state_dim, memory.outcome_dim) != (robot.n, m):
        raise ConfigError(f"parameter 'run': samples of {memory.state_dim} joints and {memory.outcome_dim} task "
                          f"dimensions in {what}; the run's parameters say {robot.n} and {m}")
    learner = EvolvingContextLearner({q.name: p[q.name] for q in LEARNER_CORE_SCHEMA}, robot, m, memory=memory)
    learner.scene, notices = build_move_check(p, robot.joint_names, str(directory), learner)
    given = np.asarray(rest_point, dtype=float)
    if given.size and (given.shape != (m,) or not np.all(np.isfinite(given))):
        raise ConfigError(f"parameter 'rest_point': {given.tolist()}; allowed: empty or {m} finite values")
    rest = given if given.size else stored
    said = [f"model: {len(memory)} samples from {what}, {robot.n} joints, {m} task dimensions; rest point "
            + ("none (requests must give start and start_point)" if rest is None else
               f"{np.round(rest, 6).tolist()}" + (" (parameter rest_point)" if given.size else ""))]
    return learner, rest, said + list(notices)


class ModelServer(Node):
    """``/sagg/compute_ik`` for the model of the parameter ``run`` (the module docstring)."""

    def __init__(self):
        super().__init__(NODE_NAME)
        p = self.params = declare_schema(self, MODEL_SERVER_SCHEMA)
        self.learner, self.rest_point, said = served_learner(p["run"], p["rest_point"])
        for line in said:
            self.get_logger().info(line)
        lp = self.learner.p
        self.steps_limit = reach_steps_limit(self.learner, lp["task_space.lower"], lp["task_space.upper"])
        self.guard = InputGuard(self.get_logger().error)
        self.answered = 0
        self.seconds = 0.0
        self.points = KnownPoints()  # (the points of the stored postures: built at the first request)
        self.create_service(ComputeIK, SERVICE, self.on_compute_ik)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable(10))
        self.create_timer(1.0, self.publish_diagnostics)
        self.get_logger().info(f"serving {SERVICE} (learning off)")

    def on_compute_ik(self, request: ComputeIK.Request, response: ComputeIK.Response) -> ComputeIK.Response:
        t0 = time.perf_counter()
        answer_ik(request, response, self.learner, self.rest_point, self.steps_limit, self.guard, self.points)
        self.answered += 1
        self.seconds += time.perf_counter() - t0
        return response

    def publish_diagnostics(self) -> None:
        state = {"samples": str(len(self.learner.memory)), "compute_ik requests answered": str(self.answered),
                 "compute_ik seconds": f"{self.seconds:.3f}"}
        self.diag_pub.publish(diagnostic_array(self.get_clock().now().to_msg(), NODE_NAME, self.guard, state))


def main(args: list[str] | None = None) -> int:
    sys.exit(run_node(NODE_NAME, ModelServer, args, executor="events"))


if __name__ == "__main__":
    main()
