"""A live view of the run: ``visualization_msgs/MarkerArray`` on ``/sagg/markers`` (RViz2, Foxglove).

What it shows (in the task space, z = 0, frame ``world``):

- ``regions``: every leaf of the goal generator's region tree, a flat box coloured by its interest
  (dark blue = the lowest interest of the tree, yellow = the highest), with its outline;
- ``goals``: the last :data:`RECENT_GOALS` self-generated goals, spheres coloured by the competence
  of their attempt (red = −1, moved away; green = 0, reached; grey = not yet reported);
- ``test_goals``: the evaluation's test goals (white), when known;
- ``tip_path``: the effector's last :data:`PATH_POINTS` distinct task points (a line strip).

The first marker of every array is a DELETEALL, so leaves that were split disappear. The topic is
reliable and transient_local (depth 1): a viewer that joins late gets the latest view at once. It is
published by ``sagg run`` and ``sagg record`` (from the topics they record), at most every
``period`` s when something changed, and recorded in the bag. :func:`marker_arrays_from_bag` and
:func:`render_markers` draw the recorded view with matplotlib (the README's screenshot).

The marker content is computed ROS-free (:func:`view_markers`: plain dicts); :func:`to_msg` makes the
message.
"""
from __future__ import annotations

import math
import time
from collections import deque
from pathlib import Path

import numpy as np

from sagg_common.report_kinds import KIND_GOAL
from sagg_common.ros_params import reliable

from ..bags.recorder import make_typestore

MARKER_TOPIC = "/sagg/markers"
FRAME = "world"
RECENT_GOALS = 50
PATH_POINTS = 500
PATH_STEP = 0.002  # (our choice: 0.2 % of the task space's diagonal, ~0.2 units for Y of 100 × 100)

# marker types / actions of visualization_msgs/Marker
LINE_STRIP, LINE_LIST, SPHERE_LIST, CUBE = 4, 5, 7, 1
DELETEALL = 3


def interest_colour(x: float) -> tuple[float, float, float]:
    """[0, 1] -> a blue-to-yellow ramp (dark blue, teal, green, yellow)."""
    stops = np.array([[0.15, 0.1, 0.45], [0.1, 0.45, 0.55], [0.2, 0.7, 0.35], [0.99, 0.9, 0.15]])
    x = float(np.clip(x, 0.0, 1.0)) * (len(stops) - 1)
    i = min(int(x), len(stops) - 2)
    c = stops[i] + (x - i) * (stops[i + 1] - stops[i])
    return tuple(float(v) for v in c)


def competence_colour(c: float | None) -> tuple[float, float, float]:
    """Competence in [-1, 0] -> red (-1) to green (0); None (not reported yet) -> grey."""
    if c is None or not np.isfinite(c):
        return (0.6, 0.6, 0.6)
    t = float(np.clip(1.0 + c, 0.0, 1.0))
    return (1.0 - t, 0.8 * t + 0.1, 0.1)


def _xyz(p) -> list[float]:
    """A task point as a marker point: (x, y) at z = 0, or (x, y, z) of a 3-D task space."""
    q = [float(v) for v in p[:3]]
    return q + [0.0] * (3 - len(q))


def _box_edges(a: np.ndarray, b: np.ndarray) -> list[list[float]]:
    """The edges of the box [a, b] as point pairs (a LINE_LIST): 4 of a 2-D box, 12 of a 3-D one."""
    if len(a) == 2:
        c = [(a[0], a[1]), (b[0], a[1]), (b[0], b[1]), (a[0], b[1])]
        return [_xyz(p) for i in range(4) for p in (c[i], c[(i + 1) % 4])]
    corners = [np.where([i & 1, i & 2, i & 4], b, a) for i in range(8)]
    return [_xyz(corners[k]) for i in range(8) for j in (1, 2, 4) if not i & j for k in (i, i | j)]


def view_markers(regions: list[dict], goals: list[dict], test_goals, path, scale: float) -> list[dict]:
    """The markers (plain dicts: ns, id, type, pose position, scale, colour(s), points) of one view.
    ``regions``: leaves with ``lower``/``upper``/``interest``; ``goals``: ``position`` and
    ``competence`` (or None); ``test_goals``/``path``: (n, 2 or 3) arrays or None; ``scale``: the task
    space's extent (sizes of spheres and lines are fractions of it). A 2-D task space lies at z = 0
    (flat boxes); a 3-D one is drawn in 3-D (boxes, goals and the tip path in space)."""
    out: list[dict] = [{"ns": "", "id": 0, "type": CUBE, "action": DELETEALL}]
    if regions:
        vals = np.array([r["interest"] for r in regions], float)
        vals = np.where(np.isfinite(vals), vals, 0.0)
        lo, hi = float(vals.min()), float(vals.max())
        lines = []
        for k, (r, v) in enumerate(zip(regions, vals)):
            a, b = np.asarray(r["lower"][:3], float), np.asarray(r["upper"][:3], float)
            rgb = interest_colour((v - lo) / (hi - lo) if hi > lo else 0.0)
            size = (b - a).tolist() + ([scale * 1e-3] if len(a) == 2 else [])
            out.append({"ns": "regions", "id": k, "type": CUBE, "position": _xyz((a + b) / 2),
                        "scale": size, "color": rgb + (0.45 if len(a) == 2 else 0.12,)})
            lines += _box_edges(a, b)
        out.append({"ns": "region_edges", "id": 0, "type": LINE_LIST, "scale": [scale * 2e-3] * 3,
                    "color": (0.1, 0.1, 0.1, 0.8), "points": lines})
    if goals:
        recent = goals[-RECENT_GOALS:]
        out.append({"ns": "goals", "id": 0, "type": SPHERE_LIST, "scale": [scale * 0.02] * 3,
                    "color": (1.0, 1.0, 1.0, 1.0),
                    "points": [_xyz(g["position"]) for g in recent],
                    "colors": [competence_colour(g.get("competence")) + (1.0,) for g in recent]})
    if test_goals is not None and len(test_goals):
        out.append({"ns": "test_goals", "id": 0, "type": SPHERE_LIST, "scale": [scale * 0.012] * 3,
                    "color": (1.0, 1.0, 1.0, 0.9), "points": [_xyz(g) for g in np.asarray(test_goals)]})
    if path is not None and len(path) > 1:
        out.append({"ns": "tip_path", "id": 0, "type": LINE_STRIP, "scale": [scale * 3e-3] * 3,
                    "color": (0.95, 0.35, 0.1, 0.9), "points": [_xyz(p) for p in np.asarray(path)]})
    return out


def to_msg(markers: list[dict], stamp, frame: str = FRAME):
    """A ``visualization_msgs/MarkerArray`` of :func:`view_markers`' dicts."""
    # lazy (heavy): ROS
    from geometry_msgs.msg import Point
    from std_msgs.msg import ColorRGBA
    from visualization_msgs.msg import Marker, MarkerArray
    arr = MarkerArray()
    for d in markers:
        m = Marker()
        m.header.stamp = stamp
        m.header.frame_id = frame
        m.ns, m.id, m.type = d["ns"], int(d["id"]), int(d["type"])
        m.action = int(d.get("action", Marker.ADD))
        if m.action == Marker.ADD:
            m.pose.orientation.w = 1.0
            x, y, z = d.get("position", [0.0, 0.0, 0.0])
            m.pose.position.x, m.pose.position.y, m.pose.position.z = float(x), float(y), float(z)
            m.scale.x, m.scale.y, m.scale.z = (float(v) for v in d["scale"])
            r, g, b, a = d["color"]
            m.color = ColorRGBA(r=float(r), g=float(g), b=float(b), a=float(a))
            m.points = [Point(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in d.get("points", [])]
            m.colors = [ColorRGBA(r=float(c[0]), g=float(c[1]), b=float(c[2]), a=float(c[3]))
                        for c in d.get("colors", [])]
        arr.markers.append(m)
    return arr


class MarkerView:
    """Keeps what the view needs from the recorded topics (:meth:`handlers`) and publishes
    ``/sagg/markers`` (reliable, transient_local, depth 1) at most every ``period`` s when it changed."""

    def __init__(self, node, topics, period: float = 0.5, task_lower=None, task_upper=None):
        # lazy (heavy): ROS
        from visualization_msgs.msg import MarkerArray
        self.node, self.period = node, period
        self.pub = node.create_publisher(MarkerArray, MARKER_TOPIC, reliable(1, transient_local=True))
        self.task_topics = [t.name for t in topics if t.msgtype == "geometry_msgs/msg/PointStamped"]
        self.regions: list[dict] = []
        self.goals: dict[int, dict] = {}
        self.test_goals = None
        self.path: deque = deque(maxlen=PATH_POINTS)
        self.scale = None if task_lower is None else float(np.linalg.norm(np.subtract(task_upper, task_lower)))
        self.dims = 2 if task_lower is None else len(task_lower)  # task dimensions (the regions say, too)
        self.dirty = False
        self.last = 0.0
        self.published = 0

    def handlers(self) -> dict:
        out = {"/sagg/regions": self.on_regions, "/sagg/goal": self.on_goal, "/sagg/competence": self.on_report}
        out.update({t: self.on_tip for t in self.task_topics})
        return out

    def on_regions(self, m) -> None:
        self.regions = [{"lower": list(r.lower), "upper": list(r.upper), "interest": float(r.interest)}
                        for r in m.regions]
        if self.regions:
            lo = np.min([r["lower"] for r in self.regions], axis=0)
            hi = np.max([r["upper"] for r in self.regions], axis=0)
            self.scale = float(np.linalg.norm(hi - lo))
            self.dims = len(lo)
        self.dirty = True

    def on_goal(self, m) -> None:
        self.goals.setdefault(int(m.seq), {"position": list(m.position), "competence": None})
        self.dirty = True

    def on_report(self, m) -> None:
        if m.kind == KIND_GOAL and int(m.goal_seq) in self.goals:
            self.goals[int(m.goal_seq)]["competence"] = float(m.competence)
            self.dirty = True

    def on_tip(self, m) -> None:
        """Keep a task point when it is at least :data:`PATH_STEP` × the task space's extent from the
        last kept one (a driver at 250 Hz would otherwise fill the path with one pose)."""
        p = (m.point.x, m.point.y, m.point.z)[:self.dims]
        if self.path and len(self.path[-1]) != len(p):
            self.path.clear()  # (the task space's dimensions learned from the first region tree)
        if self.path and math.dist(p, self.path[-1]) < PATH_STEP * (self.scale or 100.0):
            return
        self.path.append(p)
        self.dirty = True

    def set_test_goals(self, goals) -> None:
        self.test_goals = None if goals is None else np.asarray(goals, float)
        self.dirty = True

    def maybe_publish(self, force: bool = False) -> bool:
        now = time.monotonic()
        if not (self.dirty or force) or (now - self.last < self.period and not force):
            return False
        scale = self.scale or 100.0
        goals = [self.goals[k] for k in sorted(self.goals)[-RECENT_GOALS:]]
        markers = view_markers(self.regions, goals, self.test_goals, np.array(self.path) if self.path else None, scale)
        self.pub.publish(to_msg(markers, self.node.get_clock().now().to_msg()))
        self.dirty, self.last = False, now
        self.published += 1
        return True


# ------------------------------------------------------------------------------ from a bag
def marker_arrays_from_bag(bag: str | Path) -> list:
    """Every recorded ``/sagg/markers`` message of a bag (rosbags-deserialized), in order."""
    # lazy (heavy): rosbags
    from rosbags.highlevel import AnyReader
    out = []
    with AnyReader([Path(bag)], default_typestore=make_typestore()) as reader:
        conns = [c for c in reader.connections if c.topic == MARKER_TOPIC]
        for conn, _, raw in reader.messages(connections=conns):
            out.append(reader.deserialize(raw, conn.msgtype))
    return out


def render_markers(arr, png: str | Path, title: str = "") -> Path:
    """Draw one recorded MarkerArray as RViz would see it from above (matplotlib, headless)."""
    # lazy (heavy): matplotlib
    import matplotlib
    matplotlib.use("Agg")
    # lazy (heavy): matplotlib
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    fig, ax = plt.subplots(figsize=(7, 6.5), dpi=110)
    ax.set_facecolor((0.22, 0.22, 0.25))
    for m in arr.markers:
        if m.action == DELETEALL:
            continue
        col = (m.color.r, m.color.g, m.color.b, m.color.a)
        pts = np.array([[p.x, p.y] for p in m.points]) if len(m.points) else np.zeros((0, 2))
        if m.type == CUBE:
            ax.add_patch(Rectangle((m.pose.position.x - m.scale.x / 2, m.pose.position.y - m.scale.y / 2),
                                   m.scale.x, m.scale.y, facecolor=col, edgecolor="none", zorder=1))
        elif m.type == LINE_LIST and len(pts):
            for a, b in zip(pts[0::2], pts[1::2]):
                ax.plot([a[0], b[0]], [a[1], b[1]], color=col, lw=0.6, zorder=2)
        elif m.type == LINE_STRIP and len(pts):
            ax.plot(pts[:, 0], pts[:, 1], color=col, lw=1.0, zorder=3, label=m.ns)
        elif m.type == SPHERE_LIST and len(pts):
            cols = [(c.r, c.g, c.b, c.a) for c in m.colors] if len(m.colors) else [col]
            big = m.ns == "goals"
            ax.scatter(pts[:, 0], pts[:, 1], c=cols, s=40 if big else 18, marker="o" if big else "D",
                       edgecolors="black" if big else "none", linewidths=0.5, zorder=4 if big else 5, label=m.ns)
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("y1")
    ax.set_ylabel("y2")
    ax.legend(loc="upper right", fontsize=8, framealpha=0.8)
    ax.set_title(title or "/sagg/markers (regions by interest, goals by competence, test goals, tip path)",
                 fontsize=9)
    fig.tight_layout()
    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png)
    plt.close(fig)
    return png
