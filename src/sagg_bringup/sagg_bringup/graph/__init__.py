"""The ROS 2 graph of a run: the set-up registry, node processes and parameter files, the session,
``sagg run`` (simulated or external driver), ``sagg record``, ``sagg check-driver``, ``sagg reach``,
the launch plan."""
