"""Vectorised forward kinematics of one effector point of a compiled MuJoCo model (ROS-free).

Why: a model arm's reachable set and test goals need the effector position of millions of joint
configurations; ``mj_kinematics`` row by row pays a Python loop per posture, this computes a batch
at once (for a single posture numpy's per-call overhead makes ``mj_kinematics`` the better choice).
It reproduces ``mj_kinematics`` for the chain from the world to the effector's body:

- a body's frame is its parent's frame composed with (body_pos, body_quat), then with each of its
  joints in order;
- a hinge turns by θ = qpos - qpos0 about ``jnt_axis`` through the anchor ``jnt_pos`` (body
  frame); a slide moves by qpos - qpos0 along ``jnt_axis``; a ball turns by its (normalised)
  quaternion about ``jnt_pos``; a free joint sets the body's world pose from its qpos;
- the effector is a point fixed in its body (a site's ``site_pos``, or the body origin).

Only the commanded joints (columns of the batch) vary; every other joint on the chain is held at
its rest value and folded, with the fixed offsets, into constant rigid transforms. The point is
pushed from the effector towards the world: x ↦ const(x), x ↦ jp + Rot(axis, θ)(x - jp), ...
Agreement with ``mj_kinematics``: ~1e-15 relative (float rounding; checked in test_model_arm).
"""
from __future__ import annotations

import mujoco
import numpy as np

HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)
SLIDE = int(mujoco.mjtJoint.mjJNT_SLIDE)
BALL = int(mujoco.mjtJoint.mjJNT_BALL)
FREE = int(mujoco.mjtJoint.mjJNT_FREE)


def quat_matrix(q) -> np.ndarray:
    """Rotation matrix of a quaternion (w, x, y, z), normalised first (as MuJoCo does)."""
    m = np.zeros(9)
    qq = np.asarray(q, dtype=float)
    mujoco.mju_quat2Mat(m, qq / np.linalg.norm(qq))
    return m.reshape(3, 3)


def axis_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotation matrix of ``angle`` about the unit vector ``axis`` (through MuJoCo's own quaternion)."""
    q = np.zeros(4)
    mujoco.mju_axisAngle2Quat(q, np.asarray(axis, dtype=float), float(angle))
    return quat_matrix(q)


def to_z(axis: np.ndarray) -> np.ndarray:
    """A rotation matrix taking the unit vector ``axis`` to +z (the identity for +z itself)."""
    a = np.asarray(axis, dtype=float)
    if a[0] == 0.0 and a[1] == 0.0:
        return np.eye(3) if a[2] > 0 else np.diag([1.0, -1.0, -1.0])
    v = np.cross(a, [0.0, 0.0, 1.0])       # rotation axis (unnormalised), |v| = sin of the angle
    c = float(a[2])                        # cos of the angle
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx * (1.0 / (1.0 + c)) if c > -1.0 + 1e-12 else np.diag([1.0, -1.0, -1.0])


class ChainFK:
    """The effector point's world position as a function of the commanded joints.

    ``model``: compiled MjModel; ``body``: the effector's body id; ``local``: the point in that
    body's frame; ``joints``: the commanded joint ids (column i of a batch = joint ``joints[i]``,
    hinge or slide); ``qpos_rest``: full qpos holding every other joint; ``lower``/``upper``: the
    commanded joints' limits (for :meth:`ball`)."""

    def __init__(self, model: mujoco.MjModel, body: int, local: np.ndarray, joints: list[int],
                 qpos_rest: np.ndarray, lower: np.ndarray, upper: np.ndarray):
        self.n = len(joints)
        col = {int(j): i for i, j in enumerate(joints)}
        # stages from the effector to the world: ("const", R, t) | ("hinge", axis, jp, col, qpos0)
        # | ("slide", axis, col, qpos0)
        stages: list[tuple] = []

        def const(R: np.ndarray, t: np.ndarray) -> None:
            if stages and stages[-1][0] == "const":  # compose with the previous constant: this one after it
                _, R1, t1 = stages[-1]
                stages[-1] = ("const", R @ R1, R @ t1 + t)
            else:
                stages.append(("const", R, t))

        b = int(body)
        free_root = False
        while b != 0 and not free_root:
            j0, nj = int(model.body_jntadr[b]), int(model.body_jntnum[b])
            for j in range(j0 + nj - 1, j0 - 1, -1):  # last joint first
                jtype, adr = int(model.jnt_type[j]), int(model.jnt_qposadr[j])
                axis = model.jnt_axis[j].copy()
                jp = model.jnt_pos[j].copy()
                if j in col:
                    q0 = float(model.qpos0[adr])
                    stages.append(("hinge", axis, jp, col[j], q0) if jtype == HINGE else ("slide", axis, col[j], q0))
                elif jtype == HINGE:
                    R = axis_matrix(axis, float(qpos_rest[adr] - model.qpos0[adr]))
                    const(R, jp - R @ jp)
                elif jtype == SLIDE:
                    const(np.eye(3), axis * float(qpos_rest[adr] - model.qpos0[adr]))
                elif jtype == BALL:
                    R = quat_matrix(qpos_rest[adr:adr + 4])
                    const(R, jp - R @ jp)
                else:  # FREE: the body's world pose is its qpos, whatever its parents
                    const(quat_matrix(qpos_rest[adr + 3:adr + 7]), qpos_rest[adr:adr + 3].copy())
                    free_root = True
            if not free_root:
                const(quat_matrix(model.body_quat[b]), model.body_pos[b].copy())
            b = int(model.body_parentid[b])
        self.local = np.asarray(local, dtype=float).copy()
        self.stages = stages
        self._lower = np.asarray(lower, dtype=float)
        self._upper = np.asarray(upper, dtype=float)
        self._ops = self._compile()

    def positions(self, alphas: np.ndarray) -> np.ndarray:
        """(N, n) commanded joint values -> (N, 3) world positions of the effector point."""
        a = np.asarray(alphas, dtype=float)
        x, y, z = (np.full(a.shape[0], c) for c in self.local)
        for op in self._ops:
            if op[0] == "affine":
                rows, t = op[1], op[2]
                x, y, z = ((t[i] + sum(r * v for r, v in zip(rows[i], (x, y, z)) if r != 0.0)) for i in range(3))
            elif op[0] == "rotz":
                th = a[:, op[1]] - op[2] if op[2] != 0.0 else a[:, op[1]]
                c, s = np.cos(th), np.sin(th)
                x, y = c * x - s * y, s * x + c * y
            else:  # slidez
                z = z + (a[:, op[1]] - op[2])
        return np.stack((x, y, z), axis=1)

    def _compile(self) -> list[tuple]:
        """The stages as operations on the point's three coordinates: affine maps (merged where
        consecutive) and rotations / translations along z: a hinge or slide about the axis ``ax``
        through ``jp`` is conjugated by a rotation Q taking ``ax`` to z (x ↦ Q(x - jp), turn or
        move along z, x ↦ Qᵀx + jp), so that each joint costs 6 array operations plus its affine."""
        ops: list[tuple] = []

        def affine(R: np.ndarray, t: np.ndarray) -> None:
            if ops and ops[-1][0] == "affine":
                R1, t1 = ops[-1][3], ops[-1][4]
                R, t = R @ R1, R @ t1 + t
                ops.pop()
            ops.append(("affine", tuple(tuple(float(v) for v in row) for row in R), tuple(float(v) for v in t), R, t))

        for st in self.stages:
            if st[0] == "const":
                affine(st[1], st[2])
                continue
            ax = st[1]
            jp = st[2] if st[0] == "hinge" else np.zeros(3)
            Q = to_z(ax)
            affine(Q, -(Q @ jp))
            ops.append(("rotz", st[3], float(st[4])) if st[0] == "hinge" else ("slidez", st[2], float(st[3])))
            affine(Q.T, jp.copy())
        return [op[:3] for op in ops]

    def ball(self) -> tuple[np.ndarray, float]:
        """(center, radius) of a ball certain to hold the effector point for every posture within
        the limits, built from the effector to the world: a constant moves the center; a hinge
        replaces the ball B(c, r) by B(c', r + |c - c'|), c' the foot of the perpendicular from c
        on the hinge axis (every rotation of B(c, r) about the axis lies in it); a slide moves the
        center to mid-stroke and adds half the stroke. For a chain of hinges the radius is the sum
        of the link offsets measured perpendicular to the joint axes; the center, the point the
        first moving joint turns the arm about (the arm's base)."""
        c = self.local.copy()
        r = 0.0
        for st in self.stages:
            if st[0] == "const":
                c = st[1] @ c + st[2]
            elif st[0] == "hinge":
                _, ax, jp, _, _ = st
                foot = jp + ax * float(ax @ (c - jp))
                r += float(np.linalg.norm(c - foot))
                c = foot
            else:
                _, ax, i, q0 = st
                lo, hi = float(self._lower[i]) - q0, float(self._upper[i]) - q0
                c = c + ax * (0.5 * (lo + hi))
                r += 0.5 * (hi - lo) * float(np.linalg.norm(ax))
        return c, r
