"""Training batches that are a pure function of (seed, step): any run, resumed or not, sees the same data.

Each epoch is a seeded permutation of the items (optionally sorted by length within runs of
``bucket * batch_size`` items, so a batch holds similar lengths and pads less; optionally with item ``i``
repeated ``repeats[i]`` times, so rare labels are seen more often); step ``s`` takes the ``s``-th slice of
``batch_size`` items of the endless sequence of epochs. With time warp p, a fraction p of the steps plays
its whole batch slower by one factor (so the batch's lengths stay alike and padding does not grow).
"""

from __future__ import annotations

import functools

import numpy as np

from .dataset import MotionTextDataset, collate

TIME_WARP_MAX = 2.0  # a time-warped batch is slowed by a factor drawn uniformly in [1, TIME_WARP_MAX]
TIME_WARP_CONTENTS = ("all", "tempo-free")  # which items a slowed batch slows (tempo-free: the lexicon's list)
_WARP_STREAM = 7  # seeds the warp draws apart from the epoch permutations ([seed, epoch])


@functools.lru_cache(maxsize=4)
def _epoch_order(seed: int, epoch: int, n: int, chunk: int, lengths: tuple[int, ...] | None,
                 repeats: tuple[int, ...] | None = None) -> np.ndarray:
    """(2, N) item order of one epoch and each entry's copy number: a seeded permutation of the ``n`` items
    (item ``i`` present ``repeats[i]`` times, as copies 0, 1, ..., when given); with ``lengths``, each run of
    ``chunk`` entries is sorted by length, so batches hold similar lengths. Cached: every step reads it."""
    if repeats is None:
        pool, copies = np.arange(n), np.zeros(n, dtype=np.int64)
    else:
        pool = np.repeat(np.arange(n), repeats)
        copies = np.arange(len(pool)) - np.repeat(np.cumsum(repeats) - np.asarray(repeats), repeats)
    perm = np.random.default_rng([seed, epoch]).permutation(len(pool))
    order, copies = pool[perm], copies[perm]
    if lengths is not None:
        lens = np.asarray(lengths)
        perm = np.concatenate([a + np.argsort(lens[order[a:a + chunk]], kind="stable")
                               for a in range(0, len(order), chunk)])
        order, copies = order[perm], copies[perm]
    return np.stack([order, copies])


def batch_indices(step: int, batch_size: int, n: int, seed: int, *, lengths: tuple[int, ...] | None = None,
                  bucket: int = 0, repeats: tuple[int, ...] | None = None) -> list[tuple[int, int]]:
    """(epoch, item) pairs of step ``step``: consecutive slices of a per-epoch order of ``n`` items.

    With ``bucket > 0`` and the items' ``lengths``, the order groups similar lengths (see ``_epoch_order``);
    with ``repeats`` (n positive ints) an epoch holds item ``i`` that many times."""
    return [(e, i) for e, i, _ in _draws(step, batch_size, n, seed, lengths, bucket, repeats)]


def _draws(step: int, batch_size: int, n: int, seed: int, lengths, bucket: int, repeats) -> list[tuple[int, int, int]]:
    """(epoch, item, copy) triples of step ``step`` (see :func:`batch_indices`)."""
    lens = tuple(lengths) if bucket > 0 and lengths is not None else None
    chunk = batch_size * max(bucket, 1)
    size = n if repeats is None else int(sum(repeats))
    out = []
    for g in range(step * batch_size, (step + 1) * batch_size):
        epoch, k = divmod(g, size)
        order = _epoch_order(seed, epoch, n, chunk, lens, repeats)
        out.append((epoch, int(order[0, k]), int(order[1, k])))
    return out


def label_repeats(groups: list, power: float, cap: int) -> tuple[int, ...]:
    """Repeats per item that even out label frequencies: an item whose group (any hashable label, e.g.
    (dataset, content)) has ``n`` items, in a corpus whose largest group has ``n_max``, is repeated
    ``round((n_max / n) ** power)`` times, clipped to [1, cap]. ``power`` 0 gives all ones, 1 full balance."""
    from collections import Counter

    counts = Counter(groups)
    n_max = max(counts.values())
    return tuple(int(min(max(round((n_max / counts[g]) ** power), 1), cap)) for g in groups)


def batch_warp(step: int, seed: int, time_warp: float) -> float:
    """Slowing factor of step ``step``'s batch: with probability ``time_warp`` one drawn uniformly in
    [1, TIME_WARP_MAX], else 1.0; a function of (seed, step)."""
    if time_warp <= 0:
        return 1.0
    rng = np.random.default_rng([seed, _WARP_STREAM, step])
    return float(rng.uniform(1.0, TIME_WARP_MAX)) if rng.random() < time_warp else 1.0


def get_batch(ds: MotionTextDataset, step: int, batch_size: int, seed: int, bucket: int = 0,
              repeats: tuple[int, ...] | None = None, time_warp: float = 0.0,
              warpable: tuple[bool, ...] | None = None) -> dict:
    """Batch of step ``step``, trimmed to its longest item (padding beyond it is never needed); its items
    played slower by :func:`batch_warp` (``time_warp`` the probability of a slowed batch), only those whose
    entry is True in ``warpable`` when given (one per dataset item)."""
    lengths = tuple(e.end - e.start for e in ds.entries) if bucket > 0 else None
    warp = batch_warp(step, seed, time_warp)
    items = []
    for epoch, i, copy in _draws(step, batch_size, len(ds), seed, lengths, bucket, repeats):
        ds.set_epoch(epoch, copy)
        items.append(ds.item(i, warp if warpable is None or warpable[i] else 1.0))
    batch = collate(items)
    T = int(batch["length"].max())
    batch["motion"], batch["mask"] = batch["motion"][:, :T], batch["mask"][:, :T]
    return batch
