"""The scene and its collision checking (sagg_common.scene, .scene_model, .scene_params): postures
through the floor, in a box or folded onto the arm itself are refused on the example arms (arm6: an
MJCF with capsules; arm7: a URDF whose collision meshes are missing, so capsules stand for its links);
a move whose end points are free but whose middle is not is refused; the samples of a move respect
the margin (checked with the model's own forward kinematics); a move out of a collision is allowed
only on its way out; bad parameters name themselves; the task point check without a model."""
from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from sagg_common.params import ConfigError, resolve, schema_defaults
from sagg_common.robot_model import RobotModel
from sagg_common.scene import SCENE_PARAMS, SceneChecker, SceneParams, scene_from_params, task_point_refusal
from sagg_common.scene_model import LINK

REST7 = [0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4]
_ROBOTS: dict[str, RobotModel] = {}


def robot(name: str) -> RobotModel:
    """The example arms of config/arm6_mjcf.yaml and config/arm7_urdf.yaml (loaded once)."""
    if name not in _ROBOTS:
        _ROBOTS[name] = (RobotModel.load("config/robots/arm6.xml", "tool") if name == "arm6" else
                         RobotModel.load("config/robots/arm7.urdf", "tool0", rest=tuple(REST7)))
    return _ROBOTS[name]


def posture(name: str, **joints: float) -> np.ndarray:
    """The rest posture of arm ``name`` with some joints (by index: j0=..., j3=...) set."""
    a = robot(name).rest.copy()
    for k, v in joints.items():
        a[int(k[1:])] = v
    return a


def scene(**kw) -> SceneParams:
    return SceneParams.from_params({f"scene.{k}": v for k, v in kw.items()})


FLOOR = scene(floor=0.0)


# ------------------------------------------------------------------ postures
@pytest.mark.parametrize("name,through", [
    ("arm6", dict(j1=0.0)),            # shoulder lifted level: the folded forearm hangs through the table
    ("arm7", dict(j1=1.5, j3=-0.5)),   # leaning forward and down: the tool below the table
])
def test_a_posture_through_the_floor_is_refused_and_the_rest_posture_is_not(name, through):
    r = robot(name)
    c = SceneChecker(r, FLOOR)
    assert c.posture(r.rest) is None
    low = posture(name, **through)
    assert r.task_point(low)[2] < 0.0  # (the effector itself is below z = 0)
    refusal = c.posture(low)
    assert refusal is not None and refusal.cause == "floor" and refusal.distance < 0
    assert "through the floor at z=0.000" in refusal.detail and refusal.at == 1.0
    # the same posture above a floor lowered by a metre is free
    assert SceneChecker(r, scene(floor=-1.0)).posture(low) is None


def test_within_the_clearance_of_the_floor_is_a_collision():
    """arm6 with its shoulder at -0.92 rad: its wrist 0.028 m above the table, under the 0.03 m
    clearance; with a clearance of 0.02 m the same posture is free."""
    a = posture("arm6", j1=-0.92)
    refusal = SceneChecker(robot("arm6"), FLOOR).posture(a)
    assert refusal is not None and refusal.cause == "floor" and 0.0 < refusal.distance < 0.03
    assert refusal.detail.startswith("wrist_3_link 0.028 m above the floor at z=0.000 (clearance 0.03)")
    assert SceneChecker(robot("arm6"), scene(floor=0.0, clearance=0.02)).posture(a) is None


def test_the_base_and_links_turning_about_a_vertical_axis_never_meet_the_floor():
    """arm6's base (no joint) and its shoulder (turned by the vertical pan joint only) reach below
    z = 0 (the shoulder capsule's round end): a floor at 0 does not refuse them, in any pan angle;
    the notice names the shoulder."""
    c = SceneChecker(robot("arm6"), FLOOR)
    for pan in np.linspace(-3.0, 3.0, 7):
        assert c.posture(posture("arm6", j0=pan)) is None
    assert any("not checked against the floor: shoulder_link" in n for n in c.notices)


def test_a_box_in_the_way_is_refused_and_the_same_box_elsewhere_is_not():
    r = robot("arm6")
    forearm = body_position(r, r.rest, "wrist_1_link")
    near = SceneChecker(r, scene(boxes=[*forearm, 0.05, 0.05, 0.05]))
    refusal = near.posture(r.rest)
    assert refusal is not None and refusal.cause == "box" and refusal.detail.endswith("in box 1")
    far = SceneChecker(r, scene(boxes=[1.5, 1.5, 0.2, 0.1, 0.1, 0.1, *forearm, 0.05, 0.05, 0.05]))
    assert far.posture(r.rest).detail.endswith("in box 2")  # boxes are counted from 1 in their order
    assert SceneChecker(r, scene(boxes=[1.5, 1.5, 0.2, 0.1, 0.1, 0.1])).posture(r.rest) is None


@pytest.mark.parametrize("name,folded,pair", [
    ("arm6", dict(j2=3.1), "upper_arm_link and wrist_1_link"),   # elbow folded all the way
    ("arm7", dict(j3=-3.0, j5=-0.0175), "arm7_link4 and flange"),  # elbow and wrist folded onto the elbow
])
def test_the_arm_folded_onto_itself_is_refused(name, folded, pair):
    r = robot(name)
    c = SceneChecker(r, SceneParams())
    assert c.posture(r.rest) is None
    a = posture(name, **folded)
    contacts = c.contacts(a)
    print(name, [(x.detail, round(x.distance, 4)) for x in contacts])
    assert contacts and contacts[0].cause == "self" and contacts[0].detail == pair
    assert contacts[0].distance < -0.05  # (overlapping by more than 5 cm: not a grazing contact)
    assert c.posture(a) == contacts[0]
    # the same posture without self-collision checking
    assert SceneChecker(r, SceneParams(self_collision=False)).posture(a) is None


def test_links_touching_at_rest_are_left_out_and_named():
    """arm6's shoulder and upper arm touch its base cylinder at rest (the default in collision rule);
    arm7's capsules meet at the joints whose frames coincide."""
    c6 = SceneChecker(robot("arm6"), SceneParams())
    assert set(c6.scene.excluded) == {("base_link", "shoulder_link"), ("base_link", "upper_arm_link")}
    assert any("base_link-shoulder_link" in n for n in c6.notices)
    c7 = SceneChecker(robot("arm7"), SceneParams())
    assert ("arm7_link0", "arm7_link2") in c7.scene.excluded
    assert any("capsules of radius 0.05 m" in n and "arm7_link4" in n for n in c7.notices)
    assert c7.scene.capsule_links[0] == "arm7_link0"


# ------------------------------------------------------------------ moves
def test_a_move_with_free_ends_through_a_box_is_refused():
    """arm6 turning on its base by π, a box where its forearm is half way: both ends are free, the
    move is not; the refusal says where along it."""
    r = robot("arm6")
    start, end, middle = posture("arm6", j0=0.0), posture("arm6", j0=math.pi), posture("arm6", j0=math.pi / 2)
    box = [*body_position(r, middle, "forearm_link"), 0.05, 0.05, 0.05]
    c = SceneChecker(r, scene(boxes=box))
    assert c.posture(start) is None and c.posture(end) is None and c.posture(middle) is not None
    assert c.samples(start, end) > 2
    refusal = c.segment(start, end)
    # (the upper arm comes within the clearance first, a fifth of the way round)
    assert refusal is not None and refusal.cause == "box" and 0.1 < refusal.at < 0.5, refusal
    assert c.segment(end, start).at == pytest.approx(refusal.at, abs=0.05)  # the box is half way either way
    assert c.segment(start, posture("arm6", j0=-math.pi / 2)) is None  # the other way round is free


def test_a_move_with_free_ends_through_the_floor_is_refused():
    """arm6 swinging its shoulder from above the table over to the far side (lift from -1.2 to π
    rad): both ends are high, the arm passes under the table top on the way."""
    r = robot("arm6")
    c = SceneChecker(r, FLOOR)
    start, end = posture("arm6", j1=-1.2), posture("arm6", j1=math.pi)
    assert c.posture(start) is None and c.posture(end) is None
    refusal = c.segment(start, end)
    assert refusal is not None and refusal.cause == "floor" and 0.0 < refusal.at < 0.5, refusal
    assert c.segment(start, posture("arm6", j1=-2.5)) is None  # lifting further up is free


def test_the_samples_move_no_point_more_than_the_margin():
    """Straight moves of both arms (random ones, and each joint alone from the outstretched
    posture, where the bound is nearly reached): between consecutive checked postures (and from the
    start to the first one) no point of any link's geometry (its bounding sphere) moves more than
    scene.margin, measured with the model's forward kinematics; and the bound is not loose by more
    than a factor 2 on the worst of these moves."""
    rng = np.random.default_rng(3)
    for name in ("arm6", "arm7"):
        r = robot(name)
        c = SceneChecker(r, scene(margin=0.01))
        d = mujoco.MjData(c.model)
        moves = []
        for _ in range(10):
            a0, a1 = rng.uniform(r.lower, r.upper, (2, len(r.lower)))
            moves.append((a0, a0 + rng.uniform(0.05, 1.0) * (a1 - a0)))
        stretched = np.clip(np.zeros(len(r.lower)), r.lower, r.upper)
        moves += [(stretched, stretched + 0.5 * np.eye(len(r.lower))[j]) for j in range(len(r.lower))]
        worst_ratio = 0.0
        for a0, a1 in moves:
            n = c.samples(a0, a1)
            pts = [link_points(c, d, a0 + (i / n) * (a1 - a0)) for i in range(n + 1)]
            step = max(np.linalg.norm(q - p, axis=1).max() for p, q in zip(pts, pts[1:]))
            assert step <= 0.01 + 1e-12, (name, n, step)
            worst_ratio = max(worst_ratio, step / 0.01)
        print(name, "largest step / margin", worst_ratio)
        assert worst_ratio > 0.5, worst_ratio


def test_sample_counts_grow_with_the_move_and_shrink_with_the_margin():
    r = robot("arm7")
    c = SceneChecker(r, SceneParams())
    assert c.samples(r.rest, r.rest) == 1
    small, large = c.samples(r.rest, r.rest + 0.1), c.samples(r.rest, r.rest + 0.5)
    assert 1 < small < large <= 5 * small + 1
    assert SceneChecker(r, SceneParams(margin=0.01)).samples(r.rest, r.rest + 0.1) >= 2 * small - 1
    wrist = posture("arm7", j6=r.rest[6] + 0.1)
    assert c.samples(r.rest, wrist) < small  # the last joint moves a short tool only


def test_a_move_out_of_a_collision_is_allowed_only_on_its_way_out():
    """arm6 resting 2.8 cm above the table (under the 3 cm clearance, as through a calibration gap):
    lifting away is allowed; lowering further, turning on the spot (the end still in collision) and
    lifting into a box are refused."""
    r = robot("arm6")
    start = posture("arm6", j1=-0.92)
    up, down, turned = posture("arm6", j1=-1.1), posture("arm6", j1=-0.85), posture("arm6", j0=0.5, j1=-0.92)
    c = SceneChecker(r, FLOOR)
    assert c.posture(start) is not None and c.posture(up) is None
    assert c.segment(start, up) is None
    deeper = c.segment(start, down)
    assert deeper is not None and deeper.cause == "floor" and deeper.distance < c.posture(start).distance
    assert c.segment(start, turned) is not None and c.segment(start, turned).at == 1.0
    # a box where the lifted wrist goes: a new colliding pair on the way out
    boxed = SceneChecker(r, scene(floor=0.0,
                                  boxes=[*body_position(r, up, "wrist_3_link"), 0.04, 0.04, 0.04]))
    refusal = boxed.segment(start, up)
    assert refusal is not None and refusal.cause == "box"
    # a free start: the rule is not needed, the same moves are judged sample by sample
    assert c.segment(up, start) is not None and c.segment(up, start).cause == "floor"


def test_joints_in_another_order():
    r = robot("arm7")
    names = list(r.joint_names)[::-1]
    c = SceneChecker(r, SceneParams(), joints=names)
    a = posture("arm7", j3=-3.0, j5=-0.0175)
    assert c.posture(a[::-1]).detail == "arm7_link4 and flange"
    np.testing.assert_allclose(c.radii, SceneChecker(r, SceneParams()).radii[::-1])
    with pytest.raises(ConfigError, match="parameter joints"):
        SceneChecker(r, SceneParams(), joints=["arm7_joint1", "nope"])


# ------------------------------------------------------------------ parameters
@pytest.mark.parametrize("params,match", [
    ({"scene.boxes": [0.0] * 7}, r"scene.boxes.*length 7.*6 numbers per box"),
    ({"scene.boxes": [0.5, 0.0, 0.2, 0.1, -0.1, 0.1]}, r"scene.boxes.*box 1 has half sizes.*> 0"),
    ({"scene.boxes": [0.5, 0.0, 0.2, 0.1, 0.0, 0.1]}, r"scene.boxes.*half sizes > 0"),
    ({"scene.link_radius": -0.1}, r"scene.link_radius.*-0.1.*\(0.0, 1.0\]"),
    ({"scene.margin": 0.0}, r"scene.margin.*0.0.*\[0.001, 1.0\]"),
    ({"scene.clearance": -0.01}, r"scene.clearance"),
    ({"scene.floor": float("nan")}, r"scene.floor.*not finite"),
    ({"scene.floor": -1000.5}, r"scene.floor.*\[-1000.0, 100.0\]"),
    ({"scene.self_collision": 1}, r"scene.self_collision.*true or false"),
])
def test_bad_parameters_name_the_parameter_value_and_range(params, match):
    with pytest.raises(ConfigError, match=match):
        SceneParams.from_params(params)


def test_parameters_default_to_no_scene_and_an_empty_box_list_is_valid():
    defaults = schema_defaults(SCENE_PARAMS)
    assert defaults["scene.boxes"] == [] and resolve(SCENE_PARAMS, {"scene.boxes": []})["scene.boxes"] == []
    p = SceneParams.from_params(defaults)
    assert p == SceneParams() and p.floor is None and p.boxes == () and defaults["scene.floor"] == -1000.0
    assert SceneParams.from_params({"scene.floor": 0.0}).floor == 0.0  # floor: 0.0 alone is a table at z = 0
    assert SceneParams.from_params({"scene.floor": -999.0}).floor == -999.0
    assert not p.obstacles and p.self_collision  # (no scene by default; with one, self-collision on)
    two = SceneParams.from_params({"scene.boxes": [1, 2, 3, 0.1, 0.2, 0.3, 4, 5, 6, 1, 1, 1]})
    assert two.boxes == ((1.0, 2.0, 3.0, 0.1, 0.2, 0.3), (4.0, 5.0, 6.0, 1.0, 1.0, 1.0))
    assert hash(two) == hash(SceneParams.from_params({"scene.boxes": [1, 2, 3, 0.1, 0.2, 0.3, 4, 5, 6, 1, 1, 1]}))


# ------------------------------------------------------------------ without a model
def test_the_task_point_alone():
    p = scene(floor=0.1, boxes=[0.5, 0.0, 0.3, 0.1, 0.1, 0.1])
    assert task_point_refusal(np.array([0.0, 0.0, 0.5]), p) is None
    below = task_point_refusal(np.array([0.0, 0.0, 0.05]), p)
    assert below.cause == "floor" and "the task point 0.050 m below the floor at z=0.100" in below.detail
    near = task_point_refusal(np.array([0.0, 0.0, 0.12]), p)  # above, but within the clearance
    assert near is not None and near.cause == "floor"
    assert task_point_refusal(np.array([0.5, 0.05, 0.3]), p).detail == "the task point in box 1"
    grown = task_point_refusal(np.array([0.62, 0.0, 0.3]), p)  # 2 cm outside the box: within clearance
    assert grown.cause == "box" and grown.distance == pytest.approx(0.02)
    assert task_point_refusal(np.array([0.65, 0.0, 0.3]), p) is None
    # a 2-D task point (x, y): the floor cannot be checked, a box by its footprint
    assert task_point_refusal(np.array([0.5, 0.0]), p, "xy").cause == "box"
    assert task_point_refusal(np.array([0.0, 0.0]), p, "xy") is None


def test_scene_from_a_learners_parameters():
    """The learner's task_model.* give the model; without one (a tracker) there is no checker."""
    r = robot("arm7")
    p = {"task_model.file": "robots/arm7.urdf", "task_model.effector": "tool0", "task_model.task_axes": "xyz",
         "task_model.package_paths": ["."], "joint_limits.lower": list(r.lower), "joint_limits.upper": list(r.upper),
         "rest_posture": REST7, **{k: v for k, v in schema_defaults(SCENE_PARAMS).items()},
         "scene.floor": 0.0}
    joints = list(r.joint_names)[::-1]
    p["joint_limits.lower"], p["joint_limits.upper"] = p["joint_limits.lower"][::-1], p["joint_limits.upper"][::-1]
    p["rest_posture"] = REST7[::-1]
    c = scene_from_params(p, joints, "config")
    assert isinstance(c, SceneChecker) and c.joint_names == tuple(joints)
    assert c.posture(np.array(REST7[::-1])) is None
    assert c.posture(posture("arm7", j1=1.5, j3=-0.5)[::-1]).cause == "floor"
    assert scene_from_params({**p, "task_model.file": ""}, joints, "config") is None
    assert scene_from_params({**p, "scene.floor": -1000.0, "scene.self_collision": False}, joints, "config") is None
    with pytest.raises(ConfigError, match="task_model.effector"):
        scene_from_params({**p, "task_model.effector": "nope"}, joints, "config")


# ------------------------------------------------------------------ helpers
def body_position(r: RobotModel, alpha: np.ndarray, body: str) -> list[float]:
    """World position of a body's origin in a posture (mj_kinematics on the robot's model)."""
    d = mujoco.MjData(r.model)
    d.qpos[:] = r.qpos_rest
    d.qpos[r.qadr] = alpha
    mujoco.mj_kinematics(r.model, d)
    return d.xpos[mujoco.mj_name2id(r.model, mujoco.mjtObj.mjOBJ_BODY, body)].tolist()


def link_points(c: SceneChecker, d: mujoco.MjData, alpha: np.ndarray) -> np.ndarray:
    """Points fixed to every link geom of the checker's model (its centre and the six points of its
    bounding sphere on its own axes), in the world, for one posture."""
    m = c.model
    d.qpos[:] = c.data.qpos
    d.qpos[[m.jnt_qposadr[m.joint(j).id] for j in c.joint_names]] = alpha
    mujoco.mj_kinematics(m, d)
    out = []
    for g in np.flatnonzero(c.scene.geom_cause == LINK):
        centre, axes, r = d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3), m.geom_rbound[g]
        out += [centre] + [centre + s * r * axes[:, k] for k in range(3) for s in (-1.0, 1.0)]
    return np.array(out)


def test_a_posture_of_another_length_or_not_finite_is_an_error():
    c = SceneChecker(robot("arm6"), FLOOR)
    with pytest.raises(ValueError, match="6 finite values"):
        c.posture(np.zeros(5))
    with pytest.raises(ValueError, match="6 finite values"):
        c.segment(robot("arm6").rest, np.full(6, np.nan))


def test_a_tracker_set_up_checks_the_predicted_task_point_only():
    """Without the robot's model (a tracker gives the task point) the learner checks where its
    local model predicts the task point after the move (move_check.TaskPointCheck): refused below
    the floor's clearance or in a box; a point already too close may move away; said at start."""
    from sagg_low_level.move_check import TaskPointCheck, build_move_check

    params = SceneParams.from_params({"scene.floor": 0.0, "scene.boxes": [0.5, 0.0, 0.5, 0.1, 0.1, 0.1]})
    y = np.array([0.0, 0.0, 0.2])
    check = TaskPointCheck(params, "xyz", lambda a, da: np.array([0.0, 0.0, -da.sum()]), lambda: y)
    assert check.segment(np.zeros(2), np.array([0.05, 0.05])) is None           # to z = 0.1: clear
    r = check.segment(np.zeros(2), np.array([0.1, 0.09]))                      # to z = 0.01: too close
    assert r is not None and r.cause == "floor"
    into_box = TaskPointCheck(params, "xyz", lambda a, da: np.array([0.5, 0.0, 0.3]), lambda: y)
    assert into_box.segment(np.zeros(2), np.ones(2)).cause == "box"
    y = np.array([0.0, 0.0, 0.01])  # resting too close to the floor: moving up is allowed, down is not
    assert check.segment(np.zeros(2), np.array([-0.05, 0.0])) is None
    assert check.segment(np.zeros(2), np.array([0.005, 0.0])) is not None

    class Learner:
        task_lower = np.zeros(3)
        y = np.zeros(3)

        def predict(self, a, da):
            return np.zeros(3)

    p = {"scene.floor": 0.0, "task_model.file": "", "task_model.task_axes": "xyz"}
    got, notices = build_move_check(p, ["j0", "j1"], ".", Learner())
    assert isinstance(got, TaskPointCheck) and "the task point only" in notices[0]
    assert build_move_check({"task_model.file": ""}, ["j0"], ".", Learner()) == (None, [])
