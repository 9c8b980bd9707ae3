"""What every runtime does after sampling, written once (numpy, no torch): a requested length in frames, and the
final stage of raw features (the rigid fit, footskate cleanup in 'post' mode, the body written back as
features). The torch path (:class:`~stablemofusion.backends.torch_backend.TorchBackend`) and the portable runtime
(:mod:`stablemofusion.backends`) both call these."""

from __future__ import annotations

import warnings

import numpy as np

from .errors import SMFError
from .limits import DEFAULT_SECONDS, LENGTH_MULTIPLE, check_footskate, check_prompt, check_seconds, check_seed
from ..motion.rigid import RigidFitConfig, RigidMotion, rigid_from_features_many, rigid_to_features
from ..motion.skeleton import Skeleton


class LengthClampedWarning(UserWarning):
    """A requested length was outside what the model was trained on and was clamped."""


class OutOfDomainWarning(UserWarning):
    """A prompt is far from every action the model was trained on (it is generated anyway)."""


class WeakActionWarning(UserWarning):
    """A prompt's closest known action is one the model draws badly (few clips taught it; it is generated anyway)."""


class TaughtCaptionWarning(UserWarning):
    """A prompt clearly closest to a move an adapter taught is answered with the nearest caption of that move's clips
    (what the adapter draws surely)."""


class NotEnglishWarning(UserWarning):
    """A prompt does not look like English (another script, another language's words, no words): the model knows
    English prompts only (it is generated anyway)."""


class EngineWarning(UserWarning):
    """A requested engine cannot run a task (its steps are changed by hooks) and another one runs it."""


def frames_for(seconds: float | None, frames: int | None, fps: float, min_frames: int) -> int:
    """A requested duration in frames, a multiple of ``LENGTH_MULTIPLE``, at least the model's shortest
    (warning if changed); lengths past a model's window are kept (they are generated window by window)."""
    if frames is None:
        frames = int(round(check_seconds(DEFAULT_SECONDS if seconds is None else seconds) * fps))
    check_seconds(frames / fps, "the length")  # more than 0 frames, at most MAX_SECONDS
    n = max(frames, min_frames) // LENGTH_MULTIPLE * LENGTH_MULTIPLE
    if n != frames:
        warnings.warn(clamp_message(frames, n, fps), LengthClampedWarning, stacklevel=4)
    return n


def clamp_message(asked: int, made: int, fps: float) -> str:
    """The warning of a length of ``asked`` frames made as ``made`` (:func:`frames_for`)."""
    return (f"length {asked} frames ({asked / fps:.2f} s) clamped to {made} frames ({made / fps:.2f} s), the range "
            "this model was trained on")


def asked_frames(seconds: float | None, frames: int | None, fps: float) -> int | None:
    """The frames a request asked for (None: none asked, the model's estimate or the default decides)."""
    return frames if frames is not None else None if seconds is None else int(round(seconds * fps))


def check_batch_request(prompts, seconds, frames, seed) -> tuple[list[str], list, list, bool]:
    """The inputs of a text-to-motion call, checked as every runtime checks them: ``prompts`` (one text or a
    list), ``seconds``/``frames`` one value or one per prompt, ``seed`` one or one per prompt. Returns the prompts,
    the seconds and frames per prompt, and whether the seeds are per prompt."""
    prompts = [prompts] if isinstance(prompts, str) else list(prompts)
    if not prompts:
        raise SMFError("every prompt must be a non-empty text")
    for p in prompts:
        check_prompt(p, "every prompt")
    n = len(prompts)
    secs = list(seconds) if isinstance(seconds, (list, tuple)) else [seconds] * n
    frs = list(frames) if isinstance(frames, (list, tuple)) else [frames] * n
    if len(secs) != n or len(frs) != n:
        raise SMFError("give one length for all prompts or one per prompt")
    for s in secs:
        check_seconds(s)
    per_item = isinstance(seed, (list, tuple))
    if per_item and len(seed) != n:
        raise SMFError(f"give one seed for all prompts or one per prompt: {len(seed)} seeds for {n} prompts")
    for s in seed if per_item else [seed]:
        check_seed(s)
    return prompts, secs, frs, per_item


def finish_many(features: list[np.ndarray], skeleton: Skeleton, fps: float, rigid: RigidFitConfig | None,
                footskate: str = "off", footskate_options=None, like=None) -> list[tuple[np.ndarray, RigidMotion | None]]:
    """The final stage of several motions' raw features (T_i, D): their rigid fits done together (one vectorised
    fit of all their frames; each motion's result is the one it gets alone), the footskate cleanup in 'post'
    mode (on the rigid body), and each body written back as features that decode to it exactly. Returns
    (features (T, D) float64, rigid motion) per motion; with ``rigid`` None the raw features and None. ``like``: an
    array whose library and device run the fit and the cleanup (a float64 tensor on a GPU: the torch backend's
    device; None: numpy), the same functions either way."""
    check_footskate(footskate)
    fs = [np.asarray(f, dtype=np.float64) for f in features]
    if rigid is None:
        return [(f, None) for f in fs]
    if footskate == "post":
        from ..footskate import FootskateOptions
        from ..footskate.cleanup import cleanup_features_many

        options = footskate_options or FootskateOptions()
        return cleanup_features_many(fs, options.config, vgrf_model=options.vgrf_model, fps=fps, rigid=rigid,
                                     like=like)
    out = []
    for motion, f in zip(rigid_from_features_many(fs, skeleton, rigid, like), fs):
        moved, written = rigid_to_features(motion, f, rigid)
        out.append((written, moved))
    return out


__all__ = ["EngineWarning", "LengthClampedWarning", "NotEnglishWarning", "OutOfDomainWarning", "WeakActionWarning", "asked_frames", "check_batch_request",
           "clamp_message", "finish_many", "frames_for"]
