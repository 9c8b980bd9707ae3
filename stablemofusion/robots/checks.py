"""What a robot trajectory is checked for, in MuJoCo: joints inside their ranges, no contact between the robot's own
bodies, planted feet on the floor and not sliding, joint speeds, and how closely the robot's sites follow their
(scaled) human joints. Each a function of arrays; :func:`check_motion` gathers them."""

from __future__ import annotations

import numpy as np

from ..motion.resample import resample
from .model import Robot, mujoco
from .retarget import (RobotMotion, count_self_contacts, foot_points, held_joints, keypoint_targets, planted_feet,
                       robot_frame, sole_heights)


def limit_violations(robot: Robot, qpos: np.ndarray, tolerance: float = 1e-9) -> int:
    """How many (frame, joint) values of (T, nq) poses lie outside their joint's range (rad)."""
    q = qpos[:, 7:]
    return int(((q < robot.ranges[:, 0] - tolerance) | (q > robot.ranges[:, 1] + tolerance)).sum())


def poses(robot: Robot, qpos: np.ndarray):
    """Yields (t, data) with each pose's kinematics computed, on one MjData."""
    d = mujoco.MjData(robot.model)
    for t in range(len(qpos)):
        d.qpos[:] = qpos[t]
        mujoco.mj_kinematics(robot.model, d)
        yield t, d


def self_contacts(robot: Robot, qpos: np.ndarray) -> np.ndarray:
    """(T,) the number of MuJoCo contacts between two of the robot's own bodies (penetrating: distance < 0) in
    each pose; contacts with the floor or the world are not counted."""
    m = robot.model
    out = np.zeros(len(qpos), dtype=int)
    for t, d in poses(robot, qpos):
        mujoco.mj_collision(m, d)
        out[t] = count_self_contacts(m, d)
    return out


def sole_tracks(robot: Robot, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, 2) each foot's lowest sole height above the floor (m); (T, 4, 2) on the floor (x, y) the points that
    stand for the human's left ankle, left toe, right ankle, right toe: the ankle sites and the soles' toe points."""
    return sole_heights(robot, qpos), foot_points(robot, qpos)[..., :2]


def site_positions(robot: Robot, qpos: np.ndarray) -> np.ndarray:
    """(T, K, 3) the driven sites' positions, metres."""
    out = np.empty((len(qpos), len(robot.sites), 3))
    for t, d in poses(robot, qpos):
        out[t] = d.site_xpos[robot.sites]
    return out


def slide_speeds(track: np.ndarray, held: np.ndarray, fps: float) -> np.ndarray:
    """Horizontal speeds (m/s) of (T, P, 2) points between frames where they are held (T, P) in both."""
    both = held[1:] & held[:-1]
    step = np.linalg.norm(np.diff(track, axis=0), axis=-1) * fps
    return step[both]


def joint_speeds(qpos: np.ndarray, fps: float) -> np.ndarray:
    """(J,) each joint's largest speed (rad/s) over (T, nq) poses at ``fps``."""
    if len(qpos) < 2:
        return np.zeros(qpos.shape[1] - 7)
    return np.abs(np.diff(qpos[:, 7:], axis=0)).max(axis=0) * fps


def check_motion(robot: Robot, motion: RobotMotion, joints: np.ndarray, fps: float,
                 contacts: np.ndarray | None = None) -> dict:
    """The checks of one trajectory against the (T, 22, 3) HumanML3D joints (at ``fps``, with the cleanup's
    ``contacts``) it was made from: the robot's heel and toe points slide while the human's ankle and toe are held,
    the human's (scaled to the robot) the same way."""
    q = motion.qpos
    joints = np.asarray(joints, float)
    touching = self_contacts(robot, q)
    low, points = sole_tracks(robot, q)
    held = held_joints(joints, fps, contacts)
    targets, _, scale = keypoint_targets(robot, joints, planted_feet(joints, fps, held), held)
    targets = resample(targets, fps, motion.fps)[:len(q)]
    errors = np.linalg.norm(site_positions(robot, q)[:len(targets)] - targets, axis=-1)
    robot_held = (resample(held.astype(float), fps, motion.fps) > 0.5)[:len(q)]
    human = robot_frame(joints)[:, [7, 10, 8, 11], :2] * scale  # the human's ankles and toes, scaled
    return {
        "frames": len(q),
        "limit_violations": limit_violations(robot, q),
        "self_contact_frames": int((touching > 0).sum()),
        "planted_sole_height_m": low[motion.planted],
        "sole_below_floor_m": float(max(0.0, -low.min())),
        "robot_slide_mps": slide_speeds(points, robot_held, motion.fps),
        "human_slide_mps": slide_speeds(human, held, fps),
        "tracking_error_m": errors.ravel(),
        "joint_speed_max_rads": joint_speeds(q, motion.fps),
    }
