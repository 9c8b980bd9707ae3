"""Forward kinematics: the one place where local transforms are composed down a joint tree.

Every forward kinematics of the package calls :func:`forward_kinematics`: the rigid body
(:class:`stablemofusion.motion.rigid.RigidMotion`, the batched fit), the BVH reader (its Euler channels
converted to local rotation matrices first), rest poses (glTF, BVH unit detection) and bone-vector sums
(the L-BFGS fit's parametrisation, :func:`stablemofusion.motion.features.uniform_skeleton`).
``tests/motion/test_kinematics.py`` fails when a second loop composing transforms down ``parents`` appears.

Convention (BVH's): joints are indexed so that every parent precedes its children, with one root at index 0
(``parents[0] == -1``). ``offsets[c]`` is joint c's rest position relative to its parent, in the parent's
frame (metres); ``rotations[j]`` joint j's local rotation matrix. Global rotations G_0 = R_0,
G_c = G_p @ R_c; positions p_0 = root, p_c = p_p + G_p @ offsets[c] (p = parents[c]; the root's own offset
is not used). Without rotations (``None``) every G is the identity: p_c = p_p + offsets[c], the offsets
being already in world axes (a rest pose, or bone vectors).

Written once against the array API (:func:`stablemofusion.motion.arrays.namespace`): numpy in gives numpy out,
torch in gives torch out (differentiable, any device and dtype). Vectorised over frames and batch: one step
per depth of the tree, all joints of a depth at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np

from ..core.errors import SMFError
from .arrays import device, namespace


@dataclass(frozen=True)
class Levels:
    """A joint tree by depth: ``joints[d]`` the joints at depth d + 1, ``parents[d]`` their parents as
    indices into the joints at depth d, ``order`` the permutation from depth order back to joint order."""

    joints: tuple[np.ndarray, ...]
    parents: tuple[np.ndarray, ...]
    order: np.ndarray


def as_parents(parents) -> tuple[int, ...]:
    """``parents`` (a sequence or an array of ints) as a tuple of ints (the key of the cached :func:`levels`)."""
    return tuple(int(p) for p in (parents.tolist() if hasattr(parents, "tolist") else parents))


@lru_cache(maxsize=64)
def levels(parents: tuple[int, ...]) -> Levels:
    """The (cached) :class:`Levels` of ``parents`` (J,): -1 for the single root at index 0, every parent
    before its children; raises SMFError otherwise."""
    J = len(parents)
    if J == 0 or parents[0] != -1 or any(not 0 <= p < j for j, p in enumerate(parents) if j):
        raise SMFError("a joint tree needs one root at index 0 (parent -1) and every parent before its children")
    depth = [0] * J
    for j in range(1, J):
        depth[j] = depth[parents[j]] + 1
    by_depth = [[j for j in range(J) if depth[j] == d] for d in range(max(depth) + 1)]
    place = {j: i for level in by_depth for i, j in enumerate(level)}  # index within its own depth
    flat = [j for level in by_depth for j in level]
    index = lambda xs: np.asarray(xs, dtype=np.int64)  # noqa: E731
    return Levels(tuple(index(level) for level in by_depth[1:]),
                  tuple(index([place[parents[j]] for j in level]) for level in by_depth[1:]),
                  index([flat.index(j) for j in range(J)]))


def forward_kinematics(offsets, rotations, root, parents: Sequence[int] | np.ndarray, *,
                       global_rotations: bool = False):
    """Joint positions of a posed tree (convention: module docstring).

    ``offsets`` (..., J, 3) metres (e.g. (J, 3) for one skeleton, (N, J, 3) per frame, (M, 1, J, 3) per
    motion of a batch), local ``rotations`` (..., J, 3, 3) or None (all identity), ``root`` (..., 3) metres:
    the root joint's position; the leading dimensions broadcast. ``parents`` (J,) ints.
    Returns positions (..., J, 3) metres, and with ``global_rotations`` also the global rotations
    (..., J, 3, 3) (``rotations`` required). numpy in: numpy out; torch in: torch out, differentiable.
    """
    lv = levels(as_parents(parents))
    if rotations is None and global_rotations:
        raise SMFError("global rotations need local rotations")
    xp = namespace(offsets, rotations, root)
    index = (lambda a: xp.asarray(a, device=device(root)))  # noqa: E731
    pos = root[..., None, :]  # (..., 1, 3): depth 0, broadcast to the others' batch below
    glob = None if rotations is None else rotations[..., :1, :, :]
    all_pos, all_glob = [pos], [glob]
    for js, idx in zip(lv.joints, lv.parents):  # take: several times faster than x[..., idx, :] in torch
        js, idx = index(js), index(idx)
        off = xp.take(offsets, js, axis=-2)
        if glob is None:
            pos = xp.take(pos, idx, axis=-2) + off
        else:
            g_par = xp.take(glob, idx, axis=-3)
            pos = xp.take(pos, idx, axis=-2) + (g_par @ off[..., None])[..., 0]
            glob = g_par @ xp.take(rotations, js, axis=-3)
            all_glob.append(glob)
        all_pos.append(pos)
    if len(all_pos) > 1:  # depth 1 on has every leading dimension (root, offsets, rotations)
        all_pos[0] = xp.broadcast_to(all_pos[0], tuple(all_pos[1].shape[:-2]) + (1, 3))
    positions = xp.take(xp.concat(all_pos, axis=-2), index(lv.order), axis=-2)
    if not global_rotations:
        return positions
    all_glob[0] = xp.broadcast_to(all_glob[0], tuple(all_glob[-1].shape[:-3]) + (1, 3, 3))
    return positions, xp.take(xp.concat(all_glob, axis=-3), index(lv.order), axis=-3)
