"""Motion files: load joints/features `.npy` and `.bvh`; save joints, features and BVH.

A motion on disk is one of: joints `.npy` (T, J, 3) in metres, features `.npy` (T, D), or a BVH file.
The kind of a `.npy` is told by its shape (see :func:`skeleton_for_shape`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import MotionFormatError, SMFError
from ..core.io import atomic_path, save_npy
from .bvh import format_bvh, forward_kinematics, read_bvh
from .features import features_from_joints, joints_from_features
from .resample import resample
from .retarget import JointMap, retarget_bvh
from .rigid import RigidMotion, pose_from_joints
from .skeleton import Skeleton, get_skeleton, skeleton_for_shape

MOTION_SUFFIXES = (".npy", ".bvh")
MIN_BONE_M = 1e-3  # a bone shorter than this on average (1 mm) is no bone


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


def npy_header(f, size: int, where: str) -> tuple[tuple[int, ...], np.dtype]:
    """(shape, dtype) of a ``.npy``'s header (any version numpy writes) read from the open file ``f`` of ``size``
    bytes, checked before its data is read: real numbers, and data exactly as long as the header says, so a small
    file cannot ask for gigabytes. MotionFormatError naming ``where`` otherwise."""
    try:
        version = np.lib.format.read_magic(f)
        read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read(f)
    except Exception:  # noqa: BLE001 - numpy raises many types for broken headers
        raise MotionFormatError(f"{where}: not a readable .npy array") from None
    if dtype.hasobject or not np.issubdtype(dtype, np.number) or np.issubdtype(dtype, np.complexfloating):
        raise MotionFormatError(f"{where}: array of dtype {dtype} is not real numbers")
    want = f.tell() + int(np.prod(shape, dtype=np.float64)) * dtype.itemsize
    if size != want:
        raise MotionFormatError(f"{where}: its header says {want:.0f} bytes, the file has {size} "
                                f"({'truncated' if size < want else 'extra bytes'})")
    return tuple(shape), dtype


def check_values(values: np.ndarray, where: str) -> None:
    """MotionFormatError unless every number of a motion file is finite and at most MAX_ABS_VALUE in size."""
    from ..core.limits import MAX_ABS_VALUE

    values = np.asarray(values, dtype=np.float64)
    if not (np.isfinite(values).all() and np.abs(values).max(initial=0.0) <= MAX_ABS_VALUE):
        raise MotionFormatError(f"{where}: values must be finite numbers of at most {MAX_ABS_VALUE:g}")


def load_motion(path: str | Path, skeleton: str | Skeleton | None = None, joint_map: str | None = None) -> Motion:
    """Read a joints `.npy`, a features `.npy`, a `.bvh` written with our skeleton's joint names, or a
    packaged example given as ``example:<name>``; ``joint_map`` (a built-in name such as 'bandai-namco', or a
    JSON file) reads a `.bvh` of another skeleton (raw mocap) onto ours (a `.bvh` of ours is read as it is)."""
    if isinstance(path, str) and path.startswith("example:"):
        path = example_path(path[len("example:"):])
    path = Path(path)
    if path.suffix.lower() not in MOTION_SUFFIXES:
        raise SMFError(f"unsupported motion file extension '{path.suffix}' for {path}; use .npy or .bvh")
    if not path.is_file():
        raise SMFError(f"no such file: {path}")
    if path.suffix.lower() == ".bvh":
        return _load_bvh(path, skeleton, joint_map)
    with open(path, "rb") as f:
        shape, _ = npy_header(f, path.stat().st_size, str(path))  # before any data is read
    sk, kind = skeleton_for_shape(shape) if skeleton is None else _kind_for(shape, get_skeleton(skeleton))
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as e:  # noqa: BLE001 - numpy raises many types for broken files
        raise MotionFormatError(f"{path}: not a readable .npy array ({e.__class__.__name__})") from None
    if not np.isfinite(arr).all():
        raise MotionFormatError(f"{path}: {kind} contain NaN or inf")
    check_values(arr, str(path))
    if kind == "features":
        return Motion(joints_from_features(arr.astype(np.float64), sk), sk, sk.fps, arr)
    joints = arr.astype(np.float64)
    check_bones(joints, sk, str(path))
    return Motion(joints, sk, sk.fps)


def check_bones(joints: np.ndarray, skeleton: Skeleton, where: str) -> None:
    """MotionFormatError when a bone of ``joints`` (T, J, 3) metres has (almost) no length on average: those are
    not a body's joints (every joint at one point, say), and no rigid skeleton fits them."""
    parents = np.asarray(skeleton.parents)
    bones = np.linalg.norm(joints[:, 1:] - joints[:, parents[1:]], axis=-1).mean(0)  # (J-1,) metres
    short = np.flatnonzero(bones < MIN_BONE_M)
    if len(short):
        name = skeleton.joint_names[int(short[0]) + 1]
        raise MotionFormatError(f"{where}: the bone to joint {name} has no length ({bones[short[0]] * 1000:.2f} mm on "
                                "average): not a body's joints")


def _kind_for(shape: tuple[int, ...], sk: Skeleton) -> tuple[Skeleton, str]:
    found, kind = skeleton_for_shape(shape)
    if found.name != sk.name:
        raise MotionFormatError(f"array of shape {shape} does not fit the {sk.name} skeleton")
    return sk, kind


def _load_bvh(path: Path, skeleton: str | Skeleton | None, joint_map: str | None) -> Motion:
    bvh = read_bvh(path)
    candidates = [get_skeleton(skeleton)] if skeleton is not None else [get_skeleton("humanml3d"), get_skeleton("kit")]
    for sk in candidates:
        if sorted(bvh.names) == sorted(sk.joint_names):  # BVH lists joints depth-first, we index by SMPL order
            order = [list(bvh.names).index(n) for n in sk.joint_names]
            return Motion(resample(forward_kinematics(bvh)[:, order], bvh.fps, sk.fps), sk, sk.fps)
    if joint_map is not None:

        jm = JointMap.named(joint_map)
        sk = get_skeleton(jm.skeleton)
        return Motion(retarget_bvh(bvh, jm), sk, sk.fps)
    raise SMFError(
        f"{path}: BVH joints {bvh.names[:3]}... are not a {'/'.join(s.name for s in candidates)} skeleton; "
        "read it through a joint map with --joint-map NAME|FILE (built-in: bandai-namco; format in "
        "docs/data.md)"
    )


def save_bvh(joints: np.ndarray, path: str | Path, skeleton: str | Skeleton = "humanml3d",
             fps: float | None = None) -> None:
    """Write joints (T, J, 3) in metres as a BVH file (metres, Y up) with our skeleton's joint names: the
    closed-form rigid pose of the joints (exact for a rigid motion; see :func:`save_rigid_bvh` for a
    :class:`RigidMotion`)."""
    save_rigid_bvh(rigid_pose(joints, skeleton), path, fps)


def rigid_pose(joints: np.ndarray, skeleton: str | Skeleton = "humanml3d") -> RigidMotion:
    """The closed-form rigid pose of joints (T, J, 3) (exact for a rigid motion; mean bone lengths)."""
    sk = get_skeleton(skeleton)
    joints = np.asarray(joints, dtype=np.float64)
    offsets, local = pose_from_joints(joints, sk)
    return RigidMotion(offsets, local, joints[:, 0], sk.name)


def rigid_bvh_text(motion: RigidMotion, fps: float | None = None) -> str:
    """The BVH text (metres, Y up, our joint names) of a :class:`RigidMotion`: its own skeleton and rotations,
    so the file reads back to ``motion.joints()``."""
    sk = get_skeleton(motion.skeleton)
    return format_bvh(names=list(sk.joint_names), parents=np.array(sk.parents), offsets=motion.offsets,
                      rotations=motion.rotations, root_positions=motion.root, frame_time=1.0 / (fps or sk.fps))


def save_rigid_bvh(motion: RigidMotion, path: str | Path, fps: float | None = None) -> None:
    """Write a :class:`RigidMotion` as a BVH file, atomically (see :func:`rigid_bvh_text`)."""
    with atomic_path(path) as tmp:
        tmp.write_text(rigid_bvh_text(motion, fps), encoding="utf-8")


def bvh_round_trip_error(joints: np.ndarray, motion: RigidMotion | None = None,
                         skeleton: str | Skeleton = "humanml3d", fps: float | None = None) -> float:
    """Largest distance (m) between joints (T, J, 3) as a joints ``.npy`` holds them (float32) and the BVH file
    written for them (from ``motion`` when given, as `smf generate` does, else by :func:`save_bvh`), read back."""
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.bvh"
        if motion is not None:
            save_rigid_bvh(motion, path, fps)
        else:
            save_bvh(joints, path, skeleton, fps)
        back = load_motion(path, skeleton).joints
    return float(np.linalg.norm(back - np.asarray(joints, np.float32), axis=-1).max())


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
