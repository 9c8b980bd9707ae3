"""Live streams: one endless motion, made a short window at a time, that follows a prompt which may change
between windows (the server's WebSocket /v1/stream, the viewer's live mode). Written once in numpy for both
runtimes: a window is sampled by the stream's :class:`WindowSampler` (the torch pipeline's or the portable
runtime's), everything else happens here.

Every window after the first keeps the last second of the motion so far as its known start (imposed on every
x0 prediction, then its seam blended, as timelines do: :mod:`stablemofusion.core.timeline_plan`) and adds ``chunk``
frames from the prompt current when it starts; it generates ``TAIL`` frames more and drops them (a motion's last
frames are its least settled). Features are relative to the body, so the new frames continue the root path and
heading; the stream keeps the world heading and position of its kept frames and places each window's joints
there: the character continues from where it stands, with no pop.

A stream can be cut back (:meth:`MotionStream.cut`) to any of its last ``rewind`` frames: the frames from there
on are forgotten and the next window continues from the frames before the cut, with the prompt current then (the
server makes windows ahead of play time and cuts back the ones it has not sent when a new prompt arrives).

Joints come straight from the model's features (root-relative positions): the rigid final stage fits a whole
motion at once, which a stream never has. Windows of several streams of the same shape and settings are denoised
in one batched call (:func:`advance`), each with its own prompt and seed.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Hashable, Protocol

import numpy as np

from .edit_plan import blend_seams
from .errors import SMFError
from ..footskate.cleanup import CLEANUP_CONTACTS
from ..footskate.contacts import kinematic_contacts
from .limits import check_prompt
from ..motion.features import joints_from_features, root_from_features
from ..motion.root import headings
from ..motion.rotation import qinv, qrot, yaw_quat
from ..motion.skeleton import get_skeleton
from .timeline_plan import TAIL

STREAM_KEEP = 20  # frames of the motion so far each window keeps as its start (1 s at 20 fps)
STREAM_CHUNK = 12  # frames each window adds (0.6 s at 20 fps): with the kept second and the dropped tail a
# window is 40 frames, the shipped model's shortest motion, so a window costs no more than a shorter chunk's
STREAM_REWIND = 60  # frames a stream can be cut back (3 s at 20 fps): it remembers its last keep + rewind frames


class WindowSampler(Protocol):
    """What a stream needs of a pipeline: its skeleton, shortest motion and feature size, a settings object with
    another guidance scale, and a batch of windows sampled with a known start."""

    skeleton: object
    min_frames: int
    dim: int

    def with_guidance(self, settings: Hashable, guidance: float) -> Hashable:
        """``settings`` with guidance scale ``guidance`` (checked)."""

    def sample_window(self, prompts: list[str], frames: int, settings: Hashable, seeds: list[int],
                      known: np.ndarray | None) -> np.ndarray:
        """Raw features (n, frames, D) float64 in dataset units, item i from ``prompts[i]`` and ``seeds[i]``;
        ``known`` (n, keep, D) dataset units imposed on the first ``keep`` frames of every x0 prediction."""


@dataclass(frozen=True)
class Chunk:
    """Frames ``start`` .. ``start + len(joints) - 1`` of a stream, made from its prompt number ``prompt_index``
    (counted from 0): ``joints`` (n, J, 3) metres in the stream's world frame, ``features`` (n, D) dataset
    units (body-relative, as the model makes them), ``contacts`` (n, 4) bool the feet the footskate cleanup's
    detector counts as planted (left ankle, left toe, right ankle, right toe; found on the whole window)."""

    start: int
    prompt_index: int
    prompt: str
    joints: np.ndarray
    features: np.ndarray
    contacts: np.ndarray

    @property
    def frames(self) -> int:
        return len(self.joints)


def check_window(keep: int, chunk: int, rewind: int, max_frames: int) -> None:
    """SMFError unless a window keeps 1+ frames, adds 1+ frames and fits the model with its tail."""
    if not 0 < keep or not 0 < chunk or keep + chunk + TAIL > max_frames:
        raise SMFError(f"a stream window keeps 1+ frames and adds 1+ frames, at most {max_frames - TAIL} in "
                       f"all; got keep {keep}, chunk {chunk}")
    if rewind < 0:
        raise SMFError(f"a stream's rewind is 0 or more frames, not {rewind}")


class MotionStream:
    """An endless motion: ``next(stream)`` makes the next :class:`Chunk`; :meth:`set_prompt` changes the prompt
    from the next window on (``stream.send(prompt)`` does both, as a generator would); :meth:`cut` rolls the
    stream back to an earlier frame. Window j (counted along the frames kept) uses ``seed + j``. Build with a
    pipeline's ``stream`` method."""

    def __init__(self, sampler: WindowSampler, prompt: str, seed: int, settings: Hashable, chunk: int = STREAM_CHUNK,
                 keep: int = STREAM_KEEP, rewind: int = STREAM_REWIND):
        self.sampler, self.seed, self.settings = sampler, seed, settings
        self.chunk, self.keep, self.rewind = chunk, keep, rewind
        self.prompt, self.prompt_index = check_prompt(prompt, "the prompt"), 0
        self.frames = 0  # frames made so far (less those cut)
        self.windows = 0  # windows made so far (less those cut)
        self._seeded_at = 0  # the window the seed applies from
        self._starts: deque[int] = deque()  # the first frames of the windows a cut may still drop
        # the last keep + rewind frames (up to frame `frames`): features, world heading (yaw half-angles), root XZ
        self._features = np.zeros((0, sampler.dim))
        self._angle = np.zeros(0)
        self._xz = np.zeros((0, 2))

    @property
    def earliest_cut(self) -> int:
        """The earliest frame :meth:`cut` accepts: the stream remembers the ``keep`` frames before it."""
        first = self.frames - len(self._features)  # the first frame remembered
        return first + self.keep if first else 0

    def cut(self, frame: int) -> int:
        """Roll the stream back to ``frame`` (``earliest_cut`` .. ``frames``): frames ``frame`` on are forgotten,
        and the next chunk starts at ``frame``, continuing from the frames before it (their features, world
        heading and position, as when they were made) with the prompt, seed and guidance current then; the
        window count goes back to the windows that made the frames kept. Returns the frames dropped."""
        frame = int(frame)
        if not self.earliest_cut <= frame <= self.frames:
            raise SMFError(f"a stream can be cut back to frames {self.earliest_cut} .. {self.frames}, not {frame}")
        drop = self.frames - frame
        n = len(self._features) - drop
        self._features, self._angle, self._xz = self._features[:n], self._angle[:n], self._xz[:n]
        self.frames = frame
        while self._starts and self._starts[-1] >= frame:
            self._starts.pop()
            self.windows -= 1
        self._seeded_at = min(self._seeded_at, self.windows)
        return drop

    def set_prompt(self, prompt: str, *, seed: int | None = None, guidance_scale: float | None = None) -> int:
        """Use ``prompt`` from the next window on (and ``seed`` for that window, ``seed + 1`` for the one after,
        ...; ``guidance_scale``, where given); returns its prompt index."""
        self.prompt = check_prompt(prompt, "the prompt")
        if guidance_scale is not None:
            self.settings = self.sampler.with_guidance(self.settings, guidance_scale)
        if seed is not None:
            self.seed, self._seeded_at = int(seed), self.windows
        self.prompt_index += 1
        return self.prompt_index

    @property
    def window_seed(self) -> int:
        """The seed of the next window."""
        return self.seed + self.windows - self._seeded_at

    def __iter__(self):
        return self

    def __next__(self) -> Chunk:
        return advance([self])[0]

    def send(self, prompt: str | None) -> Chunk:
        """Generator protocol: a new prompt (or None: the same), then the next chunk."""
        if prompt is not None:
            self.set_prompt(prompt)
        return next(self)

    def window_shape(self) -> tuple[int, int]:
        """(frames kept, frames generated) of this stream's next window."""
        keep = min(self.keep, self.frames)
        return keep, max(keep + self.chunk + TAIL, self.sampler.min_frames)


def advance(streams: list[MotionStream]) -> list[Chunk]:
    """The next chunk of every stream: windows of the same sampler, shape and settings in one sampling call."""
    groups: dict[tuple, list[int]] = {}
    for i, s in enumerate(streams):
        groups.setdefault((s.sampler, s.window_shape(), s.settings), []).append(i)
    out: list[Chunk | None] = [None] * len(streams)
    for (_, (keep, frames), settings), idx in groups.items():
        for i, chunk in zip(idx, _window([streams[i] for i in idx], keep, frames, settings)):
            out[i] = chunk
    return out


def _window(streams: list[MotionStream], keep: int, frames: int, settings: Hashable) -> list[Chunk]:
    """One window of each stream (all keep ``keep`` frames and generate ``frames``)."""
    # 1. the known start of every stream (its kept frames), imposed on x0 at every step
    known = np.stack([s._features[-keep:] for s in streams]) if keep else None
    # 2. denoise, each stream with its prompt and its window's seed
    raw = streams[0].sampler.sample_window([s.prompt for s in streams], frames, settings,
                                           [s.window_seed for s in streams], known)
    # 3. post-process: exact on the kept part, the seam blended; placed in each stream's world
    kept = np.arange(frames) < keep
    chunks = []
    for i, s in enumerate(streams):
        f = np.array(raw[i], dtype=np.float64)
        if keep:
            f[:keep] = known[i]
            f = blend_seams(f, kept)
        chunks.append(_emit(s, f[:keep + s.chunk], keep))
    return chunks


def _emit(s: MotionStream, f: np.ndarray, keep: int) -> Chunk:
    """Place window features ``f`` (keep + chunk frames, dataset units) in the stream's world, append the new
    frames to the stream and return them as a chunk."""
    a0 = s._angle[-keep] if keep else 0.0
    p0 = s._xz[-keep] if keep else np.zeros(2)
    turn = qinv(yaw_quat(np.asarray(2.0 * a0)))  # local (window frame 0 at the origin, facing +Z) -> world
    local = joints_from_features(f, s.sampler.skeleton)  # (n, J, 3)
    world = qrot(np.broadcast_to(turn, local.shape[:-1] + (4,)), local)
    world[..., 0] += p0[0]
    world[..., 2] += p0[1]
    root = root_from_features(f)[1]
    xz = qrot(np.broadcast_to(turn, root.shape[:-1] + (4,)), root)[:, [0, 2]] + p0
    angle = a0 + headings(f)
    planted = kinematic_contacts(local, get_skeleton(s.sampler.skeleton).fps, config=CLEANUP_CONTACTS)  # whole window
    chunk = Chunk(s.frames, s.prompt_index, s.prompt, world[keep:].astype(np.float32),
                  f[keep:].astype(np.float32), planted[keep:])
    remember = s.keep + s.rewind
    s._features = np.concatenate([s._features, f[keep:]])[-remember:]
    s._angle = np.concatenate([s._angle, angle[keep:]])[-remember:]
    s._xz = np.concatenate([s._xz, xz[keep:]])[-remember:]
    s._starts.append(s.frames)
    s.frames += chunk.frames
    s.windows += 1
    while s._starts and s._starts[0] < s.earliest_cut:  # never dropped by a cut: forgotten
        s._starts.popleft()
    return chunk


__all__ = ["STREAM_CHUNK", "STREAM_KEEP", "STREAM_REWIND", "Chunk", "MotionStream", "WindowSampler", "advance",
           "check_window"]
