"""Footskate cleanup on a rigid body: planted feet held in place, legs placed by closed-form IK, no optimisation.

The body is a :class:`~stablemofusion.motion.rigid.RigidMotion`, so the cleanup moves joints, never bone lengths.
:func:`clean_joints` in five steps, each a function of arrays:

1. contacts of the four foot joints (:func:`detect_contacts`);
2. holds (:func:`holds`): each contact held at the mean of where the motion put the joint; a contact that strays
   further than ``max_slide`` is cut into pieces with frames left free between them, and consecutive holds are
   kept far enough apart for the foot to travel between them;
3. foot shifts (:func:`foot_shifts`, :func:`bridge`, :func:`bridge_lift`): what holds each joint, eased across the
   frames between two holds so the foot travels the whole swing to its next footprint (lifted where it is carried
   further than the motion took it); heel and toe blended, so a foot moves as one piece and never jumps;
4. the body leans into its turns (:mod:`~stablemofusion.motion.lean`);
5. the legs reach for the feet by two-bone IK, the pelvis moving towards a foot it cannot otherwise reach
   (:mod:`~stablemofusion.motion.ik`).

Back to features (:func:`cleanup_features`): the cleaned body is written in the body frames of the input
features (:func:`~stablemofusion.motion.rigid.rigid_to_features`), so the features decode to its joints.

Steps 1-5 are written once, against the array API, vectorised over motions and without loops over frames: numpy
runs them here; traced in torch they are the ONNX graphs the page, Node.js and game engines run
(:func:`~stablemofusion.backends.onnx_export.export_final_stage`, shipped in ``assets/final_stage/``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..core.errors import SMFError
from ..motion import timeseries as ts
from ..motion.arrays import device, namespace, on_like, to_numpy
from ..motion.features import feature_slices, features_from_joints
from ..motion.ik import LEG_CHAIN_JOINTS, hann_window, place_legs, reach_shift
from ..motion.lean import LEAN_SHARE, lean_into_turns
from ..motion import rigid_batch
from ..motion.rigid import (DEFAULT_FIT, RigidFitConfig, RigidMotion, fit_rigid, rigid_joints_of_features,
                            rigid_to_features)
from .contacts import HML_FOOT_JOINTS, KinematicContactConfig, contacts_from_vgrf, contacts_of_feet

VgrfModel = Callable  # torch: (B, T, 22, 3) metres, Y up, 20 fps -> (B, T, 2, 16); the vGRF route needs torch
CONTACT_ROUTES = ("kinematic", "vgrf")
# calibrated on the corpus (benchmarks/final_stage_check.py contacts): a real planted foot joint stays within
# a few centimetres of the floor and moves slowly; looser than the detector's defaults because a generated
# motion's planted feet slide and its floor level is noisy
CLEANUP_CONTACTS = KinematicContactConfig(speed_on=1.5, speed_off=1.875, height_on=0.06, height_off=0.08)
# a joints file keeps its own skeleton: bone lengths are the motion's median
JOINTS_FIT = RigidFitConfig(bone_lengths="median", start="positions")
# a contact is cut each time its joint has gone this many max_slide further from where the contact started: a glide
# of constant speed then has its positions within max_slide of each piece's mean (closest, in held frames, to
# cutting where a position strays max_slide from the running mean)
PIECE = 1.5


@dataclass(frozen=True)
class CleanupConfig:
    """Settings of :func:`cleanup_rigid`."""

    contacts: str = "kinematic"  # or "vgrf" (needs a vGRF model)
    blend: float = 0.15  # s: frames left free either side of a cut contact; heel-toe hand-over
    max_slide: float = 0.15  # m: a contact whose joint strays further from its hold is cut into pieces
    catch_up: float = 1.2  # m/s: how much faster than the motion moved it a foot may travel between two holds
    lift: float = 0.5  # a foot carried between holds is lifted by this share of the distance it is carried ...
    max_lift: float = 0.1  # m: ... at most this
    toes_on_floor: bool = True  # planted toes are put on the floor (y = 0) by turning the foot
    lean: float = LEAN_SHARE  # share of atan(a_lat / g) the body leans into turns (0: no lean)
    reach_smooth: float = 0.15  # s: a pelvis move that lets a leg reach its foot is spread over this either side
    kinematic: KinematicContactConfig = CLEANUP_CONTACTS  # frozen, so one shared default is safe


@dataclass
class CleanupResult:
    """Cleaned joints (T, 22, 3) in the input's frame, the contacts (T, 4) that were enforced, and the cleaned
    rigid body the joints come from."""

    joints: np.ndarray
    contacts: np.ndarray
    motion: RigidMotion


def _series(x):
    """(B, T, K, ...) -> (B * K, T, ...): each foot joint's frames as one series."""
    xp = namespace(x)
    B, T, K = x.shape[:3]
    order = (0, 2, 1, *range(3, x.ndim))
    return xp.reshape(xp.permute_dims(x, order), (B * K, T, *x.shape[3:]))


def _unseries(x, B: int):
    """(B * K, T, ...) -> (B, T, K, ...), the inverse of :func:`_series`."""
    xp = namespace(x)
    K = x.shape[0] // B
    y = xp.reshape(x, (B, K, *x.shape[1:]))
    return xp.permute_dims(y, (0, 2, 1, *range(3, y.ndim)))


def hold_places(points, contacts, max_slide: float, cut_gap: int):
    """Each contact of joint series ``points`` (N, T, 3) metres, ``contacts`` (N, T) bool, held at the mean of its
    positions: the place (N, T, 3) and the held frames (N, T). A contact whose joint travels away from where it
    started is cut into pieces, one each time it has gone another :data:`PIECE` x ``max_slide`` (m, horizontally)
    further than ever before, so a piece's positions lie within about ``max_slide`` of its mean; ``cut_gap``
    frames either side of a cut are left free for the foot to move to its next hold."""
    xp = namespace(points)
    c = contacts
    t = ts.frames(c)[None]
    start, stop = ts.last_true(~c) + 1, ts.next_true(~c)  # of the contact a frame is in
    xz = ts.xz(points)
    away = xp.where(c, ts.norm(xz - ts.at(xz, start)), xp.zeros_like(xz[..., 0]))
    first = c & ~ts.shifted(c, 1, False)
    run = xp.astype(xp.cumulative_sum(xp.astype(first, xp.int64), axis=1), away.dtype)
    # the furthest the joint has been from its contact's start so far (the run's index keeps contacts apart)
    furthest = ts.cummax(run * 1e4 + away) - run * 1e4
    piece = xp.floor(furthest / ts.const(furthest, PIECE * max_slide))
    begins = c & (first | (piece != ts.shifted(piece, 1, -1.0)))
    ends = c & (~ts.shifted(c, -1, False) | ts.shifted(begins, -1, False))
    a, b = ts.last_true(begins), ts.next_true(ends) + 1  # the piece a frame is in
    zero = xp.zeros_like(a)
    lo = a + xp.where(a > start, zero + cut_gap, zero)
    hi = b - xp.where(b < stop, zero + cut_gap, zero)
    held = c & (t >= lo) & (t < hi)
    sums = xp.concat([xp.zeros_like(points[:, :1]), xp.cumulative_sum(points, axis=1)], axis=1)  # (N, T + 1, 3)
    mean = (ts.at(sums, hi) - ts.at(sums, lo)) / xp.astype(xp.maximum(hi - lo, 1), points.dtype)[..., None]
    return xp.where(held[..., None], mean, points), held


def spaced(pull, held, frames_per_metre: float, rounds: int = 3):
    """``held`` (N, T) with the ends of consecutive holds released until the frames between the last frame of one
    and the first of the next are at least ``frames_per_metre`` times the change of ``pull`` (N, T, 2) (hold minus
    position, metres) between them: the earlier hold loses the first, third ... frame missing, the later the
    second, fourth ...; ``rounds`` times, as the pull at the new ends differs."""
    xp = namespace(held)
    T = ts.count(held)
    t = ts.frames(held)[None]
    for _ in range(rounds):
        a, b = ts.last_true(~held) + 1, ts.next_true(~held)  # the hold a frame is in
        before = ts.at(ts.last_true(held), a - 1)  # the previous hold's last frame
        before = xp.where(a > 0, before, xp.full_like(before, -1))
        after = xp.where(b < T, ts.at(ts.next_true(held), b), b * 0 + T)  # the next hold's first frame

        def missing(last, first, exists):  # frames the gap from last to first lacks
            need = xp.ceil(frames_per_metre * ts.norm(ts.at(pull, first) - ts.at(pull, last)))
            lack = xp.clip(xp.astype(need, last.dtype) - (first - last), 0, None)
            return xp.where(exists, lack, xp.zeros_like(lack))

        late = missing(b - 1, after, after < T)  # this hold and the next
        early = missing(before, a, before >= 0)  # the previous hold and this
        held = held & (t >= a + early // 2) & (t < b - (late + 1) // 2)
    return held


def holds(points, contacts, max_slide: float, cut_gap: int, fps: float = 20.0, catch_up: float = 1.2):
    """Where each foot joint is held: ``points`` (B, T, K, 3) metres, ``contacts`` (B, T, K) bool -> the place
    (B, T, K, 3) and a mask (B, T, K) of the held frames (one motion: without B). Each contact is held at the mean
    of its positions, cut into pieces where it strays (:func:`hold_places`); then two holds of a joint are kept
    apart long enough for the foot to move from one to the next (:func:`bridge`) at most ``catch_up`` m/s faster
    than the motion moved it (:func:`spaced`; a smoothstep's peak speed is 1.5x its mean)."""
    if points.ndim == 3:
        place, held = holds(points[None], contacts[None], max_slide, cut_gap, fps, catch_up)
        return place[0], held[0]
    B = points.shape[0]
    pts = _series(points)
    place, held = hold_places(pts, _series(contacts), max_slide, cut_gap)
    held = spaced(ts.xz(place - pts), held, 1.5 * fps / catch_up)
    return _unseries(place, B), _unseries(held, B)


def bridged(offset, held):
    """``offset`` (N, T, C) known where ``held`` (N, T) -> (N, T, C) everywhere: across each free stretch between two
    held frames it eases (smoothstep in time) from the offset before to the one after; before the first and after
    the last held frame it stays at the nearest one; all zeros where nothing is held."""
    xp = namespace(offset)
    T = ts.count(held)
    before, after = ts.last_true(held), ts.next_true(held)
    b = xp.where(before < 0, after, before)
    a = xp.where(after >= T, before, after)
    span = xp.astype(xp.maximum(a - b, 1), offset.dtype)
    s = ts.smoothstep(xp.astype(ts.frames(held)[None] - b, offset.dtype) / span)[..., None]
    out = (1 - s) * ts.at(offset, b) + s * ts.at(offset, a)
    return xp.where((before[:, -1:] >= 0)[..., None], out, xp.zeros_like(out))


def bridge(offset: np.ndarray, held: np.ndarray) -> np.ndarray:
    """:func:`bridged` of one series: ``offset`` (T, C), ``held`` (T,) -> (T, C)."""
    return bridged(np.asarray(offset, dtype=np.float64)[None], np.asarray(held, bool)[None])[0]


def foot_shifts(points, place, held, ramp: int):
    """(B, T, 2, 3) how far to move each foot (left, right) as one piece so that its held joints stay at their holds
    (``points``, ``place`` (B, T, 4, 3), ``held`` (B, T, 4) in HumanML3D's contact order: left ankle, left toe, right
    ankle, right toe); horizontal only. Each joint's pull (hold minus position) is known where it is held and eased
    across the frames between (:func:`bridged`), so a foot travels the whole swing to its next footprint; a foot's
    shift blends its heel's and toe's pulls by how firmly each is held around that frame (``ramp`` frames either
    side), so neither a hand-over from heel to toe nor a release ever jumps."""
    xp = namespace(points)
    B = points.shape[0]
    flat = xp.asarray([1.0, 0.0, 1.0], dtype=points.dtype, device=device(points))
    h = _series(held)
    w = _unseries(ts.window(xp.astype(h, points.dtype), hann_window(ramp), edge=False) + ts.const(points, 1e-3), B)
    o = _unseries(bridged(_series((place - points) * flat), h), B)  # (B, T, 4, 3)
    feet = [(w[..., j:j + 1] * o[:, :, j] + w[..., j + 1:j + 2] * o[:, :, j + 1])
            / (w[..., j:j + 1] + w[..., j + 1:j + 2]) for j in (0, 2)]
    return xp.stack(feet, axis=2)


def bridge_lift(shift, held, share: float, most: float):
    """(N, T) metres to lift a foot while it travels between two holds further than the motion took it: across
    each free stretch, an arc (4 s (1 - s), s the stretch's progress) of height ``share`` times the change of its
    shift ``shift`` (N, T, 3) over the stretch, at most ``most``; zero elsewhere. A foot carried to its next
    footprint is stepped there, not slid along the floor."""
    xp = namespace(shift)
    T = ts.count(held)
    last, first = ts.last_true(held), ts.next_true(held)
    free = ~held & (last >= 0) & (first < T)
    h = xp.clip(ts.const(shift, share) * ts.norm(ts.xz(ts.at(shift, first) - ts.at(shift, last))), None,
                ts.const(shift, most))
    x = xp.astype(ts.frames(held)[None] - last, shift.dtype) / xp.astype(xp.maximum(first - last, 1), shift.dtype)
    return xp.where(free, 4 * x * (1 - x) * h, xp.zeros_like(h))


def detect_contacts(joints, fps: float, config: CleanupConfig, vgrf_model: VgrfModel | None = None):
    """Contacts (B, T, 4) of joints (B, T, 22, 3) by the route named in ``config.contacts`` (one motion: without B)."""
    if joints.ndim == 3:
        return detect_contacts(joints[None], fps, config, vgrf_model)[0]
    if config.contacts == "kinematic":
        return contacts_of_feet(joints[:, :, list(HML_FOOT_JOINTS)], fps, config.kinematic)
    if config.contacts == "vgrf":
        if vgrf_model is None:
            raise SMFError("contacts='vgrf' needs a vGRF model (a distilled 22-joint model or UnderPressure)")
        import torch

        with torch.no_grad():
            f = vgrf_model(torch.as_tensor(np.asarray(joints), dtype=torch.float32)).double().numpy()
        return np.stack([contacts_from_vgrf(one, fps) for one in f])
    raise SMFError(f"unknown contact route {config.contacts!r}; choose from {', '.join(CONTACT_ROUTES)}")


def clean_joints(joints, contacts, bone_lengths, fps: float, config: CleanupConfig = CleanupConfig()):
    """The cleanup of rigid joints (B, T, 22, 3) metres (Y up, floor y = 0) with ``contacts`` (B, T, 4): the body
    leans into its turns, planted feet are held (:func:`holds`, :func:`foot_shifts`), the pelvis moves where a
    leg could not reach its foot (:func:`~stablemofusion.motion.ik.reach_shift`), and the legs are placed by IK.
    Bone lengths ``bone_lengths`` (B, 22) are kept. Returns the joints (B, T, 22, 3) and the held frames (B, T, 4);
    one motion: without B. Array API and loop-free: the ONNX graph of the final stage is this function."""
    xp = namespace(joints)
    if joints.ndim == 3:
        x, held = clean_joints(joints[None], contacts[None], bone_lengths[None], fps, config)
        return x[0], held[0]
    x0 = joints
    feet = xp.stack([x0[:, :, j] for j in HML_FOOT_JOINTS], axis=2)  # (B, T, 4, 3)
    ramp = max(1, int(round(config.blend * fps)))  # frames
    place, held = holds(feet, contacts, config.max_slide, ramp, fps, config.catch_up)
    shift = foot_shifts(feet, place, held, ramp)  # (B, T, 2, 3)
    ankles = xp.stack([x0[:, :, 7], x0[:, :, 8]], axis=2) + shift
    toes = xp.stack([x0[:, :, 10], x0[:, :, 11]], axis=2) + shift
    if config.lift > 0:
        up = xp.stack([bridge_lift(shift[:, :, f], held[:, :, a] | held[:, :, t], config.lift, config.max_lift)
                       for f, (a, t) in enumerate(((0, 1), (2, 3)))], axis=2)  # (B, T, 2)
        zero = xp.zeros_like(up)
        lift = xp.stack([zero, up, zero], axis=-1)
        ankles, toes = ankles + lift, toes + lift
    if config.toes_on_floor:  # a planted toe goes to the floor, a toe below it comes up: the foot turns
        kernel = hann_window(ramp)
        kernel /= kernel.sum()
        down = xp.clip(ts.window(xp.astype(xp.stack([held[:, :, 1], held[:, :, 3]], axis=-1), x0.dtype), kernel,
                                 edge=False), 0.0, 1.0)  # (B, T, 2)
        y = toes[..., 1]
        toes = xp.stack([toes[..., 0], xp.clip(y - down * y, 0.0, None), toes[..., 2]], axis=-1)
    x = lean_into_turns(x0, fps, config.lean) if config.lean > 0 else x0
    move = reach_shift(x, ankles, bone_lengths, fps, config.reach_smooth)  # (B, T, 3)
    body = np.ones((x.shape[2], 1))
    body[list(LEG_CHAIN_JOINTS)] = 0.0
    x = x + move[:, :, None] * xp.asarray(body, dtype=x0.dtype, device=device(x0))
    return place_legs(x, ankles, toes, bone_lengths), held


def cleanup_rigid(motion: RigidMotion, fps: float = 20.0, config: CleanupConfig = CleanupConfig(), *,
                  vgrf_model: VgrfModel | None = None, contacts: np.ndarray | None = None) -> CleanupResult:
    """Remove foot skating from a rigid HumanML3D motion (metres, Y up, floor y = 0) at ``fps`` (module
    docstring); bone lengths never change."""
    if motion.skeleton != "humanml3d" or len(motion) < 2:
        raise SMFError(f"footskate cleanup needs a HumanML3D motion of at least 2 frames, got {motion.skeleton} "
                       f"with {len(motion)}")
    x0 = motion.joints()
    c = detect_contacts(x0, fps, config, vgrf_model) if contacts is None else np.asarray(contacts, bool)
    x, held = clean_joints(x0, c, motion.bone_lengths, fps, config)
    return CleanupResult(x, c, bodies_of_joints([x], [motion.bone_lengths], [held])[0])


def cleanup_joints(joints: np.ndarray, fps: float = 20.0, config: CleanupConfig = CleanupConfig(), *,
                   vgrf_model: VgrfModel | None = None, contacts: np.ndarray | None = None,
                   rigid: RigidFitConfig = JOINTS_FIT) -> CleanupResult:
    """Remove foot skating from joints (T, 22, 3) (metres, Y up, floor y = 0) at ``fps``: fits a rigid body
    (bone lengths by ``rigid``: the motion's median by default), then :func:`cleanup_rigid`."""
    x0 = np.asarray(joints, dtype=np.float64)
    if x0.ndim != 3 or x0.shape[1:] != (22, 3) or len(x0) < 2:
        raise SMFError(f"expected joints of shape (T>=2, 22, 3), got {tuple(x0.shape)}")
    return cleanup_rigid(fit_rigid(x0, "humanml3d", rigid), fps, config, vgrf_model=vgrf_model, contacts=contacts)


def features_from_cleaned(joints: np.ndarray) -> np.ndarray:
    """Joints (T, 22, 3) -> features (T, 263): appends one extrapolated frame, since
    :func:`features_from_joints` returns one frame fewer; bone lengths and heights are kept as they are."""
    j = np.asarray(joints, dtype=np.float64)
    ext = np.concatenate([j, 2 * j[-1:] - j[-2:-1]], 0)
    feats = features_from_joints(ext, uniform=False)
    # features_from_joints puts the lowest joint of the motion at y = 0; keep the optimised heights instead
    # (the floor loss already lifted what was below the floor, frame by frame)
    lift = ext[..., 1].min()
    sl = feature_slices("humanml3d")
    feats[:, sl.root_height] += lift
    feats[:, sl.positions.start + 1:sl.positions.stop:3] += lift
    return feats


def cleanup_features_many(features: list[np.ndarray], config: CleanupConfig = CleanupConfig(), *,
                          vgrf_model: VgrfModel | None = None, fps: float = 20.0,
                          rigid: RigidFitConfig = DEFAULT_FIT, like=None) -> list[tuple[np.ndarray, RigidMotion]]:
    """HumanML3D features (T_i, 263) in dataset units -> per motion the cleaned features (T_i, 263) and the cleaned
    rigid body they decode to: the rigid fits of all the features together (``rigid``; each motion's fit is the
    one it gets alone), :func:`cleanup_rigid` of each, then each body written in its input's body frames
    (:func:`~stablemofusion.motion.rigid.rigid_to_features`). Motions of one length are cleaned together. ``like``:
    the rigid fit, contacts and cleanup run on its library and device (a tensor on a GPU; None: numpy), the pose
    and the write-back on numpy."""
    fs = [np.asarray(f, dtype=np.float64) for f in features]
    for f in fs:
        if f.ndim != 2 or f.shape[1] != 263 or len(f) < 2:
            raise SMFError(f"expected features of shape (T>=2, 263), got {tuple(f.shape)}")
    if config.contacts != "kinematic":
        like = None  # the vGRF route's model runs on the host
    rigid_joints, bone_lengths = rigid_joints_of_features(fs, "humanml3d", rigid, like)  # posed once, after the cleanup
    cleaned: list = [None] * len(fs)
    by_length: dict[int, list[int]] = {}
    for i, x in enumerate(rigid_joints):
        by_length.setdefault(len(x), []).append(i)
    for group in by_length.values():  # motions of one length are cleaned as one batch
        x = on_like(np.stack([rigid_joints[i] for i in group]), like)
        contacts = detect_contacts(x, fps, config, vgrf_model)
        joints, held = to_numpy(clean_joints(x, contacts, on_like(bone_lengths[group], like), fps, config))
        for k, i in enumerate(group):
            cleaned[i] = (joints[k], held[k])
    out = []
    for body, f in zip(bodies_of_joints([x for x, _ in cleaned], list(bone_lengths), [held for _, held in cleaned]),
                       fs):
        motion, written = rigid_to_features(body, f, rigid)
        out.append((written, motion))
    return out


def bodies_of_joints(joints: list[np.ndarray], lengths: list[np.ndarray], planted: list[np.ndarray]
                     ) -> list[RigidMotion]:
    """Rigid HumanML3D bodies of rigid joints (T_i, 22, 3) with bone lengths (22,) and held feet (T_i, 4) each: the
    closed-form pose of all their frames at once (exact for rigid joints), each remembering its joints."""
    starts = np.cumsum([0] + [len(x) for x in joints[:-1]])
    offsets, rotations = rigid_batch.pose_of_joints(np.concatenate(joints), starts, "humanml3d", np.stack(lengths))
    out = []
    for i, (a, x, held) in enumerate(zip(starts, joints, planted)):
        out.append(RigidMotion(offsets[i], rotations[a:a + len(x)], x[:, 0].copy(), "humanml3d",
                               np.asarray(held, bool)).with_joints(x))
    return out


def cleanup_features(features: np.ndarray, config: CleanupConfig = CleanupConfig(), *,
                     vgrf_model: VgrfModel | None = None, fps: float = 20.0,
                     rigid: RigidFitConfig = DEFAULT_FIT) -> tuple[np.ndarray, RigidMotion]:
    """HumanML3D features (T, 263) in dataset units -> cleaned features (T, 263) and the cleaned rigid body
    they decode to (:func:`cleanup_features_many` of one)."""
    return cleanup_features_many([features], config, vgrf_model=vgrf_model, fps=fps, rigid=rigid)[0]


def align_yaw_xz(moving: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Rotate ``moving`` (T, J, 3) about +Y and shift it in XZ to best match ``fixed`` (least squares).

    Features only fix a motion up to its first-frame heading and start point; use this before comparing
    joints decoded from two feature arrays. Heights are left untouched.
    """
    a = np.asarray(moving, np.float64)
    b = np.asarray(fixed, np.float64)
    pa, pb = a[..., [0, 2]].reshape(-1, 2), b[..., [0, 2]].reshape(-1, 2)
    ca, cb = pa.mean(0), pb.mean(0)
    h = (pa - ca).T @ (pb - cb)
    theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
    r = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    out = a.copy()
    out[..., [0, 2]] = (a[..., [0, 2]] - ca) @ r.T + cb
    return out
