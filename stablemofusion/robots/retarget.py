"""A motion's joints retargeted onto a humanoid robot, step by step, each a function of arrays:

1. :func:`robot_frame`: HumanML3D's Y-up, +Z-forward joints into MuJoCo's Z-up, +X-forward frame;
2. :func:`planted_feet`: the frames each foot stands (the cleanup's holds, else the kinematic contacts);
3. :func:`keypoint_targets`: the human joints scaled to the robot's leg length, raised so that a planted ankle sits
   at the robot's ankle height, the ankles kept far enough apart for the robot's soles (:func:`feet_apart`), and
   each foot's toe point from the human foot's heading and pitch;
4. :func:`solve_poses`: every frame at once, damped Gauss-Newton on the weighted target errors (the robot's
   kinematics from MuJoCo, its Jacobians for all frames together: :mod:`.kinematics`), held feet locked
   (:func:`lock_targets`: each held ankle and toe kept at its hold's mean place on the floor, eased in and out),
   joints kept inside their ranges, the robot's own bodies pushed apart where they overlap;
5. :func:`resample_qpos`: the trajectory at the control rate (50 Hz), angles linearly, the base quaternion by
   normalised linear interpolation;
6. :func:`pin_feet`: the frames whose held ankles or toe points drifted off their holds in between solved again;
7. :func:`separate`: frames in which the robot's own bodies still overlap pushed apart, standing feet held;
8. :func:`level_feet`: the floating base raised or lowered so that a planted foot's sole is on the floor and no
   sole goes below it (:func:`floor_feet`), a planted foot still above it brought down.

The MuJoCo data each step works on is the robot's per-thread scratch (:meth:`~.model.Robot.scratch`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ..footskate.contacts import kinematic_contacts
from ..motion.resample import resample
from ..motion.rotation import matrix_to_quat
from . import kinematics as kin
from .model import FOOT_JOINTS, Robot, mujoco

CONTROL_FPS = 50.0
TOE_WEIGHT = 5.0
BASE_WEIGHT = 2.0  # the floating base turned as the human pelvis (two points 0.2 m off its origin)
BASE_LEVER = 0.2
CLEARANCE = 0.01  # m the retarget pushes the robot's own bodies apart to (interpolated frames lie between)
BUILT_CLEARANCE = 0.001  # m a pair of geoms already near at the reference pose is pushed apart to where it overlaps
COLLISION_WEIGHT = 200.0  # of a contact's or a lifted sole's row, against the targets' weights
COARSE_STRIDE = 3  # the first pass solves every COARSE_STRIDE-th frame,
COARSE_ITERATIONS = 3  # this many iterations from the reference pose,
LOCK_ITERATIONS = 2  # then this many with the feet locked (the frames between interpolated),
ITERATIONS = 1  # then every frame this many
SETTLE_ITERATIONS = 6  # at most, then of the frames whose own bodies are still too close
SEPARATE_ITERATIONS = 6  # at most, per round of pushing the robot's own bodies apart at the control rate
HELD_BOOST = 10.0  # a held ankle's or toe's weight, times its usual one
SMOOTH_WEIGHT = 0.02  # pulls each joint toward its neighbouring frames' mean
SEPARATE_HOLD = 0.01  # how much a pose being pushed apart holds to its own place (times the usual weights)
SEPARATE_REACH = 1  # frames on either side pushed apart with it
SEPARATE_SMOOTH = 0.05  # how much each joint is pulled toward its neighbours' meanwhile
LOCK_BLEND = 0.1  # s over which a foot lock eases in before a hold and out after it
TOLERANCE = 1e-3  # rad (or m): a pass stops when no coordinate of any frame moves more
POSTURE_WEIGHT = 1e-3  # pulls redundant joints (waist, wrists) toward the reference pose
DAMPING = 1e-2
MAX_STEP = 0.4  # rad (or m) one iteration may move any coordinate
PIN_DRIFT = 0.005  # m a held ankle or toe point may be off its hold's place before pin_feet moves its frame
PIN_ITERATIONS = 2
PIN_SHARE = 0.5  # a lock eased in or out moves its point's frame only from this share of it on (the nearer half)
PIN_HOLD = 1.0  # how much the rest of a pose being pinned holds to its place (times the usual weights)
LEVEL_HEIGHT = 0.015  # m: a planted foot's lowest sole point higher than this is brought down (level_feet)
LEVEL_ITERATIONS = 4
LEVEL_SHARES = (0.75, 0.5, 0.25, 0.0)  # of a levelling change tried in turn where the whole of it makes bodies touch
LEVEL_SMOOTH = 0.05  # how much each joint is pulled toward its neighbours' meanwhile


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
    (an ankle at the robot's standing ankle height, a toe point at 0). Ankles nearer than the robot's ``min_gap``
    (feet side by side) are moved apart sideways, each by half the lack, their toe points with them."""
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
    feet = [list(robot.human_names).index(name) for name in FOOT_JOINTS]  # the ankles' targets among the sites'
    shift = feet_apart(targets[:, feet], p[:, 1] - p[:, 2], robot.min_gap)
    targets[:, feet] += np.stack([shift, -shift], axis=1)
    toe_targets = targets[:, feet] + offset
    if held is not None:
        for f, k in enumerate(feet):
            targets[held[:, 2 * f], k, 2] = robot.rest_ankle
            toe_targets[held[:, 2 * f + 1], f, 2] = 0.0
    return targets, toe_targets, scale


def feet_apart(ankles: np.ndarray, side: np.ndarray, gap: float) -> np.ndarray:
    """(T, 3) how far to move the left ankle (the right one the opposite way) so that the (T, 2, 3) left and right
    ankles are at least ``gap`` apart on the floor plane (m), along (T, 3) the body's left direction ``side`` (only
    its floor-plane part counts): zero where they are, else half the lack each."""
    left = side * np.array([1.0, 1.0, 0.0])
    left /= np.maximum(np.linalg.norm(left, axis=-1, keepdims=True), 1e-9)
    d = (ankles[:, 0] - ankles[:, 1]) * np.array([1.0, 1.0, 0.0])
    lateral = (d * left).sum(-1)
    along = np.linalg.norm(d - lateral[:, None] * left, axis=-1)
    need = np.sqrt(np.maximum(gap ** 2 - along ** 2, 0.0))
    return (np.maximum(need - lateral, 0.0) / 2)[:, None] * left


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


def count_self_contacts(model, data) -> int:
    """How many of ``data``'s contacts (after ``mj_collision``) join two of the robot's own bodies that overlap."""
    n = data.ncon
    if n == 0:
        return 0
    bodies = model.geom_bodyid[data.contact.geom[:n]]
    return int(((bodies > 0).all(axis=1) & (data.contact.dist[:n] < 0)).sum())


@lru_cache(maxsize=8)
def _layout(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """The points the solve moves: (P,) bodies and (P, 3) places in their frames, the driven sites, the two soles'
    toe points (left, right), then two points ``BASE_LEVER`` along the base's left and up axes (read-only)."""
    m = robot.model
    bodies = np.concatenate([m.site_bodyid[robot.sites], [f.body for f in robot.soles], [robot.free_body] * 2])
    local = np.concatenate([m.site_pos[robot.sites], [f.toe for f in robot.soles],
                            [[0.0, BASE_LEVER, 0.0], [0.0, 0.0, BASE_LEVER]]])
    bodies.flags.writeable = local.flags.writeable = False  # made once per robot, shared by every call
    return bodies, local


def _wanted(targets: np.ndarray, toes: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(T, P, 3) where the :func:`_layout` points should be: site targets, toe points, and the pelvis's left and
    up axes ``BASE_LEVER`` long (relative to the base, whose place is left to the sites)."""
    return np.concatenate([targets, toes, BASE_LEVER * axes[:, 1:3]], axis=1)


def _weights(robot: Robot, share: np.ndarray) -> np.ndarray:
    """(T, 3P) the rows' weights, the feet's ankles and toe points weighted up by ``share`` (T, 4) of
    ``HELD_BOOST`` (1: held, 0: free; left ankle, left toe, right ankle, right toe)."""
    K = len(robot.sites)
    w = np.concatenate([np.repeat(robot.weights, 3), np.full(6, TOE_WEIGHT), np.full(6, BASE_WEIGHT)])
    w = np.repeat(w[None], len(share), axis=0)
    names = list(robot.human_names)
    for j, point in enumerate((names.index("left_ankle"), K, names.index("right_ankle"), K + 1)):
        w[:, 3 * point:3 * point + 3] *= 1 + (HELD_BOOST - 1) * share[:, j, None]
    return w


def _places(robot: Robot, data, qpos: np.ndarray) -> np.ndarray:
    """(T, P, 3) the :func:`_layout` points of (T, nq) poses (kinematics on ``data``, an ``MjData`` of the robot's
    model or a copy), the base's two as offsets from the base."""
    return _places_of(robot, kin.forward(data.model, data, robot.chain, qpos))


def _places_of(robot: Robot, poses: kin.Poses) -> np.ndarray:
    """:func:`_places` from the poses' kinematics."""
    at = kin.points(poses, *_layout(robot))
    at[:, -2:] -= poses.pos[:, robot.free_body, None]
    return at


def _contact_rows(robot: Robot, data, qpos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For (T, nq) poses: rows (T, C, nv) of the distances between the robot's own bodies where MuJoCo finds them in
    contact on ``data`` (an ``MjData`` of ``robot.own``: where they overlap; of ``robot.near``: up to ``NEAR``
    apart), each pair of geoms once, at its closest point, as functions of the velocity coordinates; and the
    changes (T, C) wanted of them: up to ``CLEARANCE`` where closer, none where farther (a near pair is kept from
    closing in; a pair already that near at the reference pose only kept from overlapping: pushed to
    ``BUILT_CLEARANCE`` where it does). Rows of zeros where a pose has fewer than C."""
    m = data.model
    found = []  # (frame, geoms, distances, points, normals) of every pose with contacts

    def collide(t: int, data) -> None:
        mujoco.mj_collision(m, data)
        n = data.ncon
        if n:
            c = data.contact
            found.append((np.full(n, t), c.geom[:n].copy(), c.dist[:n].copy(), c.pos[:n].copy(),
                          c.frame[:n, :3].copy()))

    poses = kin.forward(m, data, robot.chain, qpos, collide)
    T = len(qpos)
    frame, geoms, dist, points, normals = (np.concatenate(x) for x in zip(*found)) if found else (
        np.zeros(0, int), np.zeros((0, 2), int), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))
    built = robot.rest_near[geoms[:, 0], geoms[:, 1]]  # pairs near at the reference pose: kept from overlapping
    keep = np.nonzero((m.geom_bodyid[geoms] > 0).all(axis=1) & (~built | (dist < 0)))[0]
    pair = frame[keep] * m.ngeom ** 2 + geoms[keep, 0] * m.ngeom + geoms[keep, 1]
    order = np.lexsort((dist[keep], pair))  # by frame and pair of geoms, the closest first
    keep = keep[order][np.unique(pair[order], return_index=True)[1]]  # each pair of geoms once, its closest point
    f = frame[keep]
    slot = np.arange(len(keep)) - np.searchsorted(f, f)  # its place among its frame's pairs
    C = int(slot.max()) + 1 if len(keep) else 1
    at, normal, bodies, more = np.zeros((T, C, 3)), np.zeros((T, C, 3)), np.zeros((T, C, 2), int), np.zeros((T, C))
    at[f, slot], normal[f, slot], bodies[f, slot] = points[keep], normals[keep], m.geom_bodyid[geoms[keep]]
    more[f, slot] = np.maximum(np.where(built[keep], BUILT_CLEARANCE, CLEARANCE) - dist[keep], 0.0)
    jac = kin.jacobians(robot.chain, poses, np.concatenate([at, at], 1),
                        np.concatenate([bodies[..., 0], bodies[..., 1]], 1))
    return np.einsum("tck,tckv->tcv", normal, jac[:, C:] - jac[:, :C]), more


def _touching(robot: Robot, data, qpos: np.ndarray) -> np.ndarray:
    """(T,) bool: the poses in which two of the robot's own bodies overlap (kinematics and collisions on ``data``,
    an ``MjData`` of ``robot.own``)."""
    out, q, model = np.zeros(len(qpos), dtype=bool), data.qpos, data.model
    for t in range(len(qpos)):
        q[:] = qpos[t]
        mujoco.mj_kinematics(model, data)
        out[t] = _overlap(data)
    return out


def _overlap(data) -> bool:
    """Whether two of the robot's own bodies overlap in ``data``'s pose (its kinematics computed; collisions found
    here)."""
    mujoco.mj_collision(data.model, data)
    return data.ncon > 0 and count_self_contacts(data.model, data) > 0


def _touching_poses(robot: Robot, data, qpos: np.ndarray) -> tuple[kin.Poses, np.ndarray]:
    """:func:`_touching` of (T, nq) poses and, from the same kinematics, their :class:`~.kinematics.Poses`."""
    out = np.zeros(len(qpos), dtype=bool)

    def check(t: int, data) -> None:
        out[t] = _overlap(data)

    return kin.forward(data.model, data, robot.chain, qpos, check), out


def _step(robot: Robot, data, qpos: np.ndarray, wanted: np.ndarray, weights: np.ndarray, pull: np.ndarray | None = None,
          contacts: tuple[np.ndarray, np.ndarray] | None = None, smooth: float = SMOOTH_WEIGHT,
          lifted: np.ndarray | None = None, poses: kin.Poses | None = None) -> tuple[np.ndarray, np.ndarray]:
    """One damped Gauss-Newton step of every pose (T, nq) toward its ``wanted`` (T, P, 3) points, rows weighted by
    ``weights`` (T, 3P): redundant joints pulled a little toward the reference pose, joints toward ``pull`` (T, J)
    where given (by ``smooth``), the distances of ``contacts`` (rows, increases: :func:`_contact_rows`) pushed up,
    the soles of ``lifted`` (T, 2) feet (left, right: those not standing) kept from going below the floor, joints at
    a limit and pushed past it held there (an active set), no coordinate moved more than ``MAX_STEP``; ``poses`` the
    poses' kinematics if already known. Returns the new poses (joints clipped to their ranges) and each pose's largest
    coordinate change (T,)."""
    chain, T = robot.chain, len(qpos)
    nv = chain.nv
    poses = kin.forward(data.model, data, chain, qpos) if poses is None else poses
    bodies, local = _layout(robot)
    at = kin.points(poses, bodies, local)
    jac = kin.jacobians(chain, poses, at, bodies, np.float32)  # a search direction: single precision will do
    jac[:, -2:, :, :3] = 0.0  # the base's axes do not move with its place
    at[:, -2:] -= poses.pos[:, robot.free_body, None]
    jac, err = jac.reshape(T, -1, nv), (wanted - at).reshape(T, -1)
    a = np.matmul(np.swapaxes(jac, 1, 2) * weights[:, None, :].astype(np.float32), jac).astype(float)
    g = np.einsum("trv,tr->tv", jac, weights * err)
    if contacts is not None:
        rows, more = contacts
        a += COLLISION_WEIGHT * np.matmul(np.swapaxes(rows, 1, 2), rows)
        g += COLLISION_WEIGHT * np.einsum("tcv,tc->tv", rows, more)
    floor = []  # each lifted foot's sole points: their heights (T, S) and the heights' rows (T, S, nv)
    if lifted is not None and lifted.any():
        for f, sole in enumerate(robot.soles):
            body = np.full(len(sole.points), sole.body)
            points = kin.points(poses, body, sole.points)
            rows = kin.height_jacobians(chain, poses, points, body)
            floor.append((np.where(lifted[:, f, None], points[..., 2] - sole.radius, np.inf), rows))
    diagonal = np.full(nv, DAMPING)
    diagonal[6:] += POSTURE_WEIGHT
    g[:, 6:] -= POSTURE_WEIGHT * (qpos[:, 7:] - robot.rest[7:])
    if pull is not None:
        diagonal[6:] += smooth
        g[:, 6:] -= smooth * (qpos[:, 7:] - pull)
    a[:, np.arange(nv), np.arange(nv)] += diagonal
    q, (lo, hi) = qpos[:, 7:], robot.ranges.T
    # joints at a limit that the gradient pushes past it: held there (an active set), the others solved
    stuck = ((q <= lo + 1e-9) & (g[:, 6:] < 0)) | ((q >= hi - 1e-9) & (g[:, 6:] > 0))
    free = np.concatenate([np.ones((T, 6), bool), ~stuck], axis=1)
    some = np.nonzero(stuck.any(axis=1))[0]  # a stuck joint's row and column: the identity's
    a[some] = a[some] * (free[some, :, None] & free[some, None, :]) + np.eye(nv) * ~free[some, :, None]
    dq = kin.solve_spd(a, g * free)
    # a lifted sole point that is, or would be, below the floor: held on it (the constraint made active), solved again
    under = [(height < 0) | (height + np.einsum("tsv,tv->ts", rows, dq) < 0) for height, rows in floor]
    again = np.nonzero(np.any([u.any(axis=1) for u in under], axis=0))[0] if floor else np.zeros(0, int)
    if len(again):
        for (height, rows), u in zip(floor, under):
            r = rows[again] * u[again, :, None] * free[again, None]
            a[again] += COLLISION_WEIGHT * np.matmul(np.swapaxes(r, 1, 2), r)
            g[again] -= COLLISION_WEIGHT * np.einsum("tsv,ts->tv", r, np.where(u[again], height[again], 0.0))
        dq[again] = kin.solve_spd(a[again], g[again] * free[again])
    change = np.abs(dq).max(axis=1)
    dq *= np.minimum(1.0, MAX_STEP / np.maximum(change, 1e-12))[:, None]
    out = kin.integrate(qpos, dq)
    out[:, 7:] = np.clip(out[:, 7:], lo, hi)
    return out, change


def _neighbours(qpos: np.ndarray) -> np.ndarray:
    """(T, J) each pose's joints' mean over the poses before and after it (the one there is at either end)."""
    q = qpos[:, 7:]
    if len(q) < 2:
        return q.copy()
    before, after = np.concatenate([q[1:2], q[:-1]]), np.concatenate([q[1:], q[-2:-1]])
    return (before + after) / 2


def _iterate(robot: Robot, data, qpos: np.ndarray, wanted: np.ndarray, weights: np.ndarray, iterations: int,
             near=None, lifted: np.ndarray | None = None) -> np.ndarray:
    """``iterations`` :func:`_step` of every pose (kinematics on ``data``, an ``MjData`` of ``robot.own``), each
    pulled toward its neighbours' mean (no sudden jumps) and, given ``near`` (an ``MjData`` of ``robot.near``), the
    robot's own bodies kept apart in every pose in which they have overlapped before a step (their pairs up to
    ``NEAR`` apart pushed out to ``CLEARANCE`` or held there: :func:`_contact_rows`), the soles of ``lifted``
    (T, 2) feet kept above the floor; stops early once no coordinate moves more than ``TOLERANCE``."""
    apart = np.zeros(len(qpos), bool)
    for _ in range(iterations):
        contacts = poses = None
        if near is not None:
            poses, now = _touching_poses(robot, data, qpos)
            apart |= now
            touching = np.nonzero(apart)[0]
            if len(touching):
                rows, more = _contact_rows(robot, near, qpos[touching])
                contacts = (np.zeros((len(qpos),) + rows.shape[1:]), np.zeros((len(qpos), rows.shape[1])))
                contacts[0][touching], contacts[1][touching] = rows, more
        qpos, change = _step(robot, data, qpos, wanted, weights, _neighbours(qpos), contacts, lifted=lifted,
                             poses=poses)
        if change.max() < TOLERANCE:
            break
    return qpos


def _between(qpos: np.ndarray, src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(len(dst), nq) poses at (fractional) frame indices ``dst`` from poses at indices ``src``: positions and
    angles linearly, the base quaternion normalised after linear interpolation (signs made continuous)."""
    q = qpos.copy()
    flip = np.cumprod(np.where(np.einsum("ti,ti->t", q[1:, 3:7], q[:-1, 3:7]) < 0, -1.0, 1.0))
    q[1:, 3:7] *= flip[:, None]
    out = np.stack([np.interp(dst, src, q[:, k]) for k in range(q.shape[1])], axis=1)
    out[:, 3:7] /= np.linalg.norm(out[:, 3:7], axis=1, keepdims=True)
    return out


def solve_poses(robot: Robot, targets: np.ndarray, toes: np.ndarray, axes: np.ndarray,
                held: np.ndarray | None = None, fps: float | None = None, iterations: int = ITERATIONS,
                coarse_iterations: int = COARSE_ITERATIONS) -> np.ndarray:
    """(T, nq) poses tracking (T, K, 3) site targets, (T, 2, 3) toe points and the (T, 3, 3) pelvis axes
    (:func:`pelvis_axes`), all frames at once, by damped Gauss-Newton (:func:`_step`): every ``COARSE_STRIDE``-th
    frame first, from the reference pose turned and moved to its pelvis (``coarse_iterations``); given the poses'
    ``fps``, the ankles and toe points of ``held`` (T, 4) feet then locked where that pass put them
    (:func:`lock_targets`) and those frames solved again (``LOCK_ITERATIONS``); then every frame, the ones between
    started halfway (``iterations``); then the frames whose own bodies still overlap (``SETTLE_ITERATIONS`` at
    most). Held feet weigh more; a foot that does not stand is kept above the floor; each frame's joints are pulled
    toward its neighbours'; joints stay inside their ranges; in the pass over every frame, once the robot's own
    bodies overlap in a frame, they are pushed apart and kept apart (:func:`_iterate`; the passes over the key
    frames leave that to it)."""
    T = len(targets)
    held = np.zeros((T, 4), bool) if held is None else np.asarray(held, bool)
    wanted, weights = _wanted(targets, toes, axes), _weights(robot, held.astype(float))
    q = np.repeat(robot.rest[None], T, axis=0)
    q[:, :2] = targets[:, list(robot.human_names).index("pelvis"), :2]
    q[:, 3:7] = matrix_to_quat(np.swapaxes(axes, 1, 2))
    keys = np.unique(np.concatenate([np.arange(0, T, COARSE_STRIDE), [T - 1]]))
    data, near = robot.scratch()
    lifted = ~(held[:, 0::2] | held[:, 1::2])  # a foot not standing: its sole kept above the floor
    q[keys] = _iterate(robot, data, q[keys], wanted[keys], weights[keys], coarse_iterations, lifted=lifted[keys])
    q = _between(q[keys], keys, np.arange(T))
    if fps is not None and held.any():
        feet = _feet_points(robot)
        wanted[:, feet], share = lock_targets(_places(robot, data, q)[:, feet], held, fps, robot.rest_ankle)
        weights = _weights(robot, np.maximum(held, share))
        q[keys] = _iterate(robot, data, q[keys], wanted[keys], weights[keys], LOCK_ITERATIONS, lifted=lifted[keys])
        q = _between(q[keys], keys, np.arange(T))
    q = _iterate(robot, data, q, wanted, weights, iterations, near, lifted)
    close = np.nonzero(_touching(robot, data, q))[0]
    for _ in range(SETTLE_ITERATIONS):  # frames whose own bodies still overlap: pushed apart further
        if not len(close):
            break
        q[close], _ = _step(robot, data, q[close], wanted[close], weights[close], _neighbours(q)[close],
                            _contact_rows(robot, near, q[close]), lifted=lifted[close])
        close = close[_touching(robot, data, q[close])]
    return q


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """The [start, stop) runs of True in a (T,) bool array."""
    edges = np.diff(np.concatenate([[0], mask.astype(int), [0]]))
    return list(zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]))


def _feet_points(robot: Robot) -> np.ndarray:
    """(4,) the :func:`_layout` points of the left ankle, left toe, right ankle, right toe (the held order)."""
    names, K = list(robot.human_names), len(robot.sites)
    return np.array([names.index("left_ankle"), K, names.index("right_ankle"), K + 1])


def _feet_rows(robot: Robot) -> np.ndarray:
    """(12,) the rows (x, y, z) of the left ankle, left toe, right ankle and right toe points among the (3P,) rows of
    :func:`_weights`."""
    return np.repeat(_feet_points(robot), 3) * 3 + np.tile(np.arange(3), 4)


def _firm_feet(robot: Robot, loose: np.ndarray, share: np.ndarray) -> np.ndarray:
    """(F, 3P) weights ``loose`` with the feet points' rows raised by their held weights times ``share`` (F, 4)."""
    rows, out = _feet_rows(robot), loose.copy()
    out[:, rows] += _weights(robot, share)[:, rows] * np.repeat(share, 3, axis=1)
    return out


def lock_targets(spots: np.ndarray, held: np.ndarray, fps: float, ankle_height: float) -> tuple[np.ndarray, np.ndarray]:
    """Foot locking, as games do it: (T, 4, 3) targets for the ankles and toe points at ``spots`` (T, 4, 3; left
    ankle, left toe, right ankle, right toe, metres, at ``fps``) that keep each one held (``held`` (T, 4)) at its
    hold's mean place on the floor (an ankle at ``ankle_height``, a toe point at 0), and (T, 4) how fully (1 inside
    a hold), the lock eased in and out over ``LOCK_BLEND`` seconds around each hold (elsewhere the spot itself)."""
    T = len(spots)
    anchors, share = spots.copy(), np.zeros((T, 4))
    blend = max(1, round(LOCK_BLEND * fps))
    t = np.arange(T)
    for j in range(4):
        runs = _runs(held[:, j])
        if not runs:
            continue
        starts, stops = (np.array(x) for x in zip(*runs))
        spot = np.array([[*spots[a:b, j, :2].mean(axis=0), ankle_height if j % 2 == 0 else 0.0] for a, b in runs])
        before = np.searchsorted(starts, t, side="right") - 1  # the last hold starting at or before each frame
        after = before + 1  # the first starting after it
        gap_before = np.where(before >= 0, t - (stops[before.clip(0)] - 1), T)  # frames since its last (0: inside)
        gap_after = np.where(after < len(runs), starts[after.clip(max=len(runs) - 1)] - t, T)
        nearer = np.where(gap_before <= gap_after, before, after)  # a tie goes to the earlier hold
        gap = np.minimum(np.maximum(gap_before, 0), gap_after)
        eased = gap <= blend  # inside a hold (gap 0) or eased in before it or out after it
        anchors[eased, j] = spot[nearer[eased]]
        share[eased, j] = 1 - gap[eased] / (blend + 1)
    return spots + share[..., None] * (anchors - spots), share


def pin_feet(robot: Robot, qpos: np.ndarray, held: np.ndarray, fps: float,
             iterations: int = PIN_ITERATIONS) -> np.ndarray:
    """(T, nq) poses (at ``fps``) whose held ankles and toe points (``held`` (T, 4): left ankle, left toe, right
    ankle, right toe) are moved on the floor plane to their hold's mean place, eased in and out
    (:func:`lock_targets`; their heights left as they are), in the frames where one is more than ``PIN_DRIFT`` off
    it and eased at least ``PIN_SHARE`` in: those points held firmly there (their held weights, eased with the
    lock), the rest to where it was (its usual weights times ``PIN_HOLD``), each joint pulled toward its
    neighbours'; up to ``iterations`` steps of the frames still that far off, a frame whose step makes the robot's
    own bodies touch stepped again from where it was with them kept apart (:func:`_contact_rows`)."""
    data, near = robot.scratch()
    feet = _feet_points(robot)
    poses = kin.forward(robot.own, data, robot.chain, qpos)
    places, low = _places_of(robot, poses), _soles_of(robot, poses)
    spots = places[:, feet]
    targets, share = lock_targets(spots, held, fps, robot.rest_ankle)
    targets[..., 2] = spots[..., 2]
    off = (np.linalg.norm((targets - spots)[..., :2], axis=-1) > PIN_DRIFT) & (share >= PIN_SHARE)
    frames = np.nonzero(off.any(axis=1))[0]
    out = qpos.copy()
    if not len(frames):
        return out
    weights = _firm_feet(robot, PIN_HOLD * _weights(robot, np.zeros((len(frames), 4))), share[frames])
    here = places[frames]  # the rest held to where it was
    here[:, feet] = targets[frames]
    moving = np.arange(len(frames))  # the frames still more than PIN_DRIFT off (their places in ``frames``)
    for _ in range(iterations):
        at, pull = frames[moving], _neighbours(out)[frames[moving]]
        now, goal, weight = out[at], here[moving], weights[moving]
        step, change = _step(robot, data, now, goal, weight, pull, smooth=SEPARATE_SMOOTH)
        poses, touching = _touching_poses(robot, data, step)
        hit = np.nonzero(touching)[0]  # a step that makes bodies touch: taken again, kept apart
        if len(hit):
            step[hit], change[hit] = _step(robot, data, now[hit], goal[hit], weight[hit], pull[hit],
                                           _contact_rows(robot, near, now[hit]), smooth=SEPARATE_SMOOTH)
        out[at] = step
        off = (np.linalg.norm((_places_of(robot, poses)[:, feet] - goal[:, feet])[..., :2], axis=-1)
               > PIN_DRIFT).any(axis=1) | touching
        moving = moving[off & (change >= TOLERANCE)]
        if not len(moving):
            break
    # a frame whose standing feet end further from level with each other (one sole higher than the other by
    # LEVEL_HEIGHT more than before: more than level_feet mends) keeps its pose: the lock asked for more than the legs
    # reach
    both = (held[frames][:, 0::2] | held[frames][:, 1::2]).all(axis=1)  # (F,) both feet standing
    spread = [np.where(both, np.abs(h[:, 0] - h[:, 1]), 0.0)
              for h in (low[frames], sole_heights(robot, out[frames]))]
    worse = spread[1] > spread[0] + LEVEL_HEIGHT
    out[frames[worse]] = qpos[frames[worse]]
    return out


def separate(robot: Robot, qpos: np.ndarray, held: np.ndarray | None = None, iterations: int = SEPARATE_ITERATIONS,
             rounds: int = 9) -> np.ndarray:
    """(T, nq) poses in which the robot's own bodies overlap pushed apart (:func:`_contact_rows`), until none
    overlap: each from its own pose, the targets its current places, held loosely so that nothing else moves more
    than it must, the ankles and toe points of ``held`` (T, 4) feet firmly. First with the frames around them, every
    joint pulled toward its neighbours' (``SEPARATE_SMOOTH``), so that no joint jumps, every pair up to ``NEAR``
    apart kept from closing in (``iterations``); then up to ``rounds`` - 1 rounds of the frames still touching alone,
    only the overlapping pairs pushed (four times as many iterations each), each from where the last one stopped, the
    standing feet held loosely too in the second half of the rounds (no overlap is left for a foot's sake)."""
    data, near = robot.scratch()
    out, T = qpos.copy(), len(qpos)
    close = np.nonzero(_touching(robot, data, out))[0]
    for round in range(rounds):
        if not len(close):
            break
        reach = SEPARATE_REACH if round == 0 else 0  # after the first round: the frames still touching alone
        window = np.unique(np.clip(close[:, None] + np.arange(-reach, reach + 1), 0, T - 1))
        here = _places(robot, data, out[window])
        weights = SEPARATE_HOLD * _weights(robot, np.zeros((len(window), 4)))
        if held is not None and round < rounds // 2:  # a standing foot stays where it stands (until the last rounds)
            firm = _weights(robot, held[window].astype(float))
            rows = _feet_rows(robot)
            weights[:, rows] = np.where(np.repeat(held[window], 3, axis=1), firm[:, rows], weights[:, rows])
        moving = np.arange(len(window))  # the window's frames still being moved
        for _ in range(iterations if reach else 4 * iterations):
            frames = window[moving]
            pairs = _contact_rows(robot, near if reach else data, out[frames])  # alone: the overlapping pairs only
            out[frames], _ = _step(robot, data, out[frames], here[moving], weights[moving], _neighbours(out)[frames],
                                   pairs, SEPARATE_SMOOTH if reach else 0.0)
            now = _touching(robot, data, out[frames])
            if not now.any():
                break
            if not reach:  # alone: a frame pushed apart is left there
                moving = moving[now]
        close = window[_touching(robot, data, out[window])]
    return out


def floor_feet(robot: Robot, qpos: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """(T, nq) poses with the base moved up or down per frame so that the lowest sole of a planted foot touches the
    floor (z = 0) and no sole is below it."""
    out = qpos.copy()
    out[:, 2] += _floor_shift(sole_heights(robot, qpos), planted)
    return out


def _floor_shift(low: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """(T,) how far :func:`floor_feet` moves each base up, from the soles' heights ``low`` (T, 2) and ``planted``."""
    standing = np.where(planted, low, np.inf).min(axis=1)
    return np.maximum(np.where(np.isfinite(standing), -standing, 0.0), -low.min(axis=1))


def level_feet(robot: Robot, qpos: np.ndarray, planted: np.ndarray, iterations: int = LEVEL_ITERATIONS) -> np.ndarray:
    """(T, nq) poses (on the floor: :func:`floor_feet`) in which a planted foot whose lowest sole point is more than
    ``LEVEL_HEIGHT`` above the floor (``planted`` (T, 2): left, right) is brought down to it: its ankle and toe
    point lowered by that height, the other planted foot held where it is, no sole let below the floor (a foot
    standing on its toe's edge would sink and the base go up again), the rest held loosely to its place, each joint
    pulled toward its neighbours', the robot's own bodies kept ``CLEARANCE`` apart (:func:`_contact_rows`); the base
    then floored again. A frame whose levelled pose makes them touch is stepped again, its pairs pushed apart, until
    they are apart and no planted foot is high (up to ``iterations`` times); one still touching takes the largest of
    ``LEVEL_SHARES`` of its change that does not (none of it at worst)."""
    out, low = qpos.copy(), sole_heights(robot, qpos)
    shift = _floor_shift(low, planted)
    out[:, 2] += shift  # floor_feet (the base moved up: every sole with it)
    frames = np.nonzero((planted & (low + shift[:, None] > LEVEL_HEIGHT)).any(axis=1))[0]
    if not len(frames):
        return out
    data, near = robot.scratch()
    feet = _feet_points(robot)
    before = out[frames].copy()

    def step(at: np.ndarray, always: bool = False) -> bool:  # one levelling step of the frames ``at``
        poses = kin.forward(robot.own, data, robot.chain, out[at])
        low = _soles_of(robot, poses)
        high = planted[at] & (low > LEVEL_HEIGHT / 2)
        if not (always or high.any()):
            return False  # no foot to bring down: not stepped
        here = _places_of(robot, poses)
        for f in range(2):  # the high foot's ankle and toe point down by its height
            here[:, feet[2 * f:2 * f + 2], 2] -= np.where(high[:, f], low[:, f], 0.0)[:, None]
        weights = _firm_feet(robot, SEPARATE_HOLD * _weights(robot, np.zeros((len(at), 4))),
                             np.repeat(planted[at], 2, axis=1).astype(float))
        out[at], _ = _step(robot, data, out[at], here, weights, _neighbours(out)[at],  # every sole kept up (lifted)
                           _contact_rows(robot, near, out[at]), smooth=LEVEL_SMOOTH, lifted=np.ones_like(planted[at]),
                           poses=poses)
        return True

    for _ in range(iterations):
        if not step(frames):
            break
    # levelled frames whose bodies touch: stepped again, their pairs pushed apart, until apart and level
    touch = _touching(robot, data, out[frames])  # (len(frames),)
    redo = np.nonzero(touch)[0]  # places among ``frames``
    for _ in range(iterations):
        if not len(redo):
            break
        step(frames[redo], always=True)
        poses, touch[redo] = _touching_poses(robot, data, out[frames[redo]])
        low, standing = _soles_of(robot, poses), planted[frames[redo]]
        high = (standing & (low + _floor_shift(low, standing)[:, None] > LEVEL_HEIGHT)).any(axis=1)
        redo = redo[touch[redo] | high]
    touching = np.nonzero(touch)[0]
    after = out[frames].copy()
    for share in LEVEL_SHARES:  # a frame whose bodies touch: the largest share of its change that keeps them apart
        if not len(touching):
            break
        q = before[touching] + share * (after[touching] - before[touching])
        q[:, 3:7] /= np.linalg.norm(q[:, 3:7], axis=1, keepdims=True)
        out[frames[touching]] = q
        touching = touching[_touching(robot, data, q)]
    out[frames] = floor_feet(robot, out[frames], planted[frames])
    return out


def foot_points(robot: Robot, qpos: np.ndarray) -> np.ndarray:
    """(T, 4, 3) the points that stand for the human's left ankle, left toe, right ankle, right toe in (T, nq) poses:
    the ankle sites and the soles' toe points, metres."""
    return _places(robot, robot.scratch()[0], qpos)[:, _feet_points(robot)]


def sole_heights(robot: Robot, qpos: np.ndarray) -> np.ndarray:
    """(T, 2) each foot's lowest sole point above the floor (m), left and right, in (T, nq) poses."""
    return _soles_of(robot, kin.forward(robot.own, robot.scratch()[0], robot.chain, qpos))


def _soles_of(robot: Robot, poses: kin.Poses) -> np.ndarray:
    """:func:`sole_heights` from the poses' kinematics."""
    return np.stack([(kin.points(poses, np.full(len(f.points), f.body), f.points)[..., 2] - f.radius).min(axis=1)
                     for f in robot.soles], axis=1)


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
    qpos = solve_poses(robot, targets, toes, pelvis_axes(joints), held, fps)
    qpos = resample_qpos(qpos, fps, out_fps)
    planted = resample(planted.astype(float), fps, out_fps) > 0.5
    held = resample(held.astype(float), fps, out_fps) > 0.5
    qpos = pin_feet(robot, qpos, held, out_fps)
    qpos = separate(robot, qpos, held)
    qpos = level_feet(robot, qpos, planted)
    return RobotMotion(robot.name, out_fps, qpos, robot.joint_names, planted, scale)
