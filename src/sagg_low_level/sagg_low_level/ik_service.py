"""``/sagg/compute_ik`` (sagg_msgs/srv/ComputeIK) on a node: a request checked, then answered by the
ROS-free core (:mod:`.ik`: joint positions for a point of Y from the learned model alone).

The learner node serves it (during learning, and with a frozen model) and so does the model server
(:mod:`.model_server`, a finished run's model). Both answer in their node's one executor thread,
the thread that grows the memory (the learner's), so that a request never reads the memory while a
sample is added. Each node keeps one :class:`~.known_points.KnownPoints` (the points of its stored
postures, where the answers start) across requests: built at the first request, then brought up to
date with the samples added since. A bad request changes nothing: it is counted (``rejected.compute_ik.invalid`` on
/diagnostics), logged naming the field, its value and what is allowed, and answered with
``success`` false, that message and the outcome 'invalid'.
"""
from __future__ import annotations

from sagg_common.diagnostics import InputGuard

from .ik import compute_ik, request_problem
from .known_points import KnownPoints
from .learner import EvolvingContextLearner

SERVICE = "/sagg/compute_ik"


def answer_ik(request, response, learner: EvolvingContextLearner, rest_point, steps_limit: int,
              guard: InputGuard, points: KnownPoints | None = None):
    """Fill ``response`` (ComputeIK.Response) for ``request`` with ``learner``'s model and
    ``rest_point`` (None: unknown), starting from ``points`` (the node's, kept across requests; None:
    built for this request); a bad request is counted in ``guard``. Returns ``response``."""
    response.joint_names = list(learner.robot.joint_names)
    why = request_problem(learner, request.target, request.start, request.start_point, request.tolerance,
                          request.max_steps, steps_limit)
    if why:
        guard.reject("compute_ik.invalid", f"{SERVICE}: {why}; request refused")
        response.success, response.message, response.outcome = False, why, "invalid"
        return response
    a = compute_ik(learner, rest_point, request.target, request.start, request.start_point, request.tolerance,
                   request.max_steps, points)
    response.success, response.message, response.outcome = bool(a.success), a.message, a.outcome
    response.joints = [float(v) for v in a.joints]
    response.predicted = [float(v) for v in a.predicted]
    response.predicted_error, response.nearest_sample = float(a.predicted_error), float(a.nearest_sample)
    response.steps = int(a.steps)
    return response
