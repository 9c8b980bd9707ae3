"""Editing a given motion with text: keep a part of it (frames, half of the body, or the root path) and let
the model generate the rest, the known part imposed at every denoising step.

Two ways to impose it (``impose``): ``x0`` replaces the known entries of the model's clean-motion prediction
at every step (and projects the root onto the constraint); ``xt`` replaces them in the noisy sample after
every step, noised to that step's level (imputation). Both end exactly on the known part.

Modes (``EDIT_MODES``), on a source motion of Ts frames and an output of T frames:

- ``prefix``: keep the first ``keep_start`` frames, generate the rest (a continuation);
- ``suffix``: keep the last ``keep_end`` frames at the end of the output; the output is placed in the world so
  that those frames are where the source has them;
- ``inbetween``: keep both; the generated middle lands the end block at the source's heading and position;
- ``upper-body`` / ``lower-body``: regenerate that half of the body, keep the other (``upper-body`` keeps the
  root, legs, feet and foot contacts);
- ``trajectory``: follow a root XZ path (the source's, or a (T, 2) path in metres).

Everything is in the source's canonical frame (frame 0 at the origin, facing +Z: the HumanML3D convention).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import SMFError
from .limits import EDIT_MODES, IMPOSE
from ..motion.arrays import device as array_device
from ..motion.arrays import namespace
from ..motion.features import feature_slices
from ..motion.resample import resample
from ..motion.rigid import RigidMotion
from ..motion.root import follow_path, headings, land_at, root_xz
from ..motion.skeleton import Skeleton, get_skeleton

SEAM_FRAMES = 10  # generated frames next to a kept block over which a seam is blended (0.5 s at 20 fps)
MODE_FLAGS = {"prefix": ("keep_start",), "suffix": ("keep_end",), "inbetween": ("keep_start", "keep_end")}


@dataclass
class EditPlan:
    """What an edit keeps, in an output of ``frames`` frames: known features (T, D) in dataset units where
    ``mask`` (T, D) is True; ``kept`` (T,) frames known whole and ``source_frame`` (T,) the source frame each
    output frame keeps (-1 where generated); root constraints: ``land`` (start, frame, half-angle, xz (2,))
    for in-betweening, ``path`` (T, 2) metres for trajectories, ``anchor`` (output frame, source frame) whose
    world placement the output takes from the source (suffix)."""

    mode: str
    frames: int
    known: np.ndarray
    mask: np.ndarray
    kept: np.ndarray
    source_frame: np.ndarray
    land: tuple[int, int, float, np.ndarray] | None = None
    path: np.ndarray | None = None
    anchor: tuple[int, int] | None = None

    def on(self, device=None) -> "PlanTensors":
        """The plan's arrays as float64 / bool tensors on ``device``, converted once for a whole sampling call;
        ``device`` None: as numpy arrays (the portable runtime)."""
        if device is None:
            return PlanTensors(self.known, self.mask, self.kept, self.land, self.path)
        import torch

        land = None
        if self.land is not None:
            start, frame, angle, xz = self.land
            land = (start, frame, angle, torch.from_numpy(xz).to(device))
        return PlanTensors(torch.from_numpy(self.known).to(device), torch.from_numpy(self.mask).to(device),
                           torch.from_numpy(self.kept).to(device), land,
                           None if self.path is None else torch.from_numpy(self.path).to(device))

    def project(self, features):
        """:meth:`PlanTensors.project` of one motion's features (T, D) in dataset units (numpy or torch)."""
        return self.on(None if isinstance(features, np.ndarray) else features.device).project(features)


@dataclass(frozen=True)
class PlanTensors:
    """An :class:`EditPlan`'s known part and root constraints as arrays of one kind (numpy, or torch tensors on
    one device; float64)."""

    known: object
    mask: object
    kept: object
    land: tuple | None
    path: object | None

    def project(self, features):
        """Impose the known entries and the root constraints on features (T, D) in dataset units, and blend
        the generated frames next to kept blocks into them (:func:`blend_seams`)."""
        xp = namespace(features, self.known)
        f = xp.where(self.mask, xp.astype(self.known, features.dtype), features)
        if bool(self.kept.any()) and not bool(self.kept.all()):
            f = blend_seams(f, self.kept)
        if self.land is not None:
            start, frame, angle, xz = self.land
            f = land_at(f, start, frame, angle, xp.astype(xz, f.dtype))
        if self.path is not None:
            f = follow_path(f, xp.astype(self.path, f.dtype))
        return f


def check_edit_inputs(mode: str, keep_start: float, keep_end: float, seconds: float | None) -> None:
    """SMFError naming the flag: a bad mode, a negative length, or a mode without the length it needs."""
    if mode not in EDIT_MODES:
        raise SMFError(f"edit mode must be one of {', '.join(EDIT_MODES)}, got {mode!r}")
    for name, value in (("keep_start", keep_start), ("keep_end", keep_end), ("seconds", seconds)):
        if value is not None and not (np.isfinite(value) and value >= 0):
            raise SMFError(f"--{name.replace('_', '-')} must be a finite number of seconds >= 0, got {value}")
    values = {"keep_start": keep_start, "keep_end": keep_end}
    for name in MODE_FLAGS.get(mode, ()):
        if not values[name] > 0:
            raise SMFError(f"a {mode} edit needs --{name.replace('_', '-')} SECONDS (the part of the source it "
                           f"keeps)")


def plan_edit_for(mode: str, source: np.ndarray, skeleton: Skeleton, fps: float, min_frames: int, max_frames: int, *,
                  keep_start: float = 0.0, keep_end: float = 0.0, seconds: float | None = None,
                  path: np.ndarray | None = None) -> EditPlan:
    """:func:`plan_edit` with lengths in seconds at ``fps``, for a model that makes ``min_frames`` to ``max_frames``
    at once (SMFError for an edit outside that range)."""
    plan = plan_edit(mode, source, skeleton, keep_start=int(round(keep_start * fps)),
                     keep_end=int(round(keep_end * fps)), frames=None if seconds is None else int(round(seconds * fps)),
                     path=path)
    if not min_frames <= plan.frames <= max_frames:
        raise SMFError(f"an edit of {plan.frames / fps:g} s is outside the {min_frames / fps:g} to {max_frames / fps:g} "
                       "s this model generates at once; for longer motions use `smf generate --timeline`")
    return plan


def x0_constraint(plan: EditPlan, mean: np.ndarray, std: np.ndarray):
    """The portable runtime's x0 hook imposing ``plan`` (``impose="x0"`` of the torch backend's :func:`~stablemofusion.backends.torch_sampling.edit_hooks`, in numpy): the known
    entries replace the prediction's (B, T, D, normalised), then the root constraints are projected."""
    mean32, std32 = np.asarray(mean, np.float32), np.asarray(std, np.float32)
    known = ((plan.known.astype(np.float32) - mean32) / std32)[None]
    mask = plan.mask[None]
    arrays = plan.on(None)

    def hook(x0: np.ndarray) -> np.ndarray:
        x0 = np.where(mask, known, x0)
        if plan.land is None and plan.path is None:
            return x0
        feats = x0.astype(np.float64) * std32.astype(np.float64) + mean32.astype(np.float64)
        return np.stack([(arrays.project(f).astype(np.float32) - mean32) / std32 for f in feats])

    return hook


def _seam_dims(xp, f):
    """(D,) True on the per-frame features a seam blends: not the root's yaw and XZ velocities (they integrate) nor the
    foot contacts."""
    dims = np.ones(f.shape[-1], dtype=bool)
    dims[:3] = False
    dims[-4:] = False
    return xp.asarray(dims, device=array_device(f))


def _fade(i, frames: int):
    """Weights of the position and the velocity offsets at ``i`` frames after a seam (any shape, float): the first
    frame (0) takes the whole position offset, the second the position plus the whole velocity offset, and both fade
    to zero value and zero slope at ``frames`` (cubic Hermite curves on frames 1..frames)."""
    xp = namespace(i)
    s = xp.clip((i - 1) / (frames - 1), min=0)
    h0 = 2 * s ** 3 - 3 * s ** 2 + 1
    h1 = i * xp.clip(1 - i / frames, min=0) ** 2 * frames ** 2 / (frames - 1) ** 2  # integer constants: exact in a graph
    return h0, h1


def blend_after(features, start, n, frames: int = SEAM_FRAMES):
    """Features (..., T, D) whose ``n`` generated frames from ``start`` on continue the kept frames before
    ``start`` (at least 2) without a jump in position or velocity: the offset that puts frame ``start`` where the
    kept block's last step leads, with the block's last velocity, fading out over ``frames`` frames (:func:`_fade`).
    Loop-free and shape-free: ``start`` and ``n`` are ints or 1-element integer arrays (the graph ``continue.onnx``
    runs it); needs ``start + 1 < T`` and ``n <= frames``."""
    xp = namespace(features)
    f = features
    T = f.shape[-2]

    def row(k):
        return xp.take(f, xp.reshape(xp.asarray(k, device=array_device(f)), (1,)), axis=-2)  # (..., 1, D)

    last, before, first, second = row(start - 1), row(start - 2), row(start), row(start + 1)
    v_kept = last - before
    dp = last + v_kept - first
    dv = v_kept - (second - first)
    i = xp.astype(xp.arange(T, device=array_device(f))[:, None] - start, f.dtype)  # (T, 1) frames after the seam
    inside = (i >= 0) & (i < n)
    h0, h1 = _fade(i, frames)
    zero = xp.zeros_like(h0)
    offset = xp.where(inside, h0, zero) * dp + xp.where(inside, h1, zero) * dv
    return f + xp.where(_seam_dims(xp, f), offset, xp.zeros_like(offset))


def continue_features(features, known, keep):
    """A window's features (..., T, D) in dataset units whose first ``keep`` frames continue a motion, made to
    continue it: those frames replaced by ``known`` (..., T, D; the motion's last ``keep`` frames first, the rest
    unread) and the generated frames after them blended into it (:func:`blend_after`; what
    :meth:`PlanTensors.project` does for a prefix edit). ``keep``: an int or a 1-element integer array, 2 to T - 2.
    A timeline's windows run it (Python), and so does the graph ``continue.onnx`` (JavaScript)."""
    xp = namespace(features, known)
    T = features.shape[-2]
    kept = xp.arange(T, device=array_device(features))[:, None] < keep  # (T, 1)
    f = xp.where(kept, xp.astype(known, features.dtype), features)
    return blend_after(f, keep, SEAM_FRAMES)


def blend_seams(features, kept, frames: int = SEAM_FRAMES):
    """Make the generated frames next to each block of ``kept`` (T,) frames continue it without a jump in
    position or velocity (inertialisation, as game engines blend animations): the first generated frame
    after a block gets an offset that puts it where the block's last step leads and gives it the block's
    last velocity; the offset fades to zero over ``frames`` frames along a cubic Hermite curve (value and
    slope at the seam, zero value and slope at the end; :func:`blend_after`). The same, backwards, before a
    block. Applies to every per-frame feature (root height, joint positions, rotations, velocities), not to
    the root's yaw and XZ velocities (which integrate) nor to the foot contacts. features (T, D) -> (T, D),
    numpy or torch."""
    xp = namespace(features)
    f = features + 0  # a copy
    T = len(f)
    dims = _seam_dims(xp, f)
    k = [bool(v) for v in (kept.tolist() if hasattr(kept, "tolist") else kept)]

    for b in range(2, T - 1):
        if k[b - 1] and k[b - 2] and not k[b]:  # a block ends at b - 1: blend forwards from b
            n = min(frames, next((i for i in range(b, T) if k[i]), T) - b)
            f = blend_after(f, b, n, frames)
    for b in range(T - 2, 1, -1):
        if k[b] and k[b + 1] and not k[b - 1]:  # a block starts at b: blend backwards from b - 1
            prev = next((i for i in range(b - 1, -1, -1) if k[i]), -1)
            n = min(frames, b - 1 - prev)
            v_kept = f[b + 1] - f[b]
            dp = f[b] - v_kept - f[b - 1]
            dv = v_kept - (f[b - 1] - f[b - 2])
            h0, h1 = _fade(xp.astype(xp.arange(n, device=array_device(f)), f.dtype)[:, None], frames)
            # going backwards in time the slope of the offset is -dv
            f[b - n:b, dims] += xp.flip(h0 * dp - h1 * dv, axis=0)[:, dims]
    return f


def splice_rigid(edited: RigidMotion, source: RigidMotion, plan: EditPlan) -> RigidMotion:
    """The edited rigid motion with its kept part taken from the source's rigid motion (same skeleton and
    world frame), so kept frames, or the kept half of the body, are the source's exactly: the rigid stage
    fits all frames together, which would move them by up to about 2 cm. The body is the source's (its
    bone offsets, which differ from the edit's own fit by a few millimetres)."""
    rotations, root = edited.rotations.copy(), edited.root.copy()
    sk = get_skeleton(edited.skeleton)
    if plan.mode in ("upper-body", "lower-body"):
        lower = list(sk.lower_body)
        keep = lower if plan.mode == "upper-body" else [j for j in range(sk.num_joints) if j not in lower]
        rotations[:, keep] = source.rotations[:, keep]
        if plan.mode == "upper-body":
            root[:] = source.root
    else:
        out = np.flatnonzero(plan.source_frame >= 0)
        rotations[out], root[out] = source.rotations[plan.source_frame[out]], source.root[plan.source_frame[out]]
    return RigidMotion(source.offsets, rotations, root, edited.skeleton)


def source_features(motion, skeleton: Skeleton, fps: float, given_fps: float | None = None) -> np.ndarray:
    """Features (T, D) in dataset units of a loaded :class:`~stablemofusion.motion.files.Motion` (joints or
    features `.npy`, BVH): features as they are; joints resampled from ``given_fps`` (default: the file's) to
    ``fps`` and converted (canonical frame, the skeleton's bone lengths), one feature frame per joint frame."""
    from ..motion.features import features_from_joints

    if motion.skeleton.name != skeleton.name:
        raise SMFError(f"the motion is on the {motion.skeleton.name} skeleton; this model uses {skeleton.name}")
    if motion.features is not None and given_fps is None:
        return np.asarray(motion.features, dtype=np.float64)
    joints = resample(np.asarray(motion.joints, dtype=np.float64), given_fps or motion.fps, fps)
    if len(joints) < 3:
        raise SMFError(f"the motion is too short to edit ({len(joints)} frames at {fps:g} fps)")
    # features of T frames need T + 1 joint frames (velocities): one more, continuing the last step, so that
    # an edit of the motion has the source's frame count
    return features_from_joints(np.concatenate([joints, 2 * joints[-1:] - joints[-2:-1]]), skeleton)


def body_mask(skeleton: Skeleton, joints: tuple[int, ...], root: bool) -> np.ndarray:
    """(D,) True on the features of ``joints`` (positions, rotations, velocities), on the root features
    when ``root``, and on the foot contacts when the joints include the feet."""
    s = feature_slices(skeleton)
    mask = np.zeros(skeleton.feature_dim, dtype=bool)
    for j in joints:
        if j > 0:  # positions and rotations are stored for joints 1..J-1
            mask[s.positions.start + 3 * (j - 1):s.positions.start + 3 * j] = True
            mask[s.rotations.start + 6 * (j - 1):s.rotations.start + 6 * j] = True
        mask[s.velocities.start + 3 * j:s.velocities.start + 3 * (j + 1)] = True
    if root:
        mask[:4] = True
    if set(skeleton.foot_left + skeleton.foot_right) <= set(joints):
        mask[s.contacts] = True
    return mask


def plan_edit(mode: str, source: np.ndarray, skeleton: Skeleton, *, keep_start: int = 0, keep_end: int = 0,
              frames: int | None = None, path: np.ndarray | None = None) -> EditPlan:
    """The plan of an edit of ``source`` features (Ts, D) in dataset units; lengths in frames."""
    if mode not in EDIT_MODES:
        raise SMFError(f"edit mode must be one of {', '.join(EDIT_MODES)}, got {mode!r}")
    src = np.asarray(source, dtype=np.float64)
    Ts, D = src.shape
    T = Ts if frames is None else int(frames)
    if mode == "trajectory":
        if path is not None:
            path = np.asarray(path, dtype=np.float64)
            if path.ndim != 2 or path.shape[1] != 2 or len(path) < 2 or not np.isfinite(path).all():
                raise SMFError(f"a path is a finite (T, 2) array of root X, Z positions in metres, got shape "
                               f"{path.shape}")
        n = len(path) if path is not None else Ts
        if frames is not None and frames != n:
            raise SMFError(f"a trajectory edit is as long as its path ({n} frames); leave out the length")
        T = n
    if T < 2:
        raise SMFError(f"the output needs at least 2 frames, got {T}")
    known, mask = np.zeros((T, D)), np.zeros((T, D), dtype=bool)
    source_frame = np.full(T, -1)
    plan = dict(mode=mode, frames=T)
    if mode in ("prefix", "inbetween"):
        if not 0 < keep_start < min(T, Ts + 1):
            raise SMFError(f"keep-start must keep 1 to {min(T, Ts + 1) - 1} frames of the source, got {keep_start}")
        known[:keep_start], source_frame[:keep_start] = src[:keep_start], np.arange(keep_start)
    if mode in ("suffix", "inbetween"):
        if not 0 < keep_end < min(T, Ts + 1) or keep_start + keep_end >= T:
            raise SMFError(f"keep-end must keep 1 to {min(T, Ts + 1) - 1 - keep_start} frames of the source, "
                           f"got {keep_end}")
        known[T - keep_end:], source_frame[T - keep_end:] = src[Ts - keep_end:], np.arange(Ts - keep_end, Ts)
    if mode in ("prefix", "suffix", "inbetween"):
        mask[source_frame >= 0] = True
    if mode == "inbetween":
        a = Ts - keep_end
        plan["land"] = (keep_start, T - keep_end, float(headings(src)[a]), root_xz(src)[a])
    if mode == "suffix":
        plan["anchor"] = (T - keep_end, Ts - keep_end)
    if mode in ("upper-body", "lower-body"):
        if T != Ts:
            raise SMFError(f"{mode} edits keep the source's length ({Ts} frames)")
        lower = tuple(skeleton.lower_body)
        upper = tuple(j for j in range(skeleton.num_joints) if j not in lower)
        mask[:] = body_mask(skeleton, lower, root=True) if mode == "upper-body" else body_mask(skeleton, upper, False)
        known[:] = src
        source_frame[:] = np.arange(T)
    if mode == "trajectory":
        if path is None:
            path = root_xz(src)
        plan["path"] = path - path[:1]
    return EditPlan(known=known, mask=mask, kept=mask.all(-1), source_frame=source_frame, **plan)


__all__ = ["EDIT_MODES", "IMPOSE", "EditPlan", "PlanTensors", "check_edit_inputs", "plan_edit", "body_mask",
           "blend_after", "blend_seams", "continue_features", "plan_edit_for", "source_features", "splice_rigid", "x0_constraint"]
