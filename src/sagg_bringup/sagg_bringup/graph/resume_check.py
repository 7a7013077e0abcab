"""At ``sagg run --resume DIR``: do the earlier bags and the nodes' checkpoints agree? (ROS-free)

The checkpoints hold every sample, report and goal the nodes ever published (each is journaled
before it is published: :mod:`sagg_low_level.checkpoint`, :mod:`sagg_goal_generator.checkpoint`);
the bags hold what the recorder had written. After a clean stop they hold the same. A bag recovered
from a killed recorder (:mod:`.bag_recover`) lacks its tail: what the recorder had received but not
yet written (its open mcap chunk, up to 1 MiB of messages). That disagreement is resolved by the
resumed nodes republishing into the next bag: the learner its stored samples from the first index
the bags lack (its parameter ``republish_from``, which :func:`compare` returns) and its journaled
reports, the generator its journaled goals; receivers drop what they have, so ``sagg relearn bag
bag2`` rebuilds the whole run. Reports or goals older than the journals (a ``checkpoint_every``
shorter than the lost tail) cannot be republished: they are named. Bags holding *more* than the
checkpoints (a journal lost, e.g. to a power cut without ``journal_fsync``, or another run's
checkpoint) cannot be resolved: the resume is refused, naming the indices.
"""
from __future__ import annotations

from pathlib import Path

from sagg_common.params import ConfigError
from sagg_goal_generator.checkpoint import published as generator_published
from sagg_low_level.checkpoint import published as learner_published


def _span(lo: int, hi: int) -> str:
    return str(lo) if lo == hi else f"{lo}..{hi}"


def compare(bag_samples: int, bag_reports: int, bag_goals: int, learner_dir: str, generator_dir: str) -> dict:
    """Compare the earlier bags (``bag_samples`` samples from index 0, ``bag_reports`` reports and
    ``bag_goals`` goals from seq 1) with the checkpoints in ``learner_dir`` / ``generator_dir``
    (empty: none). Returns ``republish_from`` (the learner's parameter for this segment), the
    counts, ``lines`` (what is missing from the bags and how it comes back) and ``unresolved``
    (what cannot come back, named). ConfigError when the bags hold more than the checkpoints."""
    lp = learner_published(Path(learner_dir)) if learner_dir else None
    gp = generator_published(Path(generator_dir)) if generator_dir else None
    out = {"republish_from": bag_samples, "bag": {"samples": bag_samples, "reports": bag_reports, "goals": bag_goals},
           "checkpoints": {"samples": lp and lp["samples"], "reports": lp and lp["reports"],
                           "goals": gp and gp["goals"]},
           "lines": [], "unresolved": []}
    # (kind, in the bags, in the checkpoint, the oldest one the journals republish, first number,
    # who republishes, where the checkpoint is)
    rows = []
    if lp is not None:
        rows.append(("samples", bag_samples, lp["samples"], bag_samples, 0, "learner", learner_dir))
        rows.append(("reports", bag_reports, lp["reports"], lp["first_report"], 1, "learner", learner_dir))
    if gp is not None:
        rows.append(("goals", bag_goals, gp["goals"], gp["first_goal"], 1, "goal generator", generator_dir))
    for kind, have, held, first, base, who, where in rows:
        last_bag = have - 1 + base  # the number of the last one in the bags
        if have > held:
            raise ConfigError(
                f"--resume: the bags hold {kind} {_span(held + base, last_bag)} that the {who}'s checkpoint "
                f"'{where}' does not (it holds {held:,}; a journal lost, e.g. to a power cut without "
                "journal_fsync, or another run's checkpoint): bags and checkpoint disagree; allowed: a run "
                "directory whose checkpoint holds at least what its bags hold")
        if have == held:
            continue
        lo, hi = last_bag + 1, held - 1 + base
        if first is not None and first <= lo:
            out["lines"].append(f"{kind} {_span(lo, hi)} ({hi - lo + 1:,}) are in the {who}'s checkpoint, "
                                "not in the bags: republished into the new bag")
            continue
        gone_hi = hi if first is None else first - 1
        out["unresolved"].append(
            f"{kind} {_span(lo, gone_hi)} ({gone_hi - lo + 1:,}) are in no bag and older than the {who}'s "
            f"journals (checkpoint_every shorter than the lost tail): they cannot be republished, and "
            f"`sagg relearn` of this run will name them missing"
            + (f"; {_span(gone_hi + 1, hi)} are republished" if gone_hi < hi else ""))
    return out
