"""The peer comparison's peer, explauto 1.4, learning the same 7-DOF arm: run by :mod:`.peer` under the
peer's own interpreter (a separate venv with explauto; nothing of sagg is imported here).

Reads one JSON object on stdin::

    {"dofs": 7, "joint_limit": 1.047..., "length_ratio": 1.5, "s_mins": [..], "s_maxs": [..],
     "points": [5000, 20000], "seed": 0, "interest": "tree", "test_goals": [[x, y], ...],
     "check_angles": [[a1..a7], ...]}

and prints one JSON object: the test error at each point (mean final distance of one-shot
nearest-neighbour reaches, explauto's "exploit" mode, noise-free), the learning rate (queries per
second of the loop, evaluation excluded) and the tips of ``check_angles`` (the caller compares
them with its own arm's, so both learn the same kinematics).

The learning loop is explauto's own (``Experiment``'s: goal from the interest model, inverse
prediction with exploration, one environment update = one forward query, both models updated).
explauto draws from numpy's global generator; it is seeded here, in the peer's process only.
explauto 1.4 predates Python 3.10 and NumPy 1.24: the aliases it uses are restored first.
"""
import collections
import collections.abc
import json
import sys
import time

import numpy as np

for _name in ("MutableMapping", "Mapping", "Sequence", "Iterable", "Callable"):
    if not hasattr(collections, _name):
        setattr(collections, _name, getattr(collections.abc, _name))
for _name, _type in (("float", float), ("int", int), ("bool", bool), ("object", object)):
    if _name not in np.__dict__:
        setattr(np, _name, _type)

from explauto import InterestModel, SensorimotorModel  # noqa: E402
from explauto.environment.simple_arm.simple_arm import SimpleArmEnvironment, forward  # noqa: E402


def main() -> None:
    spec = json.load(sys.stdin)
    n = int(spec["dofs"])
    lim = float(spec["joint_limit"])
    env = SimpleArmEnvironment(m_mins=np.full(n, -lim), m_maxs=np.full(n, lim),
                               s_mins=np.asarray(spec["s_mins"], float), s_maxs=np.asarray(spec["s_maxs"], float),
                               length_ratio=float(spec["length_ratio"]), noise=0.0)
    tips = [list(forward(a, env.lengths)) for a in spec["check_angles"]]
    np.random.seed(int(spec["seed"]))
    sm = SensorimotorModel.from_configuration(env.conf, "nearest_neighbor", "default")
    im = InterestModel.from_configuration(env.conf, env.conf.s_dims, spec["interest"], "default")
    goals = np.asarray(spec["test_goals"], float)
    m = env.random_motors(1)[0]  # explauto's Experiment starts the model with one random command
    sm.update(m, env.update(m, reset=False))
    points, errors, done, learn = sorted(int(p) for p in spec["points"]), {}, 0, 0.0
    for p in points:
        t = time.perf_counter()
        sm.mode = "explore"
        while done < p:
            s_g = im.sample()
            m = sm.inverse_prediction(s_g)
            s = env.update(m, reset=False)
            sm.update(m, s)
            im.update(np.hstack((m, s_g)), np.hstack((m, s)))
            done += 1
        learn += time.perf_counter() - t
        sm.mode = "exploit"
        reached = np.array([env.update(sm.inverse_prediction(g), reset=False) for g in goals])
        errors[str(p)] = float(np.linalg.norm(reached - goals, axis=1).mean())
    json.dump({"errors": errors, "queries_per_second": done / learn, "check_tips": tips}, sys.stdout)


if __name__ == "__main__":
    main()
