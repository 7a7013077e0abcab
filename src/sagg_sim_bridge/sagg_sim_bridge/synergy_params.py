"""Parameters of the synergy bridge (quadruped / fishing rod) and the simulator they describe. ROS-free."""
from __future__ import annotations

from sagg_common.params import Param, Schema

from . import fishing, quadruped

SETUPS = ("quadruped", "fishing")

SCHEMA: Schema = (
    Param("seed", "int", 0, "Run seed (the synergy simulators are deterministic: no noise stream).", low=0),
    Param("setup", "str", "quadruped",
          "Which synergy robot: 'quadruped' (Sec. 4) or 'fishing' (Sec. 5). Set it under '/**' so that "
          "`sagg run`/`sagg experiment` choose the fixed-context learner and synergy bridge.",
          choices=SETUPS),
) + quadruped.SCHEMA + fishing.SCHEMA



def make_sim(params: dict):
    """The simulator of resolved bridge ``params`` (QuadrupedSim or FishingSim)."""
    if params["setup"] == "quadruped":
        return quadruped.QuadrupedSim(quadruped.spec_from_params(params))
    return fishing.FishingSim(fishing.spec_from_params(params))
