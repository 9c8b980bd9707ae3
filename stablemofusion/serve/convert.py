"""POST /v1/convert: an uploaded .bvh or .npy read into joints for the viewer, bounded before it is parsed.

Checked before parsing: the upload's size (serve/guard.py), a BVH's frame count and frame time (1 to 1000
frames per second, at most MAX_CONVERT_SECONDS), a .npy's header (a known skeleton's shape, numeric, at
most MAX_CONVERT_SECONDS of frames). Checked after: every value finite and of a sane size. Runs on a thread,
never on the event loop. Raises :class:`ServeError` (422) naming the file.
"""

from __future__ import annotations

import io
import re
import tempfile
from pathlib import Path

import numpy as np

from .http_errors import ServeError
from ..core.limits import MAX_FRAME_TIME_S, MIN_FRAME_TIME_S
from .server_limits import (MAX_ABS_METRES, MAX_CONVERT_FRAMES, MAX_CONVERT_SECONDS, MAX_CONVERT_VALUES,
                            MAX_HIERARCHY_BYTES)
from ..core.output import joints_json_bytes

SUFFIXES = (".bvh", ".npy")
_MOTION = re.compile(rb"^[ \t]*MOTION[ \t]*\r?$", re.M)
_HEADER_BYTES = 1024  # where 'Frames:' and 'Frame Time:' must follow MOTION


def check_suffix(filename: str) -> str:
    suffix = Path(filename).suffix.lower()
    if suffix not in SUFFIXES:
        raise ServeError(415, f"only .bvh and .npy files can be viewed, got {filename[:100]!r}")
    return suffix


def convert_upload(data: bytes, filename: str) -> bytes:
    """The JSON the viewer shows for an uploaded file (``{"fps", "frames", "joints"}``)."""
    suffix = check_suffix(filename)
    (_check_bvh if suffix == ".bvh" else _check_npy)(data, filename)
    joints, fps = _load(data, suffix, filename)
    if len(joints) > MAX_CONVERT_SECONDS * fps + 1:
        raise ServeError(422, f"{filename}: longer than {MAX_CONVERT_SECONDS:g} s")
    if not (np.isfinite(joints).all() and np.abs(joints).max(initial=0.0) <= MAX_ABS_METRES):
        raise ServeError(422, f"{filename}: joint positions are not finite or farther than {MAX_ABS_METRES:g} m")
    return joints_json_bytes(joints, fps)


def _check_bvh(data: bytes, filename: str) -> None:
    m = _MOTION.search(data)
    lines = [] if m is None else [s.strip() for s in data[m.end():m.end() + _HEADER_BYTES].splitlines() if s.strip()]
    if len(lines) < 2 or not lines[0].startswith(b"Frames:") or not lines[1].startswith(b"Frame Time:"):
        raise ServeError(422, f"{filename}: not a BVH file (no MOTION section with 'Frames:' and 'Frame Time:')")
    try:
        frames, frame_time = int(lines[0][len(b"Frames:"):]), float(lines[1][len(b"Frame Time:"):])
    except ValueError:
        raise ServeError(422, f"{filename}: 'Frames:' or 'Frame Time:' is not a number") from None
    if not MIN_FRAME_TIME_S <= frame_time <= MAX_FRAME_TIME_S:
        raise ServeError(422, f"{filename}: Frame Time must be between {MIN_FRAME_TIME_S:g} and "
                              f"{MAX_FRAME_TIME_S:g} s, got {frame_time:g}")
    if not 0 < frames * frame_time <= MAX_CONVERT_SECONDS:
        raise ServeError(422, f"{filename}: the viewer shows motions of up to {MAX_CONVERT_SECONDS:g} s, got "
                              f"{frames} frames of {frame_time:g} s")
    if m.start() > MAX_HIERARCHY_BYTES:
        raise ServeError(422, f"{filename}: its HIERARCHY has {m.start()} bytes, at most {MAX_HIERARCHY_BYTES}")
    channels = sum(int(n) for n in re.findall(rb"CHANNELS[ \t]+(\d{1,3})", data[:m.start()]))
    if frames > MAX_CONVERT_FRAMES or frames * max(channels, 1) > MAX_CONVERT_VALUES:
        raise ServeError(422, f"{filename}: {frames} frames of {channels} channels is more than the viewer reads "
                              f"(at most {MAX_CONVERT_FRAMES} frames and {MAX_CONVERT_VALUES} values)")


def _check_npy(data: bytes, filename: str) -> None:
    """The header of an uploaded .npy (:func:`~stablemofusion.motion.files.npy_header`, as every door reads one): a
    real numeric array of a known skeleton's shape, at most MAX_CONVERT_SECONDS long, whose data is exactly as long
    as the header says; then its values (:func:`~stablemofusion.motion.files.check_values`)."""
    from ..core.errors import SMFError
    from ..motion.files import check_values, npy_header
    from ..motion.skeleton import skeleton_for_shape

    try:
        shape, _ = npy_header(io.BytesIO(data), len(data), filename)  # its messages name the file
    except SMFError as e:
        raise ServeError(422, str(e)) from None
    try:
        sk, _ = skeleton_for_shape(shape)
    except SMFError as e:
        raise ServeError(422, f"{filename}: {e}") from None
    if shape[0] > MAX_CONVERT_SECONDS * sk.fps:
        raise ServeError(422, f"{filename}: the viewer shows motions of up to {MAX_CONVERT_SECONDS:g} s, got "
                              f"{shape[0]} frames at {sk.fps:g} fps")
    _check_values(np.load(io.BytesIO(data), allow_pickle=False), filename)


def _check_values(values: np.ndarray, filename: str) -> None:
    from ..core.errors import SMFError
    from ..motion.files import check_values

    try:
        check_values(values, filename)
    except SMFError as e:
        raise ServeError(422, str(e)) from None


def _load(data: bytes, suffix: str, filename: str) -> tuple[np.ndarray, float]:
    """Joints (T, 22, 3) of the upload, read by the package's own loader (never unpickled)."""
    from ..core.errors import SMFError
    from ..motion.files import load_motion

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"upload{suffix}"
        path.write_bytes(data)
        try:
            if suffix == ".bvh":
                _check_values(_bvh_values(path), filename)
            m = load_motion(path)  # .npy with allow_pickle=False
        except SMFError as e:
            raise ServeError(422, str(e).replace(str(path), filename)) from None
        except (ValueError, OverflowError, MemoryError, IndexError, KeyError) as e:
            raise ServeError(422, f"{filename}: not a readable {suffix} file ({type(e).__name__})") from None
    if m.skeleton.name != "humanml3d":
        raise ServeError(422, f"{filename}: the viewer shows 22-joint (HumanML3D) motions, not {m.skeleton.name}")
    return m.joints, m.fps


def _bvh_values(path: Path) -> np.ndarray:
    from ..motion.bvh import read_bvh

    bvh = read_bvh(path)
    return np.concatenate([bvh.offsets.ravel(), bvh.motion.ravel()])
