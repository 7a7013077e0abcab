"""What the two learner nodes share (``learner``: :mod:`.node`; ``fixed_learner``:
:mod:`.fixed_node`): the ``/sagg`` endpoints, the start-up readiness of the goal generator and the
recorder, the check of an answered goal, and the status message.

None of this is on the per-micro-action path: the nodes' observation callbacks, ``dispatch`` and
``flush`` are their own.
"""
from __future__ import annotations

from rclpy.node import Node

from diagnostic_msgs.msg import DiagnosticArray

from sagg_common.diagnostics import goal_problem
from sagg_common.params import GOAL_STRATEGIES, ConfigError, Schema
from sagg_common.ros_params import declare_schema, reliable
from sagg_msgs.msg import CompetenceReport, LearnerStatus, Sample
from sagg_msgs.srv import NextGoal

NODE_NAME = "sagg_learner"


class LearnerNodeBase(Node):
    """A learner node (``params``: the declared ``schema``). Subclasses set ``learner``
    (``task_lower`` / ``task_upper`` / ``last_competence``), ``uses_goals``, ``guard``,
    ``goals_received``, ``exit_code`` / ``done``, and define ``advance(answer)`` (answer the pending
    request and go on) and :meth:`_goal_retry_seconds` / :meth:`_retry_goal_later`."""

    def __init__(self, schema: Schema):
        super().__init__(NODE_NAME)
        self.params = declare_schema(self, schema)

    def _build_learner(self, core_schema: Schema, dims: str, make) -> dict:
        """The learner core from its parameters (``core_schema``, values from ``self.params``):
        ``self.m`` = the task-space dimensions, 2 or 3, else ConfigError (``dims`` says what each
        means for this node); ``self.learner = make(core, m)`` (a ValueError of the core becomes a
        ConfigError); ``self.uses_goals``. Returns the core's parameters."""
        p = self.params
        core = {q.name: p[q.name] for q in core_schema}
        self.m = len(core["task_space.lower"])
        if self.m not in (2, 3):
            raise ConfigError(f"parameter 'task_space.lower': {self.m} dimensions; allowed: {dims}")
        try:
            self.learner = make(core, self.m)
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
        self.uses_goals = core["strategy"] in GOAL_STRATEGIES
        return core

    def _create_sagg_endpoints(self) -> None:
        """``/sagg/competence``, ``/sagg/sample``, ``/sagg/status``, ``/diagnostics`` and the
        ``/sagg/next_goal`` client."""
        # transient_local: a restarted goal generator gets the reports it missed (it drops those it has)
        self.report_pub = self.create_publisher(CompetenceReport, "/sagg/competence",
                                                reliable(10000, transient_local=True))
        self.sample_pub = self.create_publisher(Sample, "/sagg/sample", reliable(10000))
        self.status_pub = self.create_publisher(LearnerStatus, "/sagg/status", reliable(100))
        self.goal_client = self.create_client(NextGoal, "/sagg/next_goal")
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", reliable(10))
        self.goal_future = None  # the goal request whose answer is awaited

    # ------------------------------------------------------------------ start-up
    def _peers_ready(self, hw_pub, hw_topic: str, match_reports: bool) -> bool:
        """The graph around the learner is up: the driver listens on ``hw_topic`` (every subscriber
        matched, at least one), the goal generator serves goals and reads /sagg/competence (goal
        strategies; ``match_reports``: every /sagg/competence reader matched too), and
        ``min_sample_subscribers`` read /sagg/sample."""
        # the controller must be listening, or the first command is lost
        if hw_pub.get_subscription_count() < max(1, self.count_subscribers(hw_topic)):
            return self._waiting_for(f"a subscriber on {hw_topic} (the driver's controller)")
        if self.uses_goals:
            if not self.goal_client.service_is_ready():
                return self._waiting_for("the goal generator's /sagg/next_goal service")
            infos = self.get_subscriptions_info_by_topic("/sagg/competence")
            if not any(i.node_name == "sagg_goal_generator" for i in infos):
                return self._waiting_for("the goal generator's /sagg/competence subscription")
            if match_reports and self.report_pub.get_subscription_count() < len(infos):
                return self._waiting_for("every /sagg/competence subscriber to match")
        need = self.params["min_sample_subscribers"]
        if self.sample_pub.get_subscription_count() < need:
            return self._waiting_for(f"{need} subscriber(s) on /sagg/sample (min_sample_subscribers; "
                                     "set 0 when nothing records)")
        return True

    def _waiting_for(self, what: str) -> bool:
        """Start-up: say what the node waits for (``pause_reason``, /sagg/status; logged once per
        reason). Returns False."""
        reason = f"waiting for {what}"
        if getattr(self, "pause_reason", None) != reason:
            self.get_logger().info(reason)
        self.pause_reason = reason
        return False

    # ------------------------------------------------------------------ goals
    def _goal_retry_seconds(self) -> float:
        """Seconds after which a rejected goal is asked for again."""
        raise NotImplementedError

    def _retry_goal_later(self) -> None:
        """Schedule the goal request again after a rejected answer."""
        raise NotImplementedError

    def on_goal(self, fut) -> None:
        """The answer to a ``/sagg/next_goal`` request: a failed call stops the node (exit code 1);
        a goal outside Y or not finite is rejected (``/diagnostics``) and asked for again; a valid
        one answers the learner's goal request."""
        if fut is not self.goal_future:
            return  # an answer to a request sent again since (goal_retry)
        resp = fut.result()
        if resp is None:
            self.get_logger().error("/sagg/next_goal call failed")
            self.exit_code = 1
            self.done = True
            return
        g = resp.goal
        pos, problem = goal_problem(g.position, self.learner.task_lower, self.learner.task_upper)
        if problem:
            self.guard.reject("goal.invalid", f"goal {g.seq} {problem}; asking again in "
                                              f"{self._goal_retry_seconds()} s")
            self._retry_goal_later()
            return
        self.goals_received += 1
        self.advance((int(g.seq), pos))

    # ------------------------------------------------------------------ outputs
    def _publish_status(self, strategy: str, micro_actions: int, samples: int, rate: float, paused: bool,
                        pause_reason: str, refused: str = "") -> None:
        """``/sagg/status`` (sagg_msgs/LearnerStatus); goals and last competence from the node."""
        msg = LearnerStatus()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.strategy = strategy
        msg.micro_actions = micro_actions
        msg.goals = self.goals_received
        msg.samples = samples
        msg.reports = int(self.learner.reports_sent)
        msg.last_competence = float(self.learner.last_competence)
        msg.micro_actions_per_second = rate
        msg.paused = paused
        msg.pause_reason = pause_reason
        msg.refused = refused
        prior = getattr(self.learner, "prior", None)  # (the fixed-context learner has none)
        if prior is not None:
            msg.prior_samples, msg.prior_superseded = len(prior), prior.superseded_count
        self.status_pub.publish(msg)
