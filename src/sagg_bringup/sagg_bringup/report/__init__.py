"""Run reports: report.md and its figures, from a result.json or a graph run's summary.json (ROS-free)."""
