"""Training batches: a pure function of (seed, step), bucketed by length on request, trimmed to their longest item."""

import numpy as np
import pytest

from stablemofusion.data.batches import batch_indices, get_batch
from stablemofusion.data.dataset import MotionTextDataset


@pytest.fixture(scope="module")
def corpus(bandai_mini_corpus):
    return bandai_mini_corpus


def test_batches_are_a_function_of_the_step():
    assert batch_indices(3, 4, 10, 0) == batch_indices(3, 4, 10, 0)
    seen = [i for s in range(5) for _, i in batch_indices(s, 2, 10, 0)]
    assert sorted(seen) == list(range(10))  # one epoch visits every item once


def test_bucketed_batches_group_lengths_and_still_cover_the_epoch():
    lengths = tuple(int(x) for x in np.random.default_rng(0).integers(40, 196, 64))
    plain = [[lengths[i] for _, i in batch_indices(s, 8, 64, 0)] for s in range(8)]
    bucketed = [[lengths[i] for _, i in batch_indices(s, 8, 64, 0, lengths=lengths, bucket=8)] for s in range(8)]
    assert sorted(sum(bucketed, [])) == sorted(lengths)  # every item once per epoch
    spread = lambda batches: np.mean([max(b) - min(b) for b in batches])  # noqa: E731
    assert spread(bucketed) < 0.5 * spread(plain)


def test_get_batch_is_trimmed_to_its_longest_item(corpus):
    ds = MotionTextDataset(corpus, "train", seed=0, min_frames=16)
    batch = get_batch(ds, 0, 4, 0, bucket=1)
    assert batch["motion"].shape[1] == int(batch["length"].max()) == batch["mask"].shape[1]


def test_time_warp_slows_a_fraction_of_the_batches_by_one_factor(corpus):
    """batch_warp: 1.0 on about 1 - p of the steps, else one factor in [1, 2] for the whole batch, a function of
    (seed, step); get_batch hands it to every item; p = 0 draws exactly the batches it drew before."""
    from stablemofusion.data.batches import TIME_WARP_MAX, batch_warp

    warps = [batch_warp(s, 0, 0.3) for s in range(2000)]
    slowed = [w for w in warps if w != 1.0]
    assert 0.25 < len(slowed) / len(warps) < 0.35 and 1.0 < min(slowed) and max(slowed) < TIME_WARP_MAX == 2.0
    assert warps == [batch_warp(s, 0, 0.3) for s in range(2000)] and warps != [batch_warp(s, 1, 0.3) for s in range(2000)]
    assert {batch_warp(s, 0, 0.0) for s in range(100)} == {1.0} and {batch_warp(s, 0, 1.0) for s in range(100)} != {1.0}
    ds = MotionTextDataset(corpus, "train", seed=0, min_frames=16)
    step = next(s for s in range(50) if batch_warp(s, 0, 0.5) > 1.5)
    batch = get_batch(ds, step, 4, 0, bucket=1, time_warp=0.5)
    assert batch["warp"].tolist() == pytest.approx([batch_warp(step, 0, 0.5)] * 4)
    plain, off = get_batch(ds, step, 4, 0, bucket=1), get_batch(ds, step, 4, 0, bucket=1, time_warp=0.0)
    assert plain["caption"] == batch["caption"] and plain["motion"].equal(off["motion"])
    assert int(batch["length"].max()) > int(plain["length"].max())
