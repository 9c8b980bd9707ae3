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
features (:func:`~stablemofusion.motion.rigid.rigid_to_features`), so the features decode to its joints. The
JavaScript runtime (``assets/runtime/cleanup.js``) runs the same steps; tests hold the two together.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import SMFError
from ..motion.features import feature_slices, features_from_joints, smoothstep
from ..motion.ik import LEG_CHAIN_JOINTS, hann_window, place_legs, reach_shift
from ..motion.lean import LEAN_SHARE, lean_into_turns
from ..motion import rigid_batch
from ..motion.rigid import (DEFAULT_FIT, RigidFitConfig, RigidMotion, fit_rigid,
                            rigid_from_features_many, rigid_to_features)
from .contacts import HML_FOOT_JOINTS, KinematicContactConfig, contacts_from_vgrf, kinematic_contacts, runs

VgrfModel = Callable  # torch: (B, T, 22, 3) metres, Y up, 20 fps -> (B, T, 2, 16); the vGRF route needs torch
CONTACT_ROUTES = ("kinematic", "vgrf")
# calibrated on the corpus (benchmarks/final_stage_check.py contacts): a real planted foot joint stays within
# a few centimetres of the floor and moves slowly; looser than the detector's defaults because a generated
# motion's planted feet slide and its floor level is noisy
CLEANUP_CONTACTS = KinematicContactConfig(speed_on=1.5, speed_off=1.875, height_on=0.06, height_off=0.08)
# a joints file keeps its own skeleton: bone lengths are the motion's median
JOINTS_FIT = RigidFitConfig(bone_lengths="median", start="positions")


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


def split_contact(points: np.ndarray, max_shift: float) -> list[tuple[int, int]]:
    """Split one contact interval of a joint's positions (n, 3) into [(start, stop)) pieces in which no
    position lies further than ``max_shift`` (m, horizontally) from the piece's mean: a piece grows frame by
    frame until one of its positions strays, and the next piece starts there."""
    pieces, a, n = [], 0, len(points)
    lo, hi = points[:, [0, 2]].min(0), points[:, [0, 2]].max(0)
    if np.hypot(*(hi - lo)) <= max_shift:  # every mean lies in the box: nothing can stray (the usual case)
        return [(0, n)]
    while True:
        xz = points[a:, [0, 2]]
        means = np.cumsum(xz, 0) / np.arange(1, len(xz) + 1)[:, None]  # row m: the mean of the first m + 1
        far = np.linalg.norm(xz[None] - means[:, None], axis=-1)  # (m, i): position i from that mean
        worst = np.where(np.tri(len(xz), dtype=bool), far, 0.0).max(1)  # over the positions i <= m
        over = np.flatnonzero(worst > max_shift)
        if not len(over):
            pieces.append((a, n))
            return pieces
        b = a + max(int(over[0]), 1)
        pieces.append((a, b))
        a = b


def holds(points: np.ndarray, contacts: np.ndarray, max_slide: float, cut_gap: int, fps: float = 20.0,
          catch_up: float = 1.2) -> tuple[np.ndarray, np.ndarray]:
    """Where each foot joint is held: ``points`` (T, K, 3) metres, ``contacts`` (T, K) bool -> the place (T, K, 3)
    and a mask (T, K) of the held frames. A contact is cut into pieces that stray at most ``max_slide`` m
    (:func:`split_contact`), each held at the mean of its positions; ``cut_gap`` frames either side of a cut are
    left free. Then two holds of a joint are kept apart long enough for the foot to move from one to the next
    (:func:`bridge`) at most ``catch_up`` m/s faster than the motion moved it: the earlier is released and the
    later caught a frame later, in turn, until they are."""
    T, K = contacts.shape
    place = np.array(points, dtype=np.float64, copy=True)
    held = np.zeros((T, K), dtype=bool)
    for k in range(K):
        spans = runs(contacts[:, k])
        if not spans:
            continue
        # the usual contact needs no cut: its positions' box is within max_slide (then every mean is close to
        # every position); the box and the mean of every contact at once
        edges = np.asarray(spans).ravel()
        xz = np.concatenate([points[:, k, [0, 2]], points[-1:, k, [0, 2]]])
        box = np.maximum.reduceat(xz, edges)[0::2] - np.minimum.reduceat(xz, edges)[0::2]
        whole = np.hypot(box[:, 0], box[:, 1]) <= max_slide
        sums = np.concatenate([np.zeros((1, 3)), np.cumsum(points[:, k], 0)])
        for (a, b), one in zip(spans, whole):
            pieces = [(0, b - a)] if one else split_contact(points[a:b, k], max_slide)
            for i, (a2, b2) in enumerate(pieces):
                lo = a + a2 + (cut_gap if i > 0 else 0)
                hi = a + b2 - (cut_gap if i < len(pieces) - 1 else 0)
                if hi - lo < 1:
                    continue
                place[lo:hi, k] = (sums[hi] - sums[lo]) / (hi - lo)
                held[lo:hi, k] = True
        _space_holds(points[:, k], place[:, k], held[:, k], 1.5 * fps / catch_up)
    return place, held


def _space_holds(points: np.ndarray, place: np.ndarray, held: np.ndarray, frames_per_metre: float) -> None:
    """In place on ``held`` (T,): release the ends of consecutive holds until the frames between the last frame of
    one and the first of the next are at least ``frames_per_metre`` times the change of the pull (place minus
    position, horizontally) between them (a smoothstep's peak speed is 1.5x its mean)."""
    pull = (place - points)[:, [0, 2]]
    spans = runs(held)
    for (a1, e1), (s2, b2) in zip(spans[:-1], spans[1:]):
        last, first, turn = e1 - 1, s2, 0
        while last >= a1 and first < b2 and first - last < frames_per_metre * np.linalg.norm(pull[first] - pull[last]):
            if turn % 2 == 0:
                held[last] = False
                last -= 1
            else:
                held[first] = False
                first += 1
            turn += 1


def bridge(offset: np.ndarray, held: np.ndarray) -> np.ndarray:
    """``offset`` (T, C) known where ``held`` (T,) -> (T, C) everywhere: across each free stretch between two held
    frames it eases (smoothstep in time) from the offset before to the one after; before the first and after the
    last held frame it stays at the nearest one; all zeros where nothing is held."""
    T = len(held)
    if not held.any():
        return np.zeros_like(offset)
    before = np.maximum.accumulate(np.where(held, np.arange(T), -1))  # last held frame at or before t
    after = np.minimum.accumulate(np.where(held, np.arange(T), T)[::-1])[::-1]  # first held frame at or after t
    b = np.where(before < 0, after, before)
    a = np.where(after >= T, before, after)
    span = np.maximum(a - b, 1)
    s = smoothstep((np.arange(T) - b) / span)[:, None]
    return (1 - s) * offset[b] + s * offset[a]


def foot_shifts(points: np.ndarray, place: np.ndarray, held: np.ndarray, ramp: int) -> np.ndarray:
    """(T, 2, 3) how far to move each foot (left, right) as one piece so that its held joints stay at their holds
    (``points``, ``place`` (T, 4, 3), ``held`` (T, 4) in HumanML3D's contact order: left ankle, left toe, right
    ankle, right toe); horizontal only. Each joint's pull (hold minus position) is known where it is held and eased
    across the frames between (:func:`bridge`), so a foot travels the whole swing to its next footprint; a foot's
    shift blends its heel's and toe's pulls by how firmly each is held around that frame (``ramp`` frames either side),
    so neither a hand-over from heel to toe nor a release ever jumps."""
    pull = place - points  # (T, 4, 3)
    pull[..., 1] = 0.0
    kernel = hann_window(ramp)
    out = np.zeros((len(points), 2, 3))
    for f, (ankle, toe) in enumerate(((0, 1), (2, 3))):
        w = np.stack([np.convolve(held[:, j].astype(float), kernel, mode="same") for j in (ankle, toe)], -1) + 1e-3
        o = np.stack([bridge(pull[:, j], held[:, j]) for j in (ankle, toe)], 1)  # (T, 2, 3)
        out[:, f] = (w[..., None] * o).sum(1) / w.sum(-1, keepdims=True)
    return out


def bridge_lift(shift: np.ndarray, held: np.ndarray, share: float, most: float) -> np.ndarray:
    """(T,) metres to lift a foot while it travels between two holds further than the motion took it: across each
    free stretch, an arc (4 s (1 - s), s the stretch's progress) of height ``share`` times the change of its shift
    ``shift`` (T, 3) over the stretch, at most ``most``; zero elsewhere. A foot carried to its next footprint is
    stepped there, not slid along the floor."""
    T = len(held)
    out = np.zeros(T)
    spans = runs(held)
    for (_, e1), (s2, _) in zip(spans[:-1], spans[1:]):
        last, first = e1 - 1, s2
        h = min(share * float(np.linalg.norm(shift[first, [0, 2]] - shift[last, [0, 2]])), most)
        x = (np.arange(last + 1, first) - last) / (first - last)
        out[last + 1:first] = 4 * x * (1 - x) * h
    return out


def detect_contacts(joints: np.ndarray, fps: float, config: CleanupConfig,
                    vgrf_model: VgrfModel | None = None) -> np.ndarray:
    """Contacts (T, 4) by the route named in ``config.contacts``."""
    if config.contacts == "kinematic":
        return kinematic_contacts(joints, fps, config=config.kinematic)
    if config.contacts == "vgrf":
        if vgrf_model is None:
            raise SMFError("contacts='vgrf' needs a vGRF model (a distilled 22-joint model or UnderPressure)")
        import torch

        with torch.no_grad():
            f = vgrf_model(torch.as_tensor(joints, dtype=torch.float32)[None])[0].double().numpy()
        return contacts_from_vgrf(f, fps)
    raise SMFError(f"unknown contact route {config.contacts!r}; choose from {', '.join(CONTACT_ROUTES)}")


def clean_joints(joints: np.ndarray, contacts: np.ndarray, bone_lengths: np.ndarray, fps: float,
                 config: CleanupConfig = CleanupConfig()) -> tuple[np.ndarray, np.ndarray]:
    """The cleanup of rigid joints (T, 22, 3) metres (Y up, floor y = 0) with ``contacts`` (T, 4): the body leans
    into its turns, planted feet are held (:func:`holds`, :func:`foot_shifts`), the pelvis moves where a
    leg could not reach its foot (:func:`~stablemofusion.motion.ik.reach_shift`), and the legs are placed by IK.
    Bone lengths ``bone_lengths`` (22,) are kept. Returns the joints (T, 22, 3) and the held frames (T, 4)."""
    x0 = np.asarray(joints, dtype=np.float64)
    feet = x0[:, list(HML_FOOT_JOINTS)]  # (T, 4, 3)
    ramp = max(1, int(round(config.blend * fps)))  # frames
    place, held = holds(feet, contacts, config.max_slide, ramp, fps, config.catch_up)
    shift = foot_shifts(feet, place, held, ramp)  # (T, 2, 3)
    ankles = x0[:, [7, 8]] + shift
    toes = x0[:, [10, 11]] + shift
    if config.lift > 0:
        for f, (ankle, toe) in enumerate(((0, 1), (2, 3))):
            up = bridge_lift(shift[:, f], held[:, ankle] | held[:, toe], config.lift, config.max_lift)
            ankles[:, f, 1] += up
            toes[:, f, 1] += up
    if config.toes_on_floor:  # a planted toe goes to the floor, a toe below it comes up: the foot turns
        kernel = hann_window(ramp)
        kernel /= kernel.sum()
        for f, k in ((0, 1), (1, 3)):
            down = np.clip(np.convolve(held[:, k].astype(float), kernel, mode="same"), 0.0, 1.0)
            y = toes[:, f, 1]
            toes[:, f, 1] = np.maximum(y - down * y, 0.0)
    x = lean_into_turns(x0, fps, config.lean) if config.lean > 0 else x0.copy()
    move = reach_shift(x, ankles, bone_lengths, fps, config.reach_smooth)
    if move.any():
        body = [j for j in range(x.shape[1]) if j not in LEG_CHAIN_JOINTS]
        x[:, body] += move[:, None]
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
                          rigid: RigidFitConfig = DEFAULT_FIT) -> list[tuple[np.ndarray, RigidMotion]]:
    """HumanML3D features (T_i, 263) in dataset units -> per motion the cleaned features (T_i, 263) and the cleaned
    rigid body they decode to: the rigid fits of all the features together (``rigid``; each motion's fit is the
    one it gets alone), :func:`cleanup_rigid` of each, then each body written in its input's body frames
    (:func:`~stablemofusion.motion.rigid.rigid_to_features`)."""
    fs = [np.asarray(f, dtype=np.float64) for f in features]
    for f in fs:
        if f.ndim != 2 or f.shape[1] != 263 or len(f) < 2:
            raise SMFError(f"expected features of shape (T>=2, 263), got {tuple(f.shape)}")
    bodies = rigid_from_features_many(fs, "humanml3d", rigid)
    cleaned = []
    for b in bodies:
        x = b.joints()
        cleaned.append(clean_joints(x, detect_contacts(x, fps, config, vgrf_model), b.bone_lengths, fps, config))
    out = []
    for body, f in zip(bodies_of_joints([x for x, _ in cleaned], [b.bone_lengths for b in bodies],
                                        [held for _, held in cleaned]), fs):
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
