"""Retargeting onto a user's skeleton (a "rig"): our joint positions -> the rig's local rotations and root path.

numpy only, no other import from the package but its error type, so the Blender add-on
(``blender/stablemofusion_addon``) ships this very file (a test keeps the copy identical).

A rig is a joint tree with rest offsets (R, 3) metres, Y up, in the rest pose of all-identity rotations
(BVH's convention: p_c = p_parent + G_parent @ offsets[c], G_c = G_parent @ L_c). ``targets`` (R,) says which
of our joints each rig joint follows (-1: unmapped). Then, per frame:

- an unmapped joint keeps its rest pose (identity local rotation);
- a mapped joint with one mapped child bone (its nearest mapped descendant) turns by the shortest arc that
  takes the bone, as its parent carries it, onto the direction of the corresponding bone of ours (so its
  twist follows its parent, as our own closed-form pose does);
- a mapped joint with several mapped child bones (hips, chest) takes the rotation that best aligns all of
  them (Kabsch);
- a mapped joint without mapped child bones (hands, head, toes) keeps its rest pose relative to its parent;
- the joint following our pelvis moves along our pelvis path scaled by the ratio of leg lengths (rig / ours),
  lifted so that the rig's lowest foot joint comes as low as ours do (scaled), so planted feet stay planted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

try:
    from ..core.errors import SMFError
except ImportError:  # the Blender add-on's copy of this file, outside the package
    class SMFError(Exception):
        """Bad input (files, shapes, options)."""

# HumanML3D joint indices: (hip, knee, ankle) per leg and the foot joints (ankles, toes)
LEGS = ((1, 4, 7), (2, 5, 8))
FEET = (7, 8, 10, 11)
PELVIS = 0


@dataclass
class Rig:
    """A joint tree: ``names`` (R,), ``parents`` (R,) int (-1 for the root, parents before children),
    ``offsets`` (R, 3) rest offsets in metres, Y up (the root's: its rest position)."""

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray

    def __post_init__(self):
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.offsets = np.asarray(self.offsets, dtype=np.float64)
        R = len(self.names)
        if self.parents.shape != (R,) or self.offsets.shape != (R, 3):
            raise SMFError(f"rig: expected parents ({R},) and offsets ({R}, 3)")
        if R == 0 or self.parents[0] != -1 or (self.parents < 0).sum() != 1 or np.any(
                self.parents[1:] >= np.arange(1, R)):
            raise SMFError("rig: needs one root at index 0 and every parent before its children")

    @property
    def rest_positions(self) -> np.ndarray:
        """(R, 3) rest-pose positions in metres."""
        pos = self.offsets.copy()
        for j in range(1, len(pos)):
            pos[j] += pos[self.parents[j]]
        return pos


@dataclass
class RigMotion:
    """The rig's motion: ``rotations`` (T, R, 3, 3) local, ``glob`` (T, R, 3, 3) global (world, Y up),
    ``translations`` (T, R, 3) local translations in metres (the offsets, but for the joint carrying the
    path), ``scale``: rig leg length / ours."""

    rotations: np.ndarray
    glob: np.ndarray
    translations: np.ndarray
    scale: float

    def positions(self, parents: np.ndarray) -> np.ndarray:
        """(T, R, 3) world joint positions in metres."""
        pos = np.empty_like(self.translations)
        for j, p in enumerate(parents):
            pos[:, j] = self.translations[:, j] if p < 0 else pos[:, p] + np.einsum(
                "tij,tj->ti", self.glob[:, p], self.translations[:, j])
        return pos


def targets_from_sources(rig_names: list[str], sources: list[tuple[str, ...]]) -> np.ndarray:
    """(R,) our joint index each rig joint follows (-1: unmapped), from a joint map's ``sources``: per joint
    of ours, the rig joint names whose mean gives its position (only single names identify a rig joint)."""
    index = {n: i for i, n in enumerate(rig_names)}
    absent = sorted({s for src in sources for s in src if s not in index})
    if absent:
        raise SMFError(f"rig: the joint map names joint(s) {absent} that the rig lacks")
    targets = np.full(len(rig_names), -1, dtype=np.int64)
    for ours, src in enumerate(sources):
        if len(src) == 1:
            if targets[index[src[0]]] >= 0:
                raise SMFError(f"rig: joint {src[0]!r} is mapped twice")
            targets[index[src[0]]] = ours
    return targets


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions (w, x, y, z) -> (..., 3, 3)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(
        q.shape[:-1] + (3, 3))


def shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations taking unit vectors a onto b (T, 3) by the shortest arc (opposite vectors: the
    half turn about an axis perpendicular to a)."""
    q = np.concatenate([1.0 + (a * b).sum(-1, keepdims=True), np.cross(a, b)], -1)
    flip = q[:, 0] < 1e-6
    if flip.any():
        e = np.eye(3)[np.argmin(np.abs(a[flip]), axis=-1)]
        q[flip] = np.concatenate([np.zeros((int(flip.sum()), 1)), np.cross(a[flip], e)], -1)
    return _quat_to_matrix(q / np.linalg.norm(q, axis=-1, keepdims=True))


def best_rotation(rest: np.ndarray, now: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotations R minimising sum_k |R rest[k] - now[t, k]|^2 (Kabsch), rest (K, 3), now (T, K, 3)."""
    h = np.einsum("ki,tkj->tij", rest, now)  # sum_k rest_k now_k^T
    u, _, vt = np.linalg.svd(h)
    v = np.swapaxes(vt, -1, -2)
    d = np.sign(np.linalg.det(v @ np.swapaxes(u, -1, -2)))
    fix = np.broadcast_to(np.eye(3), h.shape).copy()
    fix[:, 2, 2] = np.where(d == 0, 1.0, d)
    return v @ fix @ np.swapaxes(u, -1, -2)


def mapped_children(parents: np.ndarray, targets: np.ndarray) -> list[list[int]]:
    """Per rig joint: its mapped child bones, i.e. the mapped joints whose nearest mapped ancestor it is."""
    kids: list[list[int]] = [[] for _ in parents]
    for c in range(len(parents)):
        if targets[c] < 0:
            continue
        a = parents[c]
        while a >= 0 and targets[a] < 0:
            a = parents[a]
        if a >= 0:
            kids[a].append(c)
    return kids


def _rig_joint(targets: np.ndarray, ours: int) -> int:
    """The rig joint following our joint ``ours`` (-1: none)."""
    found = np.flatnonzero(targets == ours)
    return int(found[0]) if len(found) else -1


def leg_length(positions: np.ndarray, legs) -> float:
    """Mean over legs of hip-knee plus knee-ankle length (m), positions (..., J, 3) averaged over frames."""
    pos = positions.reshape(-1, *positions.shape[-2:])
    return float(np.mean([(np.linalg.norm(pos[:, k] - pos[:, h], axis=-1)
                           + np.linalg.norm(pos[:, a] - pos[:, k], axis=-1)).mean() for h, k, a in legs]))


def retarget(joints: np.ndarray, rig: Rig, targets: np.ndarray, *, carrier: int | None = None,
             pelvis: int = PELVIS, legs=LEGS, feet=FEET) -> RigMotion:
    """Our joints (T, J, 3) metres, Y up -> the rig's motion (see the module docstring). ``carrier``: the rig
    joint whose translation carries the path (default the one following our ``pelvis``); it and every joint
    above it up to the root must be unmapped but for the pelvis's own."""
    X = np.asarray(joints, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.int64)
    T, R = len(X), len(rig.names)
    if X.ndim != 3 or X.shape[-1] != 3 or T < 1:
        raise SMFError(f"expected joints (T, J, 3), got {X.shape}")
    if targets.shape != (R,) or targets.max(initial=-1) >= X.shape[1]:
        raise SMFError("rig: targets must give one of our joints (or -1) per rig joint")
    parents = rig.parents
    hips = np.flatnonzero(targets == pelvis)
    if len(hips) != 1:
        raise SMFError("rig: the joint map must name one rig joint for the pelvis")
    h = int(hips[0])
    carrier = h if carrier is None else int(carrier)
    chain, a = [], h
    while a >= 0:
        chain.append(a)
        a = parents[a]
    if carrier not in chain:
        raise SMFError(f"rig: joint {rig.names[carrier]!r} does not lie above the pelvis {rig.names[h]!r}")
    if any(targets[a] >= 0 for a in chain[1:]):
        raise SMFError(f"rig: joints above the pelvis {rig.names[h]!r} must be unmapped")

    rest = rig.rest_positions
    kids = mapped_children(parents, targets)
    glob = np.empty((T, R, 3, 3))
    eye = np.broadcast_to(np.eye(3), (T, 3, 3))
    for j in range(R):
        base = glob[:, parents[j]] if parents[j] >= 0 else eye
        if targets[j] < 0 or not kids[j]:
            glob[:, j] = base
            continue
        r = _unit(rest[kids[j]] - rest[j])  # (K, 3) rest directions of its child bones
        d = _unit(X[:, targets[kids[j]]] - X[:, [targets[j]]])  # (T, K, 3) ours
        if len(kids[j]) == 1:
            glob[:, j] = shortest_arc(_unit(base @ r[0]), d[:, 0]) @ base
        else:
            glob[:, j] = best_rotation(r, d)
    local = glob.copy()
    for j in range(1, R):
        local[:, j] = np.swapaxes(glob[:, parents[j]], -1, -2) @ glob[:, j]

    rig_legs = [tuple(_rig_joint(targets, k) for k in leg) for leg in legs]
    if any(i < 0 for leg in rig_legs for i in leg):
        raise SMFError("rig: the joint map must name the rig's hips, knees and ankles")
    ours_legs = leg_length(X, legs)
    if ours_legs < 1e-6:
        raise SMFError("our motion has legs of length 0")
    scale = leg_length(rest[None], rig_legs) / ours_legs
    path = X[:, pelvis] * scale  # where the rig's pelvis goes
    up = rest[parents[carrier]] if parents[carrier] >= 0 else np.zeros(3)
    trans = np.broadcast_to(rig.offsets, (T, R, 3)).copy()
    trans[:, carrier] = path - (rest[h] - rest[carrier]) - up
    motion = RigMotion(local, glob, trans, scale)
    ours_feet = [k for k in feet if _rig_joint(targets, k) >= 0]
    rig_feet = [_rig_joint(targets, k) for k in ours_feet]
    if rig_feet:
        lift = X[:, ours_feet, 1].min() * scale - motion.positions(parents)[:, rig_feet, 1].min()
        motion.translations[:, carrier, 1] += lift
    return motion
