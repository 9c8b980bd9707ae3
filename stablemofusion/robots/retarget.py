"""A motion's joints retargeted onto a humanoid robot, step by step, each a function of arrays:

1. :func:`robot_frame`: HumanML3D's Y-up, +Z-forward joints into MuJoCo's Z-up, +X-forward frame;
2. :func:`planted_feet`: the frames each foot stands (the cleanup's holds, else the kinematic contacts);
3. :func:`keypoint_targets`: the human joints scaled to the robot's leg length, raised so that a planted ankle sits
   at the robot's ankle height, and each foot's toe point from the human foot's heading and pitch;
4. :func:`solve_poses`: per frame, damped Gauss-Newton on the weighted target errors from the previous frame's
   pose, joints kept inside their ranges, the robot's own bodies pushed apart where they would touch;
5. :func:`lock_feet`: each held ankle and toe kept at its hold's mean place on the floor, eased in and out (foot
   locking);
6. :func:`resample_qpos`: the trajectory at the control rate (50 Hz), angles linearly, the base quaternion by
   normalised linear interpolation;
7. :func:`separate`: frames in which the robot's own bodies still touch pushed apart;
8. :func:`floor_feet`: the floating base raised or lowered so that a planted foot's sole is on the floor and no
   sole goes below it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..footskate.contacts import kinematic_contacts
from ..motion.resample import resample
from ..motion.rotation import matrix_to_quat
from .model import Robot, mujoco

CONTROL_FPS = 50.0
TOE_WEIGHT = 5.0
BASE_WEIGHT = 2.0  # the floating base turned as the human pelvis (two points 0.2 m off its origin)
BASE_LEVER = 0.2
COLLISION_MARGIN = 0.02  # m the retarget keeps between the robot's own bodies (interpolated frames between)
COLLISION_WEIGHT = 200.0
EXTRA_ITERATIONS = 8
HELD_BOOST = 10.0  # a held ankle's or toe's weight, times its usual one
SMOOTH_WEIGHT = 0.02  # pulls each joint toward the previous frames' pace
SEPARATE_HOLD = 0.01  # how much a pose being pushed apart holds to its own place (times the usual weights)
LOCK_BLEND = 0.1  # s over which a foot lock eases in before a hold and out after it
TOLERANCE = 1e-3  # rad (or m): a frame's solve stops when no coordinate moves more
POSTURE_WEIGHT = 1e-3  # pulls redundant joints (waist, wrists) toward the reference pose
DAMPING = 1e-2
MAX_STEP = 0.2  # rad (or m) one iteration may move any coordinate


@dataclass
class RobotMotion:
    """A robot's trajectory: ``qpos`` (T, nq) in MuJoCo's order (base position m, base quaternion w x y z, then
    the joints in rad, named ``joint_names``) at ``fps``; ``planted`` (T, 2) the frames the human's left and right
    foot stood; ``scale`` the human-to-robot size ratio used; ``robot`` its name; ``warnings`` one line each."""

    robot: str
    fps: float
    qpos: np.ndarray
    joint_names: tuple[str, ...]
    planted: np.ndarray
    scale: float
    warnings: list[str] = field(default_factory=list)

    @property
    def root_pos(self) -> np.ndarray:
        return self.qpos[:, :3]

    @property
    def root_quat(self) -> np.ndarray:
        """(T, 4) w x y z."""
        return self.qpos[:, 3:7]

    @property
    def dof_pos(self) -> np.ndarray:
        return self.qpos[:, 7:]

    @property
    def seconds(self) -> float:
        return len(self.qpos) / self.fps


def robot_frame(joints: np.ndarray) -> np.ndarray:
    """(..., 3) HumanML3D (x left, y up, z forward) -> MuJoCo (x forward, y left, z up), metres."""
    return joints[..., [2, 0, 1]]


def planted_feet(joints: np.ndarray, fps: float, contacts: np.ndarray | None = None) -> np.ndarray:
    """(T, 2) bool, left and right: a foot stands when its ankle or toe is held by the cleanup (``contacts``, (T, 4)
    in HumanML3D's left ankle, left toe, right ankle, right toe order), else by the kinematic contacts of the
    (T, 22, 3) HumanML3D joints."""
    held = held_joints(joints, fps, contacts)
    return np.stack([held[:, 0] | held[:, 1], held[:, 2] | held[:, 3]], axis=1)


def held_joints(joints: np.ndarray, fps: float, contacts: np.ndarray | None = None) -> np.ndarray:
    """(T, 4) bool: the cleanup's holds (``contacts``) of the left ankle, left toe, right ankle, right toe, else the
    kinematic contacts of the (T, 22, 3) HumanML3D joints."""
    return kinematic_contacts(joints, fps) if contacts is None else np.asarray(contacts, dtype=bool)


def _rest_height(values: np.ndarray, planted: np.ndarray) -> float:
    return float(np.median(values[planted])) if planted.any() else float(np.percentile(values, 5))


def keypoint_targets(robot: Robot, joints: np.ndarray, planted: np.ndarray,
                     held: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """The robot's targets from (T, 22, 3) HumanML3D joints: (T, K, 3) site targets (the robot's ``human`` joints),
    (T, 2, 3) toe points (left, right) in MuJoCo's frame, metres, and the scale (robot leg / human leg). ``planted``
    (T, 2) the frames each foot stands; ``held`` (T, 4) the held ankles and toes, whose targets are put on the floor
    (an ankle at the robot's standing ankle height, a toe point at 0)."""
    p = robot_frame(joints)
    leg = np.linalg.norm(p[:, 1] - p[:, 4], axis=-1) + np.linalg.norm(p[:, 4] - p[:, 7], axis=-1)
    scale = robot.leg / float(np.median(leg))
    ankles, toes = p[:, [7, 8]], p[:, [10, 11]]
    rest_ankle = _rest_height(ankles[..., 2], planted)
    lift = robot.rest_ankle - scale * rest_ankle
    targets = scale * p[:, robot.human]
    targets[..., 2] += lift
    # toe points: the robot's resting toe vector turned to the human foot's heading, tilted by its pitch off rest
    v = toes - ankles
    yaw = np.arctan2(v[..., 1], v[..., 0])
    pitch = np.arctan2(v[..., 2], np.linalg.norm(v[..., :2], axis=-1))
    tilt = pitch - _rest_height(pitch, planted)
    r = robot.rest_toe
    forward, up = r[0] * np.cos(tilt) - r[2] * np.sin(tilt), r[0] * np.sin(tilt) + r[2] * np.cos(tilt)
    offset = np.stack([forward * np.cos(yaw) - r[1] * np.sin(yaw), forward * np.sin(yaw) + r[1] * np.cos(yaw), up], -1)
    ankle_targets = scale * ankles
    ankle_targets[..., 2] += lift
    toe_targets = ankle_targets + offset
    if held is not None:
        for f, name in enumerate(("left_ankle", "right_ankle")):
            k = list(robot.human_names).index(name)
            targets[held[:, 2 * f], k, 2] = robot.rest_ankle
            toe_targets[held[:, 2 * f + 1], f, 2] = 0.0
    return targets, toe_targets, scale


def pelvis_axes(joints: np.ndarray) -> np.ndarray:
    """(T, 3, 3) the human pelvis's left and up axes (rows 1, 2) and forward (row 0) in MuJoCo's frame, from the
    (T, 22, 3) HumanML3D hips and first spine joint: the frame the robot's floating base is turned to."""
    p = robot_frame(joints)
    left = p[:, 1] - p[:, 2]
    left /= np.linalg.norm(left, axis=-1, keepdims=True)
    up = p[:, 3] - p[:, 0]
    up -= (up * left).sum(-1, keepdims=True) * left
    up /= np.linalg.norm(up, axis=-1, keepdims=True)
    return np.stack([np.cross(left, up), left, up], axis=1)


def count_self_contacts(model, data, below: float = 0.0) -> int:
    """How many of ``data``'s contacts (after ``mj_collision``) join two of the robot's own bodies closer than
    ``below`` (m; 0: penetrating)."""
    n = data.ncon
    if n == 0:
        return 0
    bodies = model.geom_bodyid[data.contact.geom[:n]]
    return int(((bodies > 0).all(axis=1) & (data.contact.dist[:n] < below)).sum())


class _Solver:
    """Per-frame IK on one MuJoCo data: weighted site and toe-point errors, posture prior, joint ranges, and
    self-contacts pushed apart."""

    def __init__(self, robot: Robot):
        self.r, self.m = robot, robot.model
        self.d = mujoco.MjData(self.m)
        nv = self.m.nv
        self.w = np.concatenate([np.repeat(robot.weights, 3), np.full(6, TOE_WEIGHT), np.full(6, BASE_WEIGHT)])
        K, names = len(robot.sites), list(robot.human_names)
        ankles = [names.index(j) for j in ("left_ankle", "right_ankle")]
        # the rows of the left ankle, left toe point, right ankle, right toe point (the held joints' order)
        self.feet_rows = [np.arange(3 * k, 3 * k + 3) for k in (ankles[0], K, ankles[1], K + 1)]
        self.prior = np.zeros(nv)
        self.prior[6:] = POSTURE_WEIGHT
        m = self.m
        self.dof_jnt = m.dof_jntid.copy()
        self.slide = np.array([int(m.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE) for j in m.dof_jntid])
        # moves[b, v]: dof v moves body b (its joint's body is b or an ancestor of b)
        self.moves = np.zeros((m.nbody, nv))
        for b in range(m.nbody):
            a = b
            while a > 0:
                self.moves[b, m.dof_bodyid == a] = 1.0
                a = int(m.body_parentid[a])
        self.point_bodies = np.concatenate([m.site_bodyid[robot.sites], [s.body for s in robot.soles],
                                            [robot.free_body] * 3])

    def _jacobians(self, points: np.ndarray, bodies: np.ndarray) -> np.ndarray:
        """(P, 3, nv) the world-frame position Jacobians of ``points`` (P, 3) fixed to ``bodies`` (P,), from the
        current kinematics (MuJoCo's free joint: world translation, then rotation about the body's own axes)."""
        d = self.d
        axis, anchor = d.xaxis[self.dof_jnt].copy(), d.xanchor[self.dof_jnt].copy()
        base = self.r.free_body
        axis[3:6] = d.xmat[base].reshape(3, 3).T  # rows: the base's own axes
        anchor[3:6] = d.xpos[base]
        arm = points[:, None] - anchor[None]  # (P, nv, 3)
        ax, ay, az = axis[None, :, 0], axis[None, :, 1], axis[None, :, 2]
        jac = np.stack([ay * arm[..., 2] - az * arm[..., 1], az * arm[..., 0] - ax * arm[..., 2],
                        ax * arm[..., 1] - ay * arm[..., 0]], axis=1)  # (P, 3, nv) rotation: axis x arm
        jac[:, :, self.slide] = axis[self.slide].T[None]
        jac[:, :, 0:3] = np.eye(3)
        return jac * self.moves[bodies][:, None, :]

    def weights(self, share: np.ndarray) -> np.ndarray:
        """The rows' weights with the feet's ankles and toe points weighted up by ``share`` (4,) of ``HELD_BOOST``
        (1: held, 0: free; the held joints' order)."""
        w = self.w.copy()
        for rows, k in zip(self.feet_rows, share):
            w[rows] *= 1 + (HELD_BOOST - 1) * k
        return w

    def toe_points(self) -> np.ndarray:
        """(2, 3) the soles' toe points, left and right, in the current kinematics."""
        d = self.d
        return np.stack([d.xmat[f.body].reshape(3, 3) @ f.toe + d.xpos[f.body] for f in self.r.soles])

    def here(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The current pose's own sites, toe points and base axes (the targets that keep it where it is)."""
        mujoco.mj_kinematics(self.m, self.d)
        return (self.d.site_xpos[self.r.sites].copy(), self.toe_points(),
                self.d.xmat[self.r.free_body].reshape(3, 3).T.copy())

    def _errors(self, sites: np.ndarray, toes: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m, d, r = self.m, self.d, self.r
        mujoco.mj_kinematics(m, d)
        base = r.free_body
        rot, origin = d.xmat[base].reshape(3, 3), d.xpos[base]
        points = np.concatenate([d.site_xpos[r.sites], self.toe_points(), [origin + BASE_LEVER * rot[:, 1],
                                                                 origin + BASE_LEVER * rot[:, 2], origin]])
        jac = self._jacobians(points, self.point_bodies)
        jac[-3:-1] -= jac[-1]
        want = np.concatenate([sites, toes, BASE_LEVER * axes[1:3]])
        have = np.concatenate([points[:-3], BASE_LEVER * rot[:, 1:3].T])
        return jac[:-1].reshape(-1, m.nv), (want - have).ravel()

    def _contacts(self) -> tuple[np.ndarray, np.ndarray]:
        """Rows (C, nv) and wanted increases (C,) of the distances between the robot's own bodies that are
        closer than the margin."""
        m, d = self.m, self.d
        mujoco.mj_collision(m, d)
        n = d.ncon
        pairs = m.geom_bodyid[d.contact.geom[:n]] if n else np.zeros((0, 2), int)
        near = (pairs > 0).all(axis=1) & (d.contact.dist[:n] < COLLISION_MARGIN) if n else np.zeros(0, bool)
        if not near.any():
            return np.zeros((0, m.nv)), np.zeros(0)
        points, normals = d.contact.pos[:n][near], d.contact.frame[:n, :3][near]
        j1, j2 = self._jacobians(points, pairs[near, 0]), self._jacobians(points, pairs[near, 1])
        rows = np.einsum("ck,ckv->cv", normals, j2 - j1)
        return rows, COLLISION_MARGIN - d.contact.dist[:n][near]

    def step(self, sites: np.ndarray, toes: np.ndarray, axes: np.ndarray, contacts: bool,
             weights: np.ndarray | None = None, smooth_to: np.ndarray | None = None) -> float:
        """One damped Gauss-Newton step toward the targets (``weights`` per row, else the usual ones), the joints
        also pulled toward ``smooth_to`` (the previous frames' pace); returns the largest coordinate change."""
        m, d = self.m, self.d
        jac, err = self._errors(sites, toes, axes)
        w = self.w if weights is None else weights
        a = jac.T @ (w[:, None] * jac)
        g = jac.T @ (w * err)
        if contacts:
            rows, want = self._contacts()
            if len(rows):
                a += COLLISION_WEIGHT * rows.T @ rows
                g += COLLISION_WEIGHT * rows.T @ want
        dq_prior = np.zeros(m.nv)
        dq_prior[6:] = d.qpos[7:] - self.r.rest[7:]
        a[np.diag_indices_from(a)] += DAMPING + self.prior
        g -= self.prior * dq_prior
        if smooth_to is not None:
            joints = np.arange(6, m.nv)
            a[joints, joints] += SMOOTH_WEIGHT
            g[6:] -= SMOOTH_WEIGHT * (d.qpos[7:] - smooth_to)
        dq = np.linalg.solve(a, g)
        q, (lo, hi) = d.qpos[7:], self.r.ranges.T
        stuck = ((q <= lo + 1e-9) & (dq[6:] < 0)) | ((q >= hi - 1e-9) & (dq[6:] > 0))
        if stuck.any():  # joints at a limit and pushed past it: held there, the others solved again
            held = np.concatenate([np.zeros(6, bool), stuck])
            a[held, :], a[:, held], g[held] = 0.0, 0.0, 0.0
            a[held, held] = 1.0
            dq = np.linalg.solve(a, g)
        dq *= min(1.0, MAX_STEP / max(float(np.abs(dq).max()), 1e-12))
        mujoco.mj_integratePos(m, d.qpos, dq, 1.0)
        d.qpos[7:] = np.clip(d.qpos[7:], self.r.ranges[:, 0], self.r.ranges[:, 1])
        return float(np.abs(dq).max())

    def self_contacts(self) -> int:
        mujoco.mj_kinematics(self.m, self.d)
        mujoco.mj_collision(self.m, self.d)
        return count_self_contacts(self.m, self.d, below=COLLISION_MARGIN / 2)


def solve_poses(robot: Robot, targets: np.ndarray, toes: np.ndarray, axes: np.ndarray,
                held: np.ndarray | None = None, iterations: int = 4, first_iterations: int = 60) -> np.ndarray:
    """(T, nq) poses tracking (T, K, 3) site targets, (T, 2, 3) toe points and the (T, 3, 3) pelvis axes
    (:func:`pelvis_axes`), frame after frame from the previous pose moved on at its pace (the first from the
    reference pose turned and moved to the first frame's pelvis): the ankles and toe points of ``held`` (T, 4)
    feet weighted up, the joints pulled toward the previous frames' pace (no sudden jumps), joints inside their
    ranges, self-contacts pushed apart (further iterations of a frame while any remain)."""
    s = _Solver(robot)
    held = np.zeros((len(targets), 4)) if held is None else held
    q = robot.rest.copy()
    pelvis = list(robot.human_names).index("pelvis")
    q[:2] = targets[0, pelvis, :2]
    q[3:7] = matrix_to_quat(axes[0].T)
    s.d.qpos[:] = q
    out = np.empty((len(targets), robot.model.nq))
    lo, hi = robot.ranges[:, 0], robot.ranges[:, 1]
    for t in range(len(targets)):
        pace = None
        if t > 1:  # from the previous pose moved on at the previous pace (the base's turn left to the solve)
            pace = np.clip(2 * out[t - 1, 7:] - out[t - 2, 7:], lo, hi)
            s.d.qpos[:3] += out[t - 1, :3] - out[t - 2, :3]
            s.d.qpos[7:] = pace
        weights = s.weights(held[t])
        for i in range(first_iterations if t == 0 else iterations):
            if s.step(targets[t], toes[t], axes[t], False, weights, pace) < TOLERANCE:
                break
        for _ in range(EXTRA_ITERATIONS):  # the robot's own bodies still touching: pushed apart further
            if not s.self_contacts():
                break
            s.step(targets[t], toes[t], axes[t], True, weights, pace)
        out[t] = s.d.qpos
    return out


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """The [start, stop) runs of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]))


def lock_feet(robot: Robot, qpos: np.ndarray, held: np.ndarray, fps: float, iterations: int = 2) -> np.ndarray:
    """(T, nq) poses whose held ankles and toe points (``held`` (T, 4): left ankle, left toe, right ankle, right
    toe) stay at the hold's mean place, on the floor (an ankle at the standing ankle height, a toe point at 0), the
    lock eased in and out over ``LOCK_BLEND`` seconds around each hold (poses at ``fps``): a few Gauss-Newton
    steps from each pose,
    every other target its own current place."""
    s = _Solver(robot)
    names = list(robot.human_names)
    ankles = [robot.sites[names.index(j)] for j in ("left_ankle", "right_ankle")]
    T = len(qpos)
    spots = np.empty((T, 4, 3))  # where each ankle site and toe point is
    for t in range(T):
        s.d.qpos[:] = qpos[t]
        mujoco.mj_kinematics(robot.model, s.d)
        spots[t, 0::2], spots[t, 1::2] = s.d.site_xpos[ankles], s.toe_points()
    anchors, share = spots.copy(), np.zeros((T, 4))  # where each is pulled to, and how fully (1 inside a hold)
    blend = max(1, round(LOCK_BLEND * fps))
    for j in range(4):
        for a, b in _runs(held[:, j]):
            spot = np.array([*spots[a:b, j, :2].mean(axis=0), robot.rest_ankle if j % 2 == 0 else 0.0])
            anchors[a:b, j], share[a:b, j] = spot, 1.0
            for k in range(1, blend + 1):  # eased in before the hold and out after it
                ease = 1 - k / (blend + 1)
                for t in (a - k, b - 1 + k):
                    if 0 <= t < T and ease > share[t, j]:
                        anchors[t, j], share[t, j] = spot, ease
    targets = spots + share[..., None] * (anchors - spots)
    feet = [names.index(j) for j in ("left_ankle", "right_ankle")]
    out = qpos.copy()
    for t in np.nonzero(share.any(axis=1))[0]:
        s.d.qpos[:] = qpos[t]
        sites, toes, axes = s.here()
        sites[feet], toes = targets[t, 0::2], targets[t, 1::2]
        weights = s.weights(share[t])
        for _ in range(iterations):
            if s.step(sites, toes, axes, False, weights) < TOLERANCE:
                break
        out[t] = s.d.qpos
    return out


def separate(robot: Robot, qpos: np.ndarray, iterations: int = 3 * EXTRA_ITERATIONS, rounds: int = 4) -> np.ndarray:
    """(T, nq) poses in which the robot's own bodies touch pushed apart (only those frames, each from its own pose,
    the targets its current sites, held loosely so that nothing else moves more than it must; up to ``rounds``
    rounds, each from where the last one stopped)."""
    s = _Solver(robot)
    out = qpos.copy()
    for t in range(len(qpos)):
        s.d.qpos[:] = qpos[t]
        for _ in range(rounds):
            if not s.self_contacts():
                break
            sites, toes, axes = s.here()
            for _ in range(iterations):
                s.step(sites, toes, axes, True, SEPARATE_HOLD * s.w)
                if not s.self_contacts():
                    break
        out[t] = s.d.qpos
    return out


def floor_feet(robot: Robot, qpos: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """(T, nq) poses with the base moved up or down per frame so that the lowest sole of a planted foot touches the
    floor (z = 0) and no sole is below it."""
    d = mujoco.MjData(robot.model)
    out = qpos.copy()
    for t in range(len(qpos)):
        d.qpos[:] = qpos[t]
        mujoco.mj_kinematics(robot.model, d)
        low = np.array([robot.sole_heights(d, sole).min() for sole in robot.soles])
        standing = low[planted[t]]
        out[t, 2] += max(-standing.min() if len(standing) else 0.0, -low.min())
    return out


def resample_qpos(qpos: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """(T', nq) at ``dst_fps`` over the same time: positions and angles linearly, the base quaternion normalised
    after linear interpolation (signs made continuous first)."""
    q = qpos.copy()
    quat = q[:, 3:7]
    for t in range(1, len(quat)):
        if quat[t] @ quat[t - 1] < 0:
            quat[t] = -quat[t]
    out = resample(q, src_fps, dst_fps)
    out[:, 3:7] /= np.linalg.norm(out[:, 3:7], axis=1, keepdims=True)
    return out


def retarget(robot: Robot, joints: np.ndarray, fps: float, contacts: np.ndarray | None = None,
             out_fps: float = CONTROL_FPS) -> RobotMotion:
    """(T, 22, 3) HumanML3D joints (metres, at ``fps``; ``contacts`` the cleanup's (T, 4) holds, None: detected)
    -> the robot's trajectory at ``out_fps``: solved at the motion's rate, resampled, then put on the floor."""
    joints = np.asarray(joints, dtype=float)
    held = held_joints(joints, fps, contacts)
    planted = planted_feet(joints, fps, held)
    targets, toes, scale = keypoint_targets(robot, joints, planted, held)
    qpos = lock_feet(robot, solve_poses(robot, targets, toes, pelvis_axes(joints), held), held, fps)
    qpos = resample_qpos(qpos, fps, out_fps)
    planted = resample(planted.astype(float), fps, out_fps) > 0.5
    qpos = floor_feet(robot, separate(robot, qpos), planted)
    return RobotMotion(robot.name, out_fps, qpos, robot.joint_names, planted, scale)
