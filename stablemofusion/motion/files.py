"""Motion files: load joints/features `.npy` and `.bvh`; save joints, features and BVH.

A motion on disk is one of: joints `.npy` (T, J, 3) in metres, features `.npy` (T, D), or a BVH file.
The kind of a `.npy` is told by its shape (see :func:`skeleton_for_shape`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import MotionFormatError, SMFError
from ..io import save_npy
from .bvh import forward_kinematics, read_bvh, write_bvh
from .features import features_from_joints, joints_from_features
from .skeleton import Skeleton, get_skeleton, skeleton_for_shape

MOTION_SUFFIXES = (".npy", ".bvh")


@dataclass
class Motion:
    """Joint positions (T, J, 3) in metres with their skeleton; ``features`` when the file held them."""

    joints: np.ndarray
    skeleton: Skeleton
    fps: float
    features: np.ndarray | None = None


def example_path(name: str) -> Path:
    """The packaged example motion ``name`` (see stablemofusion/assets/examples/README.md)."""
    from importlib import resources

    folder = resources.files("stablemofusion") / "assets" / "examples"
    path = Path(str(folder / f"{name}.npy"))
    if not path.is_file():
        known = sorted(p.name[:-4] for p in folder.iterdir() if p.name.endswith(".npy"))
        raise SMFError(f"no example motion named {name!r}; known: {', '.join(known)}")
    return path


def load_motion(path: str | Path, skeleton: str | Skeleton | None = None) -> Motion:
    """Read a joints `.npy`, a features `.npy`, a `.bvh` written with our skeleton's joint names, or a
    packaged example given as ``example:<name>``."""
    if isinstance(path, str) and path.startswith("example:"):
        path = example_path(path[len("example:"):])
    path = Path(path)
    if path.suffix.lower() not in MOTION_SUFFIXES:
        raise SMFError(f"unsupported motion file extension '{path.suffix}' for {path}; use .npy or .bvh")
    if not path.is_file():
        raise SMFError(f"no such file: {path}")
    if path.suffix.lower() == ".bvh":
        return _load_bvh(path, skeleton)
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - numpy raises many types for broken files
        raise MotionFormatError(f"{path}: not a readable .npy array ({e.__class__.__name__})") from None
    if not np.issubdtype(arr.dtype, np.number):
        raise MotionFormatError(f"{path}: array of dtype {arr.dtype} is not numeric")
    sk, kind = skeleton_for_shape(arr.shape) if skeleton is None else _kind_for(arr.shape, get_skeleton(skeleton))
    if not np.isfinite(arr).all():
        raise MotionFormatError(f"{path}: {kind} contain NaN or inf")
    if kind == "features":
        return Motion(joints_from_features(arr.astype(np.float64), sk), sk, sk.fps, arr)
    return Motion(arr.astype(np.float64), sk, sk.fps)


def resample(x: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Linearly resample a motion (T, ...) from ``src_fps`` to ``dst_fps`` over the same duration."""
    if abs(src_fps - dst_fps) < 1e-9 or len(x) < 2:
        return x
    t_src = np.arange(len(x)) / src_fps
    n = int(np.floor(t_src[-1] * dst_fps + 1e-9)) + 1
    pos = np.arange(n) / dst_fps * src_fps
    i0 = np.minimum(np.floor(pos).astype(int), len(x) - 2)
    w = (pos - i0).reshape((-1,) + (1,) * (x.ndim - 1))
    return x[i0] * (1 - w) + x[i0 + 1] * w


def _kind_for(shape: tuple[int, ...], sk: Skeleton) -> tuple[Skeleton, str]:
    found, kind = skeleton_for_shape(shape)
    if found.name != sk.name:
        raise MotionFormatError(f"array of shape {shape} does not fit the {sk.name} skeleton")
    return sk, kind


def _load_bvh(path: Path, skeleton: str | Skeleton | None) -> Motion:
    bvh = read_bvh(path)
    candidates = [get_skeleton(skeleton)] if skeleton is not None else [get_skeleton("humanml3d"), get_skeleton("kit")]
    for sk in candidates:
        if sorted(bvh.names) == sorted(sk.joint_names):  # BVH lists joints depth-first, we index by SMPL order
            order = [list(bvh.names).index(n) for n in sk.joint_names]
            return Motion(resample(forward_kinematics(bvh)[:, order], bvh.fps, sk.fps), sk, sk.fps)
    raise SMFError(
        f"{path}: BVH joints {bvh.names[:3]}... are not a {'/'.join(s.name for s in candidates)} skeleton; "
        "retarget it first with `smf prepare bvh --joint-map`"
    )


def _branch_frame(joints: np.ndarray, sk: Skeleton, joint: int, children: list[int]) -> np.ndarray:
    """(T, 3, 3) orientation of a branching joint: X from its -X child to its +X child, Y towards the
    remaining (up or down) child, Z = X x Y."""
    raw = sk.offsets_array
    pos_x = [c for c in children if raw[c][0] > 0]
    neg_x = [c for c in children if raw[c][0] < 0]
    other = [c for c in children if raw[c][0] == 0]
    if len(pos_x) != 1 or len(neg_x) != 1 or len(other) != 1:
        raise SMFError(f"cannot orient branching joint {sk.joint_names[joint]}")
    x = joints[:, pos_x[0]] - joints[:, neg_x[0]]
    x /= np.linalg.norm(x, axis=-1, keepdims=True) + 1e-12
    y = (joints[:, other[0]] - joints[:, joint]) * np.sign(raw[other[0]][1])
    y -= (y * x).sum(-1, keepdims=True) * x
    y /= np.linalg.norm(y, axis=-1, keepdims=True) + 1e-12
    return np.stack([x, y, np.cross(x, y)], axis=-1)


def _shortest_arc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(T, 3, 3) rotation taking unit vectors a onto b (T, 3) by the shortest arc (Rodrigues)."""
    v = np.cross(a, b)
    c = (a * b).sum(-1)
    k = np.zeros(a.shape[:-1] + (3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    scale = 1.0 / np.maximum(1.0 + c, 1e-9)
    return np.eye(3) + k + (k @ k) * scale[..., None, None]


def bvh_pose(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d") -> tuple[np.ndarray, np.ndarray]:
    """Inverse kinematics for BVH export: joints (T, J, 3) -> (rest offsets (J, 3), local rotations (T, J, 3, 3)).

    Branching joints (pelvis, upper spine) get the frame spanned by their children and rest offsets that
    are the children's mean position in that frame; every other bone gets its mean length along the
    skeleton's rest direction and the shortest rotation from its parent-rotated rest direction, so the
    twist of each limb follows its parent. Leaf joints keep their parent's rotation.
    """
    sk = get_skeleton(skeleton)
    T, J = joints.shape[:2]
    parents = sk.parents
    children = {j: [c for c in range(J) if parents[c] == j] for j in range(J)}
    raw = sk.offsets_array
    offsets = np.zeros((J, 3))
    glob = np.zeros((T, J, 3, 3))
    for j in range(J):  # joints are in topological order
        parent_rot = glob[:, parents[j]] if parents[j] >= 0 else np.broadcast_to(np.eye(3), (T, 3, 3))
        kids = children[j]
        if len(kids) > 1:
            glob[:, j] = _branch_frame(joints, sk, j, kids)
            for c in kids:
                local = np.einsum("tij,ti->tj", glob[:, j], joints[:, c] - joints[:, j])
                offsets[c] = local.mean(0)
        elif len(kids) == 1:
            c = kids[0]
            bone = joints[:, c] - joints[:, j]
            length = np.linalg.norm(bone, axis=-1)
            offsets[c] = raw[c] * length.mean()
            rest_dir = np.einsum("tij,j->ti", parent_rot, raw[c])
            glob[:, j] = _shortest_arc(rest_dir, bone / np.maximum(length, 1e-12)[:, None]) @ parent_rot
        else:
            glob[:, j] = parent_rot
    local = glob.copy()
    for j in range(1, J):
        local[:, j] = np.swapaxes(glob[:, parents[j]], -1, -2) @ glob[:, j]
    return offsets, local


def save_bvh(joints: np.ndarray, path: str | Path, skeleton: str | Skeleton = "humanml3d",
             fps: float | None = None) -> None:
    """Write joints (T, J, 3) in metres as a BVH file (metres, Y up) with our skeleton's joint names."""
    sk = get_skeleton(skeleton)
    offsets, local = bvh_pose(np.asarray(joints, dtype=np.float64), sk)
    write_bvh(path, names=list(sk.joint_names), parents=np.array(sk.parents), offsets=offsets, rotations=local,
              root_positions=joints[:, 0], frame_time=1.0 / (fps or sk.fps))


def save_motion(motion: Motion, path: str | Path, kind: str) -> None:
    """Write ``motion`` as kind 'joints' (.npy), 'features' (.npy) or 'bvh'; atomically."""
    path = Path(path)
    if kind == "bvh":
        save_bvh(motion.joints, path, motion.skeleton, motion.fps)
    elif kind == "joints":
        save_npy(path, motion.joints.astype(np.float32))
    elif kind == "features":
        feats = motion.features if motion.features is not None else features_from_joints(motion.joints, motion.skeleton)
        save_npy(path, feats.astype(np.float32))
    else:
        raise SMFError(f"unknown output kind {kind!r}; use joints, features or bvh")
