"""Pictures of the synergy robots for the README: ``MUJOCO_GL=egl python -m sagg_lab.render DIR``.

Writes ``DIR/quadruped.png`` (the quadruped half-way through a gait) and ``DIR/fishing.png`` (the
fishing rod during a cast, float in flight). Headless rendering needs ``MUJOCO_GL=egl`` (or osmesa).
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

import mujoco
import numpy as np

from sagg_common.synergy import SinusoidSynergy, VelocitySynergy

from sagg_sim_bridge.fishing import FishingSim
from sagg_sim_bridge.quadruped import QuadrupedSim


def _render(model, data, camera: mujoco.MjvCamera, path: Path, width=640, height=480) -> None:
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt
    with mujoco.Renderer(model, height, width) as r:
        r.update_scene(data, camera)
        plt.imsave(path, r.render())


def render_quadruped(path: Path) -> None:
    sim = QuadrupedSim()
    syn = SinusoidSynergy(sim.joint_names, sim.rest, [0.2, 0.5, 0.5] * 4, 2 * math.pi, 1.3, 50.0)
    theta = np.concatenate([[0.1, 0.4, 0.4] * 4, [0.0, 0.0, 0.0, math.pi, math.pi, math.pi] * 2])
    sim.execute(syn.trajectory(theta))
    cam = mujoco.MjvCamera()
    cam.lookat[:] = sim.data.xpos[sim._torso]
    cam.distance, cam.azimuth, cam.elevation = 1.3, 135.0, -25.0
    _render(sim.model, sim.data, cam, path)


def render_fishing(path: Path) -> None:
    sim = FishingSim()
    syn = VelocitySynergy(sim.joint_names, [-1.5] * 4, [1.5] * 4, 2.0, 50.0)
    traj = syn.trajectory([0.7, 0.85, 0.8, 0.8])
    sim.reset()
    m, d = sim.model, sim.data
    ref = sim.rest.copy()
    dt = m.opt.timestep
    for i in range(int(1.0 / dt)):        # 1 s into the cast
        ref = np.clip(ref + traj.sample_velocities(i * dt) * dt, sim.lower, sim.upper)
        d.ctrl[:] = ref
        mujoco.mj_step(m, d)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = [0.2, 0.1, 0.45]
    cam.distance, cam.azimuth, cam.elevation = 1.7, 250.0, -12.0
    _render(m, d, cam, path)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    out = Path(argv[0] if argv else ".")
    out.mkdir(parents=True, exist_ok=True)
    render_quadruped(out / "quadruped.png")
    render_fishing(out / "fishing.png")
    print(f"wrote {out / 'quadruped.png'} and {out / 'fishing.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
