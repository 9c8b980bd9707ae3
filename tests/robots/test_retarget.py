"""Retargeting to the shipped humanoid robots, checked in MuJoCo: each step as a function of arrays, the whole
retarget on generated motions (limits, self-contacts, feet on the floor, tracking), the files a robotics user loads,
and every door (library, CLI, HTTP)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco", reason="the robot extra (pip install 'stablemofusion[robot]')")

from stablemofusion.cli.main import main  # noqa: E402
from stablemofusion.core.errors import SMFError  # noqa: E402
from stablemofusion.pipelines.motion_pipeline import MotionPipeline  # noqa: E402
from stablemofusion.robots.checks import check_motion, limit_violations, self_contacts  # noqa: E402
from stablemofusion.robots.files import csv_columns, npz_arrays, write_keyframes  # noqa: E402
from stablemofusion.robots.model import Robot, load_robot, read_joint_map  # noqa: E402
from stablemofusion.robots.retarget import (LEVEL_HEIGHT, _feet_points, _places, _runs,  # noqa: E402
                                            feet_apart, floor_feet, keypoint_targets, level_feet, lock_targets,
                                            pelvis_axes, pin_feet, planted_feet, resample_qpos, robot_frame,
                                            separate, sole_heights, solve_poses)

ROBOTS = ("g1", "h1")
# H1 poses of generated motions before levelling, where 0.4.6 left a planted sole over 2 cm (the file says how made)
LEVELLING_WINDOWS = json.loads((Path(__file__).parent / "levelling_windows.json").read_text())["windows"]


@pytest.fixture(scope="module")
def pipe():
    return MotionPipeline.from_pretrained(backend="onnx", threads=1)


@pytest.fixture(scope="module")
def waves(pipe):
    return pipe("a person waves with the right hand", seconds=4, seed=0)[0]


def test_the_frame_turns_y_up_z_forward_into_z_up_x_forward():
    left, up, forward = np.eye(3)  # HumanML3D: x left, y up, z forward
    assert np.array_equal(robot_frame(np.stack([forward, left, up])), np.eye(3))


def test_pelvis_axes_are_a_rotation_facing_where_the_hips_say():
    joints = np.zeros((2, 22, 3))
    joints[:, 1], joints[:, 2], joints[:, 3] = [0.1, 0, 0], [-0.1, 0, 0], [0, 0.1, 0.02]
    axes = pelvis_axes(joints)
    assert np.allclose(axes[0] @ axes[0].T, np.eye(3)) and np.isclose(np.linalg.det(axes[0]), 1.0)
    assert np.allclose(axes[0, 1], [0, 1, 0]) and axes[0, 0, 0] > 0.9  # left is +y, forward +x


@pytest.mark.parametrize("name", ROBOTS)
def test_the_shipped_robots_load_with_their_sites_on_the_right_sides(name):
    robot = load_robot(name)
    assert robot.model.nq == 7 + len(robot.joint_names) and len(robot.sites) == 14
    assert 0.5 < robot.leg < 1.0 and 0.03 < robot.rest_ankle < 0.1


def test_a_map_whose_left_site_is_on_the_right_is_refused(tmp_path):
    sites, _ = read_joint_map(None)
    sites["left_wrist"], sites["right_wrist"] = sites["right_wrist"], sites["left_wrist"]
    bad = tmp_path / "swapped.json"
    bad.write_text(json.dumps({"sites": sites}))
    with pytest.raises(SMFError, match="left_wrist, lies on the robot's right side"):
        Robot("g1", bad)


def test_a_robot_with_two_joints_on_one_body_is_refused_in_one_line(tmp_path):
    """The kinematics take one hinge or slide per body; an MJCF with two on one body gets a one-line error."""
    path = tmp_path / "two.xml"
    path.write_text("""<mujoco><worldbody><body name="base"><freejoint/><geom size="0.1"/>
      <body name="arm"><joint name="a" type="hinge"/><joint name="b" type="hinge" axis="1 0 0"/><geom size="0.05"/>
      </body></body></worldbody></mujoco>""")
    with pytest.raises(SMFError, match="a body with more than one joint is not supported") as err:
        Robot(path)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("text, message", [("{", "not JSON"), ('{"sites": {"nose": "x"}}', "does not have: nose"),
                                           ('{"sites": {"pelvis": "BODY_25:MidHip"}}', "must map left_ankle")])
def test_bad_joint_maps_get_one_line(tmp_path, text, message):
    path = tmp_path / "map.json"
    path.write_text(text)
    with pytest.raises(SMFError, match=message):
        read_joint_map(path)


def test_the_solver_reaches_a_pose_the_robot_can_take():
    """Targets read off a random pose inside the joint ranges: the solve from the reference pose finds sites within
    a few millimetres of them (the posture prior pulls the redundant joints toward the reference pose), joints
    inside their ranges."""
    robot = load_robot("g1")
    rng = np.random.default_rng(0)
    q = robot.rest.copy()
    q[7:] = np.clip(q[7:] + rng.normal(0, 0.15, len(q) - 7), robot.ranges[:, 0], robot.ranges[:, 1])
    d = mujoco.MjData(robot.own)
    here = _places(robot, d, q[None])[0]
    K = len(robot.sites)
    sites, toes = here[:K], here[K:K + 2]
    d.qpos[:] = q
    mujoco.mj_kinematics(robot.model, d)
    axes = d.xmat[robot.free_body].reshape(3, 3).T.copy()
    got = solve_poses(robot, sites[None], toes[None], axes[None], coarse_iterations=200)[0]
    d.qpos[:] = got
    mujoco.mj_kinematics(robot.model, d)
    error = np.linalg.norm(d.site_xpos[robot.sites] - sites, axis=1)
    assert np.median(error) < 0.005 and error.max() < 0.03
    assert limit_violations(robot, got[None]) == 0


def test_the_base_quaternion_is_resampled_without_a_sign_flip():
    q = np.zeros((3, 8))
    q[:, 3:7] = [[1, 0, 0, 0], [-np.cos(0.1), 0, 0, -np.sin(0.1)], [np.cos(0.2), 0, 0, np.sin(0.2)]]
    out = resample_qpos(q, 20.0, 50.0)
    assert np.allclose(np.linalg.norm(out[:, 3:7], axis=1), 1.0)
    assert (np.einsum("ti,ti->t", out[1:, 3:7], out[:-1, 3:7]) > 0.99).all()


def test_planted_feet_come_from_the_cleanups_holds(waves):
    held = waves.contacts
    feet = planted_feet(waves.joints, waves.fps, held)
    assert np.array_equal(feet[:, 0], held[:, 0] | held[:, 1]) and np.array_equal(feet[:, 1], held[:, 2] | held[:, 3])


@pytest.mark.parametrize("name", ROBOTS)
def test_a_generated_motion_on_each_robot(waves, name):
    """Inside the joint ranges, no contact between the robot's own bodies, planted soles on the floor (within 2 cm,
    none below it), keypoints tracked (median under 7 cm), feet sliding no more than the human's, 50 Hz."""
    robot = load_robot(name)
    motion = waves.to_robot(name)
    assert motion.fps == 50.0 and len(motion.qpos) == (waves.frames - 1) * 5 // 2 + 1  # 20 fps -> 50 Hz
    got = check_motion(robot, motion, waves.joints, waves.fps, waves.contacts)
    assert got["limit_violations"] == 0 and got["self_contact_frames"] == 0
    assert np.percentile(got["planted_sole_height_m"], 95) <= 0.02 and got["sole_below_floor_m"] < 1e-6
    assert np.median(got["tracking_error_m"]) < 0.07
    assert np.median(got["robot_slide_mps"]) < 0.01 < np.median(got["human_slide_mps"])  # locked, the human's not
    # the right hand waves: the right wrist's site above the right shoulder's for a good part of the motion
    d = mujoco.MjData(robot.model)
    names = list(robot.human_names)
    up = []
    for q in motion.qpos:
        d.qpos[:] = q
        mujoco.mj_kinematics(robot.model, d)
        up.append(d.site_xpos[robot.sites[names.index("right_wrist")], 2]
                  > d.site_xpos[robot.sites[names.index("right_shoulder")], 2])
    assert np.mean(up) > 0.3


def test_self_contacts_are_counted_and_pushed_apart():
    """A pose with an arm swung 0.3 rad into the body (4 cm deep) is counted (the check is not blind), and
    separate() pushes it out."""
    robot = load_robot("g1")
    q = robot.rest.copy()
    q[7 + robot.joint_names.index("left_shoulder_roll_joint")] = -0.3
    assert self_contacts(robot, q[None])[0] > 0
    fixed = separate(robot, q[None], iterations=20)
    assert self_contacts(robot, fixed)[0] == 0 and limit_violations(robot, fixed) == 0


def test_an_arm_swung_into_the_body_is_pushed_out_with_the_frames_around_it():
    """Twenty frames at rest, the left arm swung into the body in one: separate() pushes it out and moves the frames
    around it part of the way (the shoulder's largest step between frames well under the 0.3 rad it was swung), the
    frames far from it untouched."""
    robot = load_robot("g1")
    q = np.repeat(robot.rest[None], 20, axis=0)
    shoulder = 7 + robot.joint_names.index("left_shoulder_roll_joint")
    q[10, shoulder] = -0.3
    fixed = separate(robot, q)
    assert self_contacts(robot, fixed).sum() == 0
    assert np.abs(np.diff(fixed[:, shoulder])).max() < 0.2 and (fixed[9, 7:] != q[9, 7:]).any()
    assert np.array_equal(fixed[:5], q[:5]) and np.array_equal(fixed[15:], q[15:])


def test_a_foot_in_the_air_is_kept_above_the_floor():
    """Targets that put the left ankle 10 cm below the floor while neither foot of the left stands: the solve keeps
    the left sole above the floor (within 5 mm: a stiff penalty, not a hard bound), where the targets alone would
    sink it."""
    robot = load_robot("g1")
    d = mujoco.MjData(robot.own)
    here = _places(robot, d, robot.rest[None])[0]
    K = len(robot.sites)
    sites, toes = here[:K].copy(), here[K:K + 2].copy()
    ankle = list(robot.human_names).index("left_ankle")
    sites[ankle, 2] -= 0.1
    toes[0, 2] -= 0.1
    d.qpos[:] = robot.rest
    mujoco.mj_kinematics(robot.model, d)
    axes = d.xmat[robot.free_body].reshape(3, 3).T.copy()
    held = np.array([[False, False, True, True]])  # the right foot stands, the left is in the air
    got = solve_poses(robot, sites[None], toes[None], axes[None], held, coarse_iterations=60)
    assert sole_heights(robot, got)[0, 0] > -0.005
    standing = solve_poses(robot, sites[None], toes[None], axes[None], np.ones((1, 4), bool), coarse_iterations=60)
    assert sole_heights(robot, standing)[0, 0] < -0.02  # a standing foot is not lifted: it follows its targets


def test_pairs_of_geoms_close_at_the_reference_pose_are_known():
    """The G1's build puts some of its geoms within 2 cm of each other at the reference pose (they are only kept
    from overlapping); a pair far apart there is not among them; the table is symmetric."""
    robot = load_robot("g1")
    assert robot.rest_near.any() and np.array_equal(robot.rest_near, robot.rest_near.T)
    m = robot.model
    names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in m.geom_bodyid]
    hand = names.index("left_wrist_yaw_link")
    foot = names.index("right_ankle_roll_link")
    assert not robot.rest_near[hand, foot]


def test_lock_targets_hold_a_foot_at_its_mean_place_on_the_floor_and_ease_in_and_out():
    spots = np.cumsum(np.full((80, 4, 3), 0.01), axis=0)  # every point drifting 1 cm a frame on each axis
    held = np.zeros((80, 4), bool)
    held[20:60, 0] = True  # the left ankle, 2 s at 20 fps
    targets, share = lock_targets(spots, held, 20.0, ankle_height=0.07)
    assert np.allclose(targets[20:60, 0, :2], spots[20:60, 0, :2].mean(axis=0))
    assert np.allclose(targets[20:60, 0, 2], 0.07)
    assert (share[20:60, 0] == 1).all() and 0 < share[19, 0] < 1 and 0 < share[60, 0] < 1  # eased in and out
    assert (share[:18, 0] == 0).all() and np.array_equal(targets[:18], spots[:18]) and (share[:, 1:] == 0).all()
    assert _runs(held[:, 0]) == [(20, 60)]


def test_a_held_foot_stays_put_on_the_floor(waves):
    """The whole solve with a held left ankle (2 s of the waving motion, whose human foot stands): the robot's ankle
    keeps one place on the floor while held (within 1 cm)."""
    robot = load_robot("h1")
    held = np.zeros((waves.frames, 4), bool)
    held[20:60, 0] = True
    joints = waves.joints.astype(float)
    targets, toes, _ = keypoint_targets(robot, joints, planted_feet(joints, waves.fps, held), held)
    q = solve_poses(robot, targets, toes, pelvis_axes(joints), held, waves.fps)
    ankle = _places(robot, mujoco.MjData(robot.own), q)[:, _feet_points(robot)[0]]
    inside = ankle[22:58]
    assert np.abs(inside - inside.mean(axis=0)).max() < 0.01 and abs(inside[:, 2].mean() - robot.rest_ankle) < 0.005


@pytest.mark.parametrize("name", ROBOTS)
def test_a_planted_foot_left_above_the_floor_is_brought_down(name):
    """Both feet planted, the right leg bent so that its foot is in the air: putting the base on the floor leaves the
    right sole above it; levelling brings it down (within LEVEL_HEIGHT), the left foot stays on the floor, nothing
    touches, no joint leaves its range, and a frame whose feet are level is left as it was."""
    robot = load_robot(name)
    suffix = "_joint" if name == "g1" else ""
    knee, hip, ankle = (7 + list(robot.joint_names).index(j + suffix) for j in (
        "right_knee", "right_hip_pitch", "right_ankle_pitch" if name == "g1" else "right_ankle"))
    q = np.repeat(robot.rest[None], 6, axis=0)
    bend = np.linspace(0.6, 0.8, 5)  # the knee bent, hip and ankle half as much back: the foot flat, 3-5 cm up
    q[1:, knee] += bend
    q[1:, hip] -= bend / 2
    q[1:, ankle] -= bend / 2
    planted = np.ones((6, 2), bool)
    floored = floor_feet(robot, q, planted)
    assert (sole_heights(robot, floored)[1:, 1] > 0.02).all()
    level = level_feet(robot, q, planted)
    low = sole_heights(robot, level)
    assert np.abs(low).max() <= LEVEL_HEIGHT and low.min() >= -1e-9
    assert (self_contacts(robot, level) == 0).all() and limit_violations(robot, level) == 0
    np.testing.assert_array_equal(level[0], floored[0])



def test_a_levelled_foot_that_would_touch_the_other_leg_is_stepped_apart_not_left_up():
    """Both feet planted, the G1's right leg bent 7.5 cm up and turned in toward the left one: bringing the foot
    down makes the legs touch, so the levelled frame is stepped again with them pushed apart (the foot ends on the
    floor) rather than taking only a share of the change (which left the sole 2.1 cm up)."""
    robot = load_robot("g1")
    index = {name: 7 + k for k, name in enumerate(robot.joint_names)}
    q = np.repeat(robot.rest[None], 3, axis=0)
    for joint, turn in (("right_knee", 0.98), ("right_hip_pitch", -0.49), ("right_ankle_pitch", -0.49),
                        ("right_hip_roll", 0.47), ("left_hip_roll", -0.07), ("right_hip_yaw", 0.33),
                        ("left_hip_yaw", 0.37)):
        q[:, index[joint + "_joint"]] += turn
    planted = np.ones((3, 2), bool)
    assert (sole_heights(robot, floor_feet(robot, q, planted))[:, 1] > 0.07).all()
    level = level_feet(robot, q, planted)
    low = sole_heights(robot, level)
    assert np.abs(low).max() <= LEVEL_HEIGHT and low.min() >= -1e-9
    assert (self_contacts(robot, level) == 0).all() and limit_violations(robot, level) == 0


@pytest.mark.parametrize("motion", sorted(LEVELLING_WINDOWS))
def test_a_foot_standing_on_its_toe_is_not_sunk_while_the_other_is_brought_down(motion):
    """H1 frames of generated motions (a dance, a bow, a turn) in which both feet stand, one on its toe's edge: the
    other planted sole is brought down to the floor (the toe kept from sinking through it, which made the base go
    up again and left that sole 2.3-2.9 cm up), and a frame whose levelling made the bodies touch is stepped on
    until it is level, not only until they part."""
    robot = load_robot("h1")
    q, planted = np.array(LEVELLING_WINDOWS[motion]["qpos"]), np.array(LEVELLING_WINDOWS[motion]["planted"], bool)
    level = level_feet(robot, q, planted)
    low = sole_heights(robot, level)
    assert low[planted].max() <= 0.02 and low.min() >= -1e-9
    assert (self_contacts(robot, level) == 0).all() and limit_violations(robot, level) == 0


@pytest.mark.parametrize("name", ROBOTS)
def test_a_planted_foot_is_brought_down_past_a_lifted_foot_on_the_floor(name):
    """The right foot planted but bent up, the left one not planted and flat on the floor (a shuffling swing foot):
    the left sole sets the base's height, and levelling must bend the right leg down, not lower the whole body (the
    left foot would go through the floor and the base be raised again)."""
    robot = load_robot(name)
    suffix = "_joint" if name == "g1" else ""
    knee, hip, ankle = (7 + list(robot.joint_names).index(j + suffix) for j in (
        "right_knee", "right_hip_pitch", "right_ankle_pitch" if name == "g1" else "right_ankle"))
    q = np.repeat(robot.rest[None], 4, axis=0)
    q[:, knee] += 0.6
    q[:, hip] -= 0.3
    q[:, ankle] -= 0.3
    planted = np.tile([False, True], (4, 1))
    assert (sole_heights(robot, floor_feet(robot, q, planted))[:, 1] > 0.02).all()
    low = sole_heights(robot, level_feet(robot, q, planted))
    assert (low[:, 1] <= LEVEL_HEIGHT).all() and low.min() >= -1e-9


def test_feet_side_by_side_are_moved_apart_to_the_gap_and_others_left():
    side = np.tile([0.0, 1.0, 0.3], (4, 1))  # left is +y (its height part does not count)
    ankles = np.array([[[0, 0.02, 0.1], [0, -0.02, 0.1]],  # 4 cm apart side by side: 6 cm short of 10
                       [[0, 0.2, 0.1], [0, -0.2, 0.1]],  # far apart
                       [[0.3, 0.0, 0.1], [0, 0.0, 0.1]],  # one ahead of the other by more than the gap
                       [[0, -0.01, 0.1], [0, 0.01, 0.1]]])  # crossed, side by side
    shift = feet_apart(ankles, side, 0.1)
    np.testing.assert_allclose(shift[0], [0, 0.03, 0], atol=1e-12)
    np.testing.assert_allclose(shift[1:3], 0, atol=1e-12)
    np.testing.assert_allclose(shift[3], [0, 0.06, 0], atol=1e-12)


@pytest.mark.parametrize("name", ROBOTS)
def test_the_ankles_targets_stay_apart_for_the_soles(name, waves):
    """Feet together in the motion: the ankles' targets (and their toe points) are the robot's min_gap apart."""
    robot = load_robot(name)
    joints = np.array(waves.joints, dtype=float)
    mid = (joints[:, 7] + joints[:, 8]) / 2
    joints[:, 7, [0, 2]], joints[:, 8, [0, 2]] = mid[:, [0, 2]], mid[:, [0, 2]]  # both ankles at one place
    targets, toes, _ = keypoint_targets(robot, joints, np.ones((len(joints), 2), bool))
    names = list(robot.human_names)
    gap = targets[:, names.index("left_ankle"), :2] - targets[:, names.index("right_ankle"), :2]
    np.testing.assert_allclose(np.linalg.norm(gap, axis=-1), robot.min_gap, rtol=1e-9)
    assert 0.05 < robot.min_gap < 0.2


@pytest.mark.parametrize("name", ROBOTS)
def test_held_feet_are_pinned_to_their_holds_place(name):
    """The base gliding 6 cm forward over 25 frames at 50 Hz, the legs as they are: the feet glide with it. With
    both feet held the whole time, pinning keeps every held ankle and toe point within 1 cm of one place on the
    floor plane, nothing touches and no joint leaves its range; feet not held are left where they are."""
    robot = load_robot(name)
    q = np.repeat(robot.rest[None], 25, axis=0)
    q[:, 0] += np.linspace(0.0, 0.06, 25)
    d = mujoco.MjData(robot.own)
    feet = _feet_points(robot)
    before = _places(robot, d, q)[:, feet, :2]
    held = np.ones((25, 4), bool)
    pinned = pin_feet(robot, q, held, 50.0)
    after = _places(robot, d, pinned)[:, feet, :2]
    assert np.linalg.norm(before - before.mean(axis=0), axis=-1).max() > 0.025
    assert np.linalg.norm(after - after.mean(axis=0), axis=-1).max() < 0.01
    assert (self_contacts(robot, pinned) == 0).all() and limit_violations(robot, pinned) == 0
    np.testing.assert_array_equal(pin_feet(robot, q, np.zeros((25, 4), bool), 50.0), q)


def test_the_files_hold_the_trajectory(tmp_path, waves):
    robot = load_robot("g1")
    motion = waves.to_robot("g1")
    arrays = npz_arrays(motion)
    assert np.array_equal(arrays["root_rot"][:, 3], motion.qpos[:, 3])  # x y z w
    assert list(arrays["joint_names"]) == list(robot.joint_names) and arrays["dof_pos"].shape[1] == 29
    columns = csv_columns(motion)
    assert columns[:8] == ["time", "base_x", "base_y", "base_z", "base_qw", "base_qx", "base_qy", "base_qz"]
    keys = write_keyframes(motion, robot, tmp_path / "keys.xml")
    model = mujoco.MjModel.from_xml_path(str(keys))
    key = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, "f00007")
    assert np.allclose(model.key_qpos[key], motion.qpos[7], atol=1e-6) and model.key_time[key] == 7 / 50


def test_smf_generate_writes_the_robots_files(tmp_path, capsys):
    assert main(["generate", "a person bows", "--seconds", "3", "--seed", "0", "--format", "json", "--robot", "h1",
                 "--robot-format", "npz,csv", "--out", str(tmp_path)]) == 0
    (npz,) = tmp_path.glob("*.h1.npz")
    data = np.load(npz)
    assert data["qpos"].shape == (148, 26) and float(data["fps"]) == 50.0
    (csv,) = tmp_path.glob("*.h1.csv")
    table = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert np.allclose(table[:, 1:], data["qpos"], atol=1e-6)


@pytest.mark.parametrize("args, message", [(["--robot", "r2d2"], "robot must be one of g1, h1 or an MJCF .xml file"),
                                           (["--robot", "g1", "--robot-format", "fbx"], "unknown robot format fbx"),
                                           (["--robot-format", "npz"], "go with --robot")])
def test_smf_generate_refuses_bad_robot_flags_in_one_line(tmp_path, capsys, args, message):
    assert main(["generate", "a person bows", "--out", str(tmp_path), *args]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1 and not list(tmp_path.iterdir())


def test_smf_convert_to_a_robot(tmp_path):
    out = tmp_path / "wave.csv"
    assert main(["convert", "example:wave-both-hands", str(out), "--robot", "g1"]) == 0
    assert out.read_text().splitlines()[0].startswith("time,base_x")


def test_http_answers_the_robots_trajectory(pipe):
    from serve.serve_helpers import call
    from stablemofusion.serve import create_app

    ok, bad, wrong_format = call(create_app(pipe, max_streams=0),
                                 ("POST", "/v1/generate", {"prompt": "a person bows", "seconds": 3, "seed": 0,
                                                           "robot": "g1"}),
                                 ("POST", "/v1/generate", {"prompt": "a person bows", "robot": "r2d2"}),
                                 ("POST", "/v1/generate?format=bvh", {"prompt": "a person bows", "robot": "g1"}))
    assert ok.status_code == 200, ok.text
    body = ok.json()
    assert body["robot"] == "g1" and body["fps"] == 50 and np.asarray(body["qpos"]).shape == (148, 36)
    assert body["columns"][:3] == ["base_x", "base_y", "base_z"] and body["seed"] == 0
    assert bad.status_code == 422 and wrong_format.status_code == 422 and "JSON" in wrong_format.json()["error"]


def test_without_mujoco_every_door_says_how_to_get_it(tmp_path, capsys, monkeypatch, pipe):
    """The robot extra missing: the CLI answers one line naming it (exit 2, before any generation), HTTP a 422."""
    from serve.serve_helpers import call
    from stablemofusion.robots import model as robot_model
    from stablemofusion.serve import checks, create_app

    monkeypatch.setattr(robot_model, "mujoco", None)
    monkeypatch.setattr(checks, "mujoco", None)
    robot_model.load_robot.cache_clear()
    try:
        assert main(["generate", "a person bows", "--robot", "g1", "--out", str(tmp_path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "pip install 'stablemofusion[robot]'" in err[0] and not list(tmp_path.iterdir())
        (answer,) = call(create_app(pipe, max_streams=0),
                         ("POST", "/v1/generate", {"prompt": "a person bows", "robot": "g1"}))
        assert answer.status_code == 422 and "MuJoCo is not installed" in answer.json()["error"]
    finally:
        robot_model.load_robot.cache_clear()


def test_a_generation_without_a_robot_does_not_load_mujoco(tmp_path):
    """MuJoCo (about 0.2 s to import) loads only when a robot is asked for, not on every `smf generate`."""
    import subprocess
    import sys

    code = ("import sys; from stablemofusion.cli.main import main; "
            f"rc = main(['generate', 'a person walks', '--seconds', '2', '--seed', '0', '--format', 'json', "
            f"'--engine', 'onnx', '--out', {str(tmp_path)!r}]); print(rc, 'mujoco' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.stdout.strip().splitlines()[-1] == "0 False", run.stdout + run.stderr
