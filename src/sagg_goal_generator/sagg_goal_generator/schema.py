"""The goal-generator node's parameter schema (ROS-free, so that ``sagg experiment`` and ``sagg
params`` read it without rclpy): the core's parameters (:data:`sagg_goal_generator.core.SCHEMA`)
and the node's own (publication, service, checkpoints, input checks)."""
from __future__ import annotations

from sagg_common.params import Param, Schema

from .core import SCHEMA as CORE_SCHEMA

NODE_SCHEMA: Schema = (
    Param("regions_period", "float", 0.5,
          "Seconds between two /sagg/regions snapshots when nothing split (a split publishes at once).",
          low=0.01, high=3600.0),
    Param("min_goal_subscribers", "int", 0,
          "Answer goal requests only once /sagg/goal has at least this many matched subscribers "
          "(e.g. 1 when a recorder must see every goal). 0 = do not wait.", low=0, high=1000),
    # checkpoint / resume (sagg_goal_generator.checkpoint)
    Param("checkpoint_dir", "str", "",
          "Directory of the generator's checkpoints and goal journal (generator_*). Empty = off. With "
          "resume true the generator resumes from the checkpoint in it exactly (reports it missed come "
          "again from the learner's transient_local /sagg/competence history). `sagg run` uses "
          "DIR/checkpoint and gives it on the command line (never in DIR/params.yaml)."),
    Param("resume", "bool", False,
          "Continue the run whose checkpoint is in checkpoint_dir. false: a checkpoint_dir that holds "
          "a checkpoint is refused (exit 2, one line; nothing written). `sagg run --resume DIR` sets true."),
    Param("checkpoint_every", "int", 1000,
          "Checkpoint every this many reports (and at shutdown). At most the learner's "
          "/sagg/competence history (10000 reports), which re-sends the reports since the last "
          "checkpoint after a crash. Our choice.", low=1, high=10000),
    Param("journal_fsync", "bool", False,
          "fsync the goal journal after every goal (survives a power cut, not only a killed process)."),
    Param("report_reorder_wait", "float", 10.0,
          "A report ahead of the next one expected is kept this long (s) for the ones before it "
          "(reordered, or re-delivered from the learner's history after a re-subscription) before "
          "those are counted as lost and skipped (under load the history after a re-subscription can "
          "come seconds later: a short wait loses reports). Our choice.", low=0.0, high=3600.0),
    Param("report_window", "int", 10000,
          "A competence report whose seq lies more than this beyond the last one processed is rejected "
          "(its gap is not skipped; docs/safety.md). The learner's /sagg/competence history (10000) bounds a "
          "real gap. Our choice.", low=1, high=1_000_000),
    Param("plausibility.source_grace", "float", 2.0,
          "Reports from one source (docs/safety.md): while a second publisher sends well-formed reports on "
          "/sagg/competence (told apart by the publishers' sequence numbers), every report is dropped "
          "and named; this many seconds (s) after the second source's last report the generator "
          "subscribes again and takes the real ones from the learner's history. A publisher that "
          "sends nothing changes nothing. Same name and default as the learner's (set both under "
          "'/**'). Our choice.", low=0.0, high=3600.0, low_open=True),
)
SCHEMA: Schema = CORE_SCHEMA + NODE_SCHEMA
