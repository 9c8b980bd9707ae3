"""Training batches that are a pure function of (seed, step): any run, resumed or not, sees the same data.

Each epoch is a seeded permutation of the items (optionally sorted by length within runs of
``bucket * batch_size`` items, so a batch holds similar lengths and pads less); step ``s`` takes the
``s``-th slice of ``batch_size`` items of the endless sequence of epochs.
"""

from __future__ import annotations

import functools

import numpy as np

from .dataset import MotionTextDataset, collate


@functools.lru_cache(maxsize=4)
def _epoch_order(seed: int, epoch: int, n: int, chunk: int, lengths: tuple[int, ...] | None) -> np.ndarray:
    """Item order of one epoch: a seeded permutation; with ``lengths``, each run of ``chunk`` items is
    sorted by length, so batches hold similar lengths. Cached: every step of an epoch reads it."""
    order = np.random.default_rng([seed, epoch]).permutation(n)
    if lengths is None:
        return order
    lens = np.asarray(lengths)
    return np.concatenate([part[np.argsort(lens[part], kind="stable")]
                           for part in (order[a:a + chunk] for a in range(0, n, chunk))])


def batch_indices(step: int, batch_size: int, n: int, seed: int, *, lengths: tuple[int, ...] | None = None,
                  bucket: int = 0) -> list[tuple[int, int]]:
    """(epoch, item) pairs of step ``step``: consecutive slices of a per-epoch order of ``n`` items.

    With ``bucket > 0`` and the items' ``lengths``, the order groups similar lengths (see ``_epoch_order``)."""
    lens = tuple(lengths) if bucket > 0 and lengths is not None else None
    chunk = batch_size * max(bucket, 1)
    out = []
    for g in range(step * batch_size, (step + 1) * batch_size):
        epoch, k = divmod(g, n)
        out.append((epoch, int(_epoch_order(seed, epoch, n, chunk, lens)[k])))
    return out


def get_batch(ds: MotionTextDataset, step: int, batch_size: int, seed: int, bucket: int = 0) -> dict:
    """Batch of step ``step``, trimmed to its longest item (padding beyond it is never needed)."""
    lengths = tuple(e.end - e.start for e in ds.entries) if bucket > 0 else None
    items = []
    for epoch, i in batch_indices(step, batch_size, len(ds), seed, lengths=lengths, bucket=bucket):
        ds.set_epoch(epoch)
        items.append(ds[i])
    batch = collate(items)
    T = int(batch["length"].max())
    batch["motion"], batch["mask"] = batch["motion"][:, :T], batch["mask"][:, :T]
    return batch
