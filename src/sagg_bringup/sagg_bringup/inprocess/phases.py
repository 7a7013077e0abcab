"""Where an in-process run's micro-actions (fixed context: experiments) went: counts by phase (reaching,
exploration, babbling) and returns to rest, split by whether the self-generated goal they served
lies in the arm's reachable area; and how close the run's tips came to each test goal. ROS-free;
written into result.json by :mod:`sagg_bringup.inprocess.experiment`."""
from __future__ import annotations

import numpy as np

# Command kinds of sagg_low_level.learner.Command that are micro-actions; "reset" is a return to
# rest (no sample stored, not counted as a micro-action).
MICRO_ACTION_KINDS = ("reach", "explore", "babble")


class PhaseCounter:
    """Counts the learner's commands by kind, in total and per self-generated goal (the goal last
    handed to the learner; commands before the first goal belong to none)."""

    def __init__(self) -> None:
        self.totals: dict[str, int] = {}
        self.per_goal: dict[int, dict[str, int]] = {}
        self._current: dict[str, int] | None = None

    def goal(self, seq: int) -> None:
        self._current = self.per_goal.setdefault(seq, {})

    def command(self, kind: str) -> None:
        self.totals[kind] = self.totals.get(kind, 0) + 1
        if self._current is not None and kind != "reset":
            self._current[kind] = self._current.get(kind, 0) + 1


def phase_breakdown(counter: PhaseCounter, goal_seqs, goal_positions: np.ndarray, area) -> dict:
    """Micro-actions by phase, in total and on goals inside / outside the reachable area (``area``
    as in goal_share_stats), with the mean per goal; ``rest_returns`` counts returns to rest."""
    t = counter.totals
    out = {"reach": t.get("reach", 0), "explore": t.get("explore", 0), "babble": t.get("babble", 0),
           "rest_returns": t.get("reset", 0)}
    done = out["reach"] + out["explore"] + out["babble"]
    out["explore_share"] = out["explore"] / done if done else float("nan")
    pos = np.asarray(goal_positions, dtype=float)
    inside = area.contains(pos) if len(pos) else np.zeros(0, bool)
    for name, mask in (("reachable_goals", inside), ("unreachable_goals", ~inside)):
        seqs = [s for s, m in zip(goal_seqs, mask) if m and s in counter.per_goal]
        reach = sum(counter.per_goal[s].get("reach", 0) for s in seqs)
        explore = sum(counter.per_goal[s].get("explore", 0) for s in seqs)
        out[name] = {"goals": len(seqs), "reach": reach, "explore": explore,
                     "share_of_micro_actions": (reach + explore) / done if done else float("nan"),
                     "micro_actions_per_goal": (reach + explore) / len(seqs) if seqs else float("nan")}
    return out


def coverage(tips: np.ndarray, test_goals: np.ndarray) -> dict:
    """Distance from each test goal to the nearest tip position the run ever reached (does
    exploration cover the reachable set?): max, mean and median over the test goals."""
    # lazy (heavy): scipy
    from scipy.spatial import cKDTree

    if len(tips) == 0:
        return {"max": float("nan"), "mean": float("nan"), "median": float("nan")}
    d, _ = cKDTree(np.asarray(tips, dtype=float)).query(np.asarray(test_goals, dtype=float))
    return {"max": float(d.max()), "mean": float(d.mean()), "median": float(np.median(d))}
