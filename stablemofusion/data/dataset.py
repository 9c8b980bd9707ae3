"""Text-motion training dataset over a HumanML3D-style folder (the official Text2MotionDatasetV2 behaviour)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import torch
from torch.utils.data import Dataset

from ..core.errors import SMFError
from ..motion.features import feature_slices
from ..motion.skeleton import Skeleton
from .augment import slowed_features
from .layout import CaptionLine, MotionLayout

MAX_SOURCE_FRAMES = 200  # official upper bound: clips (and sub-clips) with >= 200 frames are dropped


@dataclass(frozen=True)
class _Entry:
    """One training item: frames [start, end) of clip ``index`` and the captions describing them."""

    index: int
    start: int
    end: int
    captions: tuple[CaptionLine, ...]


def biased_std(std: np.ndarray, skeleton: str | Skeleton, feat_bias: float) -> np.ndarray:
    """(D,) std with the root dims (0:4) and the foot contacts divided by ``feat_bias`` (they weigh more)."""
    s = feature_slices(skeleton)
    out = np.array(std, dtype=np.float64)
    out[0:4] /= feat_bias
    out[s.contacts] /= feat_bias
    return out


SHORT_CROP_MIN_FRACTION = 0.5  # a short crop keeps at least this fraction of the clip's training length


class MotionTextDataset(Dataset):
    """(normalised motion, caption) pairs from ``<root>/<split>.txt``, all held in memory as float32.

    Each clip with frames in [min_frames, 200) and at least one whole-clip caption is one item; each caption
    with a sub-range [start, end) s is its own item over ``motion[int(start*fps):int(end*fps)]`` when that
    length is in bounds (clips with only sub-range captions get no whole-clip item, as officially).
    ``__getitem__`` picks a random caption and a random crop whose length is the clip length floored to a
    multiple of ``unit_length`` (one unit shorter with probability 1/3 when unit_length < 10), at most
    ``max_frames``. With ``seed`` set, item ``i`` of epoch ``e`` is a function of (seed, e, i), so results
    are reproducible and independent of DataLoader workers: call :meth:`set_epoch` each epoch. With
    ``seed=None`` every call draws fresh randomness. :meth:`item` with ``warp`` > 1 gives the item's motion
    played that many times slower (data/augment.py ``slowed_features``; data/batches.py draws it per batch).
    """

    def __init__(self, root: str | os.PathLike | MotionLayout, split: str = "train", *,
                 skeleton: str | Skeleton | None = None, min_frames: int | None = None, max_frames: int | None = None,
                 unit_length: int = 4, feat_bias: float = 5.0, seed: int | None = None,
                 ids: Sequence[str] | None = None, short_crops: float = 0.0):
        self.layout = root if isinstance(root, MotionLayout) else MotionLayout(root, skeleton)
        self.layout.validate()
        sk = self.skeleton = self.layout.skeleton
        self.split = split
        self.min_frames = sk.min_frames if min_frames is None else int(min_frames)
        self.max_frames = sk.max_frames if max_frames is None else int(max_frames)
        self.unit_length, self.feat_bias = int(unit_length), float(feat_bias)
        if self.unit_length < 1 or self.max_frames < self.unit_length or self.min_frames < self.unit_length:
            raise SMFError(f"need 1 <= unit_length ({unit_length}) <= min_frames ({self.min_frames}) and "
                           f"<= max_frames ({max_frames})")
        if not feat_bias > 0:
            raise SMFError(f"feat_bias must be positive, got {feat_bias}")
        if not 0.0 <= short_crops <= 1.0:
            raise SMFError(f"short_crops is a probability in [0, 1], got {short_crops}")
        self.short_crops = float(short_crops)
        self.seed = seed
        self.epoch, self.copy = 0, 0
        self.mean = np.asarray(self.layout.mean, dtype=np.float32)
        self.std = biased_std(self.layout.std, sk, self.feat_bias).astype(np.float32)

        id_list = list(self.layout.ids(split) if ids is None else ids)
        self.ids: list[str] = []
        self.motions: list[np.ndarray] = []  # normalised (T, D) float32
        self.entries: list[_Entry] = []
        for mid in id_list:
            self._add_clip(mid)
        if not self.entries:
            where = f"split '{split}' ({self.layout.split_path(split)})" if ids is None else "the given ids"
            raise SMFError(f"{where}: no motions left after filtering {len(id_list)} id(s) (clip length must be "
                           f"in [{self.min_frames}, {MAX_SOURCE_FRAMES}) frames, with usable captions)")

    def _in_bounds(self, n: int) -> bool:
        return self.min_frames <= n < MAX_SOURCE_FRAMES

    def _add_clip(self, mid: str) -> None:
        feats = self.layout.load_features(mid)
        T = len(feats)
        if not self._in_bounds(T):
            return
        texts = self.layout.load_texts(mid)
        fps = self.skeleton.fps
        index = len(self.motions)
        subs = [_Entry(index, a, min(b, T), (c,)) for c in texts if not c.whole_clip
                for a, b in [(max(int(c.start * fps), 0), int(c.end * fps))] if self._in_bounds(min(b, T) - a)]
        whole = tuple(c for c in texts if c.whole_clip)
        if not whole and not subs:
            return
        self.ids.append(mid)
        self.motions.append(self.normalize(np.asarray(feats, dtype=np.float32)))
        if whole:
            self.entries.append(_Entry(index, 0, T, whole))
        self.entries.extend(subs)

    def __len__(self) -> int:
        return len(self.entries)

    def set_epoch(self, epoch: int, copy: int = 0) -> None:
        """Select the random stream of an epoch (only matters with a seed); ``copy`` > 0 selects another
        stream for an item drawn more than once in the epoch (label balancing), so each copy differs."""
        self.epoch, self.copy = int(epoch), int(copy)

    def _rng(self, i: int) -> np.random.Generator:
        if self.seed is None:
            return np.random.default_rng()
        return np.random.default_rng([self.seed, self.epoch, i] + ([self.copy] if self.copy else []))

    def crop_length(self, n: int, rng: np.random.Generator) -> int:
        """Training length for a clip of ``n`` frames: a multiple of unit_length in [unit_length, max_frames].
        With ``short_crops`` p: with probability p a length drawn uniformly between SHORT_CROP_MIN_FRACTION of
        that (at least min_frames) and all of it, so that an action whose clips are all long (waves: 6-8 s) is
        also seen at shorter lengths (a motion of 4 s is not only what short clips do: raising a hand)."""
        u = self.unit_length
        units = n // u
        if u < 10 and units > 1 and rng.random() < 1 / 3:  # official coin: 'single', 'single', 'double'
            units -= 1
        units = min(units, self.max_frames // u)
        if self.short_crops > 0 and rng.random() < self.short_crops:
            low = max(-(-self.min_frames // u), int(np.ceil(SHORT_CROP_MIN_FRACTION * units)))
            if low < units:
                units = int(rng.integers(low, units + 1))
        return units * u

    def __getitem__(self, i: int) -> dict[str, Any]:
        return self.item(i)

    def item(self, i: int, warp: float = 1.0) -> dict[str, Any]:
        """dict: motion (max_frames, D) float32 normalised and zero-padded, mask (max_frames,) bool,
        length int, caption str, tokens list[str], id str, frames (start, end) of the source file the crop
        covers, warp float. With ``warp`` > 1 the crop is taken from the motion played ``warp`` times slower
        (the same random draws otherwise: same caption, crop length from the slower motion's length)."""
        if not warp >= 1.0:
            raise SMFError(f"warp is a slowing factor >= 1, got {warp}")
        if not -len(self) <= i < len(self):
            raise IndexError(f"index {i} out of range for {len(self)} items")
        e = self.entries[i]
        rng = self._rng(i % len(self))
        cap = e.captions[int(rng.integers(len(e.captions)))]
        source, warp = self.motions[e.index][e.start:e.end], float(warp)
        if warp != 1.0:
            source = self.normalize(slowed_features(self.denormalize(source), warp, self.skeleton)).astype(np.float32)
        n = self.crop_length(len(source), rng)
        a = int(rng.integers(0, len(source) - n + 1))
        motion = torch.zeros(self.max_frames, self.mean.shape[0], dtype=torch.float32)
        motion[:n] = torch.from_numpy(source[a:a + n])
        mask = torch.zeros(self.max_frames, dtype=torch.bool)
        mask[:n] = True
        # source frames the crop covers: the slowed frame k sits at source time k / warp (k itself when warp is 1)
        frames = (e.start + int(a / warp), min(e.end, e.start + int(np.ceil((a + n - 1) / warp)) + 1))
        return {"motion": motion, "mask": mask, "length": n, "caption": cap.caption, "tokens": list(cap.tokens),
                "id": self.ids[e.index], "frames": frames, "warp": warp}

    def _stats_like(self, x):
        if isinstance(x, torch.Tensor):
            return (torch.as_tensor(self.mean, dtype=x.dtype, device=x.device),
                    torch.as_tensor(self.std, dtype=x.dtype, device=x.device))
        return self.mean, self.std

    def normalize(self, x):
        """(..., D) raw features -> (x - mean) / biased std; numpy or torch."""
        mean, std = self._stats_like(x)
        return (x - mean) / std

    def denormalize(self, x):
        """(..., D) normalised features -> raw features; numpy or torch."""
        mean, std = self._stats_like(x)
        return x * std + mean


def collate(batch: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """DataLoader collate: motion (B, T, D), mask (B, T), length (B,) long, frames (B, 2) long, warp (B,); lists of
    caption / tokens / id."""
    if not batch:
        raise SMFError("collate: empty batch")
    return {
        "motion": torch.stack([b["motion"] for b in batch]),
        "mask": torch.stack([b["mask"] for b in batch]),
        "length": torch.tensor([b["length"] for b in batch], dtype=torch.long),
        "frames": torch.tensor([b["frames"] for b in batch], dtype=torch.long),
        "warp": torch.tensor([b["warp"] for b in batch], dtype=torch.float32),
        "caption": [b["caption"] for b in batch],
        "tokens": [b["tokens"] for b in batch],
        "id": [b["id"] for b in batch],
    }
