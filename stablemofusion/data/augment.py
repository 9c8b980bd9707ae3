"""Training augmentation. Captions: word dropout, synonym swap, typos and case/punctuation noise; motions:
slowed copies (time warp).

People type fragments, misspell, drop punctuation and pick their own words; template captions do none
of that. ``augment_caption`` perturbs a caption the way a user's prompt differs from it, seeded by the
caller's generator so a training step stays reproducible. Synonym groups are data: single words that
the corpus lexicon lists for one label (``synonym_groups``).
"""

from __future__ import annotations

import random
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from ..motion.features import features_from_joints, joints_from_features
from ..motion.resample import resample
from ..motion.skeleton import Skeleton

_WORD = re.compile(r"[A-Za-z']+")
_KEEP = frozenset("both not back backward backwards forward".split())  # meaning-bearing small words
_SIDE = re.compile(r"left|right|clockwise", re.IGNORECASE)


def _protected(word: str) -> bool:
    """Words augmentation never drops or misspells: sides (left, rightward...) and a few small meaning words."""
    return word.lower().strip(".,") in _KEEP or _SIDE.search(word) is not None


@dataclass(frozen=True)
class AugmentConfig:
    """Per-caption probabilities of each perturbation (applied independently, in this order)."""

    synonym: float = 0.5  # swap one word for another of its synonym group
    dropout: float = 0.3  # drop words, each with probability ``word_drop``
    word_drop: float = 0.15
    typo: float = 0.2  # one typo (swap, drop or double a letter) in a word of 4+ letters
    casing: float = 0.5  # lower-case and strip the final period


def synonym_groups(groups: Iterable[Sequence[str]]) -> dict[str, tuple[str, ...]]:
    """Word -> the other single words of its group (groups of one word and multi-word entries are skipped)."""
    table: dict[str, set[str]] = {}
    for group in groups:
        words = {w.lower() for w in group if _WORD.fullmatch(w)}
        for w in words:
            table.setdefault(w, set()).update(words - {w})
    return {w: tuple(sorted(others)) for w, others in table.items() if others}


def _typo(word: str, rng: random.Random) -> str:
    i = rng.randrange(1, len(word) - 1)
    kind = rng.randrange(3)
    if kind == 0:
        return word[:i] + word[i + 1] + word[i] + word[i + 2:]
    if kind == 1:
        return word[:i] + word[i + 1:]
    return word[:i] + word[i] + word[i:]


def augment_caption(caption: str, rng: random.Random, synonyms: dict[str, tuple[str, ...]] | None = None,
                    config: AugmentConfig = AugmentConfig()) -> str:
    """A perturbed copy of ``caption`` (never empty; left/right, both, back... are never dropped or misspelt)."""
    words = caption.split()
    if synonyms and rng.random() < config.synonym:
        spots = [i for i, w in enumerate(words) if w.lower().strip(".,") in synonyms]
        if spots:
            i = rng.choice(spots)
            bare = words[i].strip(".,")
            words[i] = words[i].replace(bare, rng.choice(synonyms[bare.lower()]))
    if rng.random() < config.dropout and len(words) > 3:
        kept = [w for w in words if _protected(w) or rng.random() >= config.word_drop]
        words = kept if len(kept) >= 2 else words
    if rng.random() < config.typo:
        spots = [i for i, w in enumerate(words) if len(w) >= 4 and w.isalpha() and not _protected(w)]
        if spots:
            i = rng.choice(spots)
            words[i] = _typo(words[i], rng)
    text = " ".join(words)
    if rng.random() < config.casing:
        text = text.lower().rstrip(".")
    return text


def slowed_features(features: np.ndarray, factor: float, skeleton: str | Skeleton = "humanml3d") -> np.ndarray:
    """Features (T, D) -> features (floor((T-1) * factor), D) of the same motion played ``factor`` >= 1 times
    slower: decoded to joints (the exact inverse), resampled linearly in time, encoded again (uniform bones,
    HumanML3D's first-frame convention, foot contacts from the slower feet). Poses and path are kept; every
    velocity shrinks by ``factor``. A raise that lasts 2 s becomes one of up to 2 s x factor."""
    if not factor >= 1.0:
        raise ValueError(f"slowing factor must be >= 1, got {factor}")
    joints = joints_from_features(np.asarray(features, dtype=np.float64), skeleton)
    return features_from_joints(resample(joints, 1.0, float(factor)), skeleton)


__all__ = ["AugmentConfig", "augment_caption", "slowed_features", "synonym_groups"]
