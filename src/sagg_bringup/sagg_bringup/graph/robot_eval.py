"""The evaluation on the robot of an external-driver run: the test goals reached from rest through
the learner's own ``/sagg/reach`` action (:class:`~.reach_client.ReachClient`), so every motion of the evaluation
obeys the learner's rules (the scene, the velocity limits and streamed setpoints, the stopped-arm
hold; docs/safety.md), with a time bound per test goal; the frozen model is the learner's, learning
paused (:class:`RobotEvaluation`)."""
from __future__ import annotations

import time

import numpy as np

from sagg_low_level.eval_metrics import error_metrics, frame_summary, metric_frame

from .processes import GraphError

def spread_points(points: np.ndarray, n: int, seed: int) -> np.ndarray:
    """``n`` of ``points`` spread by farthest-point selection (the first one drawn with ``seed``):
    test goals over where the robot has been, when the reachable area is unknown."""
    pts = np.unique(np.asarray(points, float), axis=0)
    if len(pts) <= n:
        return pts
    rng = np.random.default_rng(seed)
    chosen = [int(rng.integers(len(pts)))]
    d = np.linalg.norm(pts - pts[chosen[0]], axis=1)
    while len(chosen) < n:
        i = int(np.argmax(d))
        chosen.append(i)
        d = np.minimum(d, np.linalg.norm(pts - pts[i], axis=1))
    return pts[chosen]


class RobotEvaluation:
    """The learner's model reaching test goals from rest on the robot, at the scheduled points
    (``every`` micro-actions, 0 = only at the end) and at the end, each goal through ``/sagg/reach``
    (``client``: a :class:`~.reach_client.ReachClient`, or anything with its ``reach``). Results: ``curve``
    (micro-actions, the evaluation's metrics of sagg_low_level.eval_metrics: mean, median, share
    within tolerance, mean error per distance-from-base band; the errors of every goal) and the
    initial error (the empty model does not move the arm: the distance from the rest tip, measured
    by a return to rest through the action, to each goal). Each goal has at most ``goal_seconds`` s
    on the robot: then it is canceled, its error is where the arm is, and it is counted
    (``timed_out``), so an evaluation ends whatever the arm does."""

    def __init__(self, learner_params: dict, client, n_goals: int, every: int, goals=None,
                 base=None, goal_seconds: float = 120.0):
        self.lp, self.client, self.n_goals, self.every = learner_params, client, n_goals, every
        self.goal_seconds = goal_seconds
        self.timed_out = 0  # goals whose time ran out
        self.steps = 0      # reaching steps of the evaluation (each streamed and checked by the learner)
        self.base = base  # the arm's base in Y (the metric bands; None: the origin)
        self.goals = None if goals is None else np.asarray(goals, float)
        self.goal_source = "the simulated model's test goals" if goals is not None else None
        self.curve: list[dict] = []
        self.initial_errors: np.ndarray | None = None
        self.seconds = 0.0
        self.next_at = every if every > 0 else None

    def choose_goals(self, reached: list[np.ndarray]) -> None:
        """The test goals (once): the simulated model's if given, else spread over ``reached``."""
        if self.goals is None:
            if not reached:
                raise GraphError("no task point recorded: nothing to choose test goals from")
            self.goals = spread_points(np.array(reached), self.n_goals, self.lp["eval.seed"])
            self.goal_source = (f"spread over the {len(reached)} task points the robot reached before "
                                "the first evaluation (no model of the reachable area; not independent "
                                "of exploration)")

    def run(self, at: int, reached: list[np.ndarray]) -> np.ndarray:
        """Evaluate the learner's model at ``at`` micro-actions on the robot (learning paused)."""
        self.choose_goals(reached)
        t0 = time.perf_counter()
        if self.initial_errors is None:  # the rest tip: a return to rest, nothing reached
            rest = self.client.reach(self.goals[0], self.goal_seconds, from_rest=True, tolerance=1e9)
            tip = np.asarray(rest["reached"], float)
            self.initial_errors = np.linalg.norm(self.goals - tip, axis=1)
        errors = np.array([self.reach(g) for g in self.goals])
        self.seconds += time.perf_counter() - t0
        # the evaluation's metrics (sagg_low_level.eval_metrics; bands from the arm's base)
        self.curve.append({"micro_actions": int(at), **error_metrics(errors, self.frame()),
                           "errors": errors.tolist()})
        return errors

    def reach(self, goal: np.ndarray) -> float:
        """One test goal reached from rest within ``goal_seconds`` (the final distance)."""
        r = self.client.reach(goal, self.goal_seconds, from_rest=True)
        self.timed_out += bool(r["timed_out"])
        self.steps += r["steps"]
        return r["error"]

    def frame(self) -> dict:
        """The metric frame of the test goals (R, tolerance, distance bands; eval_metrics)."""
        return metric_frame(self.goals, np.zeros(self.goals.shape[1]) if self.base is None else self.base)

    def summary(self) -> dict:
        init = self.initial_errors
        return {"label": "on the robot", "goals": None if self.goals is None else self.goals.tolist(),
                "goal_source": self.goal_source, "every": self.every,
                "initial_mean_error": float(init.mean()) if init is not None else float("nan"),
                "initial_errors": None if init is None else init.tolist(),
                "curve": self.curve,
                "final_mean_error": self.curve[-1]["mean_error"] if self.curve else float("nan"),
                "final_median_error": self.curve[-1]["median_error"] if self.curve else float("nan"),
                "final_within_share": self.curve[-1]["within_share"] if self.curve else float("nan"),
                "band_mean_errors": self.curve[-1]["band_mean_errors"] if self.curve else None,
                "eval_metrics": None if self.goals is None else frame_summary(self.frame()),
                "steps": self.steps, "goal_seconds": self.goal_seconds, "goals_timed_out": self.timed_out,
                "seconds": self.seconds}
