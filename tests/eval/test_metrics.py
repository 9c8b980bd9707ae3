"""T2M metrics on cases with known answers."""

import numpy as np
import pytest

from stablemofusion.core.errors import SMFError
from stablemofusion.eval.metrics import diversity, fid, mean_ci, multimodality, r_precision


def test_fid_identical_sets_is_zero_and_a_shift_adds_its_square():
    x = np.random.default_rng(0).normal(size=(500, 8))
    assert fid(x, x) == pytest.approx(0.0, abs=1e-6)
    shift = np.array([3.0, 0, 0, 0, 0, 0, 0, 4.0])  # same covariance, means 5 apart -> FID 25
    assert fid(x, x + shift) == pytest.approx(25.0, rel=1e-6)
    assert fid(x, x * 2) > 1.0  # a different spread is penalised


def test_r_precision_on_a_hand_made_batch():
    motion = np.zeros((32, 4))
    motion[:, 0] = 10.0 * np.arange(32)  # motions on a line, 10 apart
    text = motion.copy()
    text[16:, 0] += 6.0  # texts 16..30 are nearer the next motion (4) than their own (6): rank 2; 31 has none next
    top, match = r_precision(text, motion, batch_size=32)
    assert top == pytest.approx([17 / 32, 1.0, 1.0])
    assert match == pytest.approx(16 * 6.0 / 32)


def test_r_precision_drops_the_last_partial_batch_and_checks_shapes():
    x = np.random.default_rng(1).normal(size=(70, 5))
    top, match = r_precision(x, x, batch_size=32)  # 64 pairs used, each its own nearest
    assert top == pytest.approx([1, 1, 1]) and match == pytest.approx(0.0, abs=1e-6)
    with pytest.raises(SMFError, match="at least 32"):
        r_precision(x[:10], x[:10])
    with pytest.raises(SMFError, match="differ in shape"):
        r_precision(x, x[:, :3])


def test_diversity_of_a_simplex_and_scaling():
    c = 3.0
    emb = np.eye(400) * c / np.sqrt(2)  # every two distinct points are c apart
    rng = np.random.default_rng(5)
    a, b = rng.choice(400, 300, replace=False), rng.choice(400, 300, replace=False)
    assert diversity(emb, 300, np.random.default_rng(5)) == pytest.approx(c * np.mean(a != b))
    x = np.random.default_rng(2).normal(size=(400, 6))
    assert diversity(2 * x, 300, np.random.default_rng(3)) == pytest.approx(2 * diversity(x, 300, np.random.default_rng(3)))
    assert diversity(np.ones((400, 3)), 300) == 0.0
    with pytest.raises(SMFError, match="more than 300"):
        diversity(x[:100], 300)


def test_multimodality_zero_for_identical_samples_and_known_for_two_clusters():
    emb = np.ones((5, 30, 4))
    assert multimodality(emb, 10) == 0.0
    emb = np.zeros((5, 30, 4))
    emb[:, 1::2, 0] = 2.0  # odd samples 2 away from even ones
    rng = np.random.default_rng(9)
    a, b = rng.choice(30, 10, replace=False), rng.choice(30, 10, replace=False)
    assert multimodality(emb, 10, np.random.default_rng(9)) == pytest.approx(2.0 * np.mean((a % 2) != (b % 2)))


def test_mean_ci():
    m, ci = mean_ci([1.0, 2.0, 3.0, 4.0])
    assert m == 2.5 and ci == pytest.approx(1.96 * np.sqrt(1.25) / 2)
