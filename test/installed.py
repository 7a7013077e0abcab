"""The installed executables the tests start, found the way `sagg run` finds its nodes'
(sagg_bringup.graph.processes.find_node_executable): next to this Python (the make set-up's venv), in an
ament prefix's lib/<package> (a colcon workspace, the `ros2 run` layout), or on PATH."""
from __future__ import annotations

from sagg_bringup.graph.processes import find_node_executable

# console script -> the package that installs it
PACKAGE = {"sagg": "sagg_bringup", "goal_generator": "sagg_goal_generator", "learner": "sagg_low_level",
           "fixed_learner": "sagg_low_level", "synergy_learner": "sagg_low_level", "model_server": "sagg_low_level",
           "mujoco_bridge": "sagg_sim_bridge", "synergy_bridge": "sagg_sim_bridge"}


def executable(script: str) -> str:
    """The path of console script ``script`` (ConfigError naming where it looked if it is missing)."""
    return str(find_node_executable(PACKAGE[script], script))


SAGG = executable("sagg")
