"""T2M metrics on evaluator embeddings: FID, R-precision, matching distance, diversity, multimodality.

All functions take numpy arrays of embeddings (rows = samples) and follow the T2M protocol:
R-precision and matching distance in batches of 32 (Euclidean distances), diversity over 300 random
pairs, multimodality over 10 random pairs of samples per caption.
"""

from __future__ import annotations

import numpy as np
from scipy import linalg

from ..core.errors import SMFError


def activation_stats(emb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (D,) and covariance (D, D) of embeddings (N, D)."""
    emb = np.asarray(emb, dtype=np.float64)
    if emb.ndim != 2 or len(emb) < 2:
        raise SMFError(f"need at least 2 embeddings of shape (N, D), got {emb.shape}")
    return emb.mean(0), np.cov(emb, rowvar=False)


def frechet_distance(mu1: np.ndarray, sigma1: np.ndarray, mu2: np.ndarray, sigma2: np.ndarray,
                     eps: float = 1e-6) -> float:
    """Fréchet distance between Gaussians: |mu1-mu2|^2 + tr(S1 + S2 - 2 sqrt(S1 S2))."""
    diff = mu1 - mu2
    covmean = linalg.sqrtm(sigma1.dot(sigma2))
    if not np.isfinite(covmean).all():
        offset = np.eye(sigma1.shape[0]) * eps
        covmean = linalg.sqrtm((sigma1 + offset).dot(sigma2 + offset))
    covmean = np.real(covmean)
    return float(max(diff.dot(diff) + np.trace(sigma1) + np.trace(sigma2) - 2 * np.trace(covmean), 0.0))


def fid(real: np.ndarray, generated: np.ndarray) -> float:
    """FID between two sets of embeddings (N, D) and (M, D)."""
    return frechet_distance(*activation_stats(real), *activation_stats(generated))


def euclidean_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise Euclidean distances (N, M) between rows of a (N, D) and b (M, D)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    d2 = (a ** 2).sum(1)[:, None] - 2 * a @ b.T + (b ** 2).sum(1)[None]
    return np.sqrt(np.maximum(d2, 0.0))


def r_precision_batch(text: np.ndarray, motion: np.ndarray, top_k: int = 3) -> tuple[np.ndarray, float]:
    """One batch of paired rows: (hits (top_k,) counts of the true motion within rank <= k for k = 1..top_k,
    summed matching distance of the true pairs)."""
    dist = euclidean_matrix(text, motion)
    ranks = (dist < np.diag(dist)[:, None]).sum(1)  # how many motions are strictly closer than the true one
    hits = np.array([(ranks < k).sum() for k in range(1, top_k + 1)], dtype=np.int64)
    return hits, float(np.trace(dist))


def r_precision(text: np.ndarray, motion: np.ndarray, batch_size: int = 32, top_k: int = 3
                ) -> tuple[np.ndarray, float]:
    """R-precision top-1..top_k (fractions) and mean matching distance over consecutive batches of
    ``batch_size`` pairs (a last partial batch is dropped, as the T2M loader does)."""
    text, motion = np.asarray(text), np.asarray(motion)
    if text.shape != motion.shape:
        raise SMFError(f"text and motion embeddings differ in shape: {text.shape} vs {motion.shape}")
    n = len(text) // batch_size * batch_size
    if n == 0:
        raise SMFError(f"R-precision needs at least {batch_size} pairs, got {len(text)}")
    hits, match = np.zeros(top_k, dtype=np.int64), 0.0
    for a in range(0, n, batch_size):
        h, m = r_precision_batch(text[a:a + batch_size], motion[a:a + batch_size], top_k)
        hits, match = hits + h, match + m
    return hits / n, match / n


def diversity(emb: np.ndarray, times: int = 300, rng: np.random.Generator | None = None) -> float:
    """Mean distance between ``times`` random pairs of rows (two independent index draws, as in T2M)."""
    emb = np.asarray(emb, dtype=np.float64)
    if len(emb) <= times:
        raise SMFError(f"diversity needs more than {times} samples, got {len(emb)}")
    rng = rng or np.random.default_rng(0)
    a, b = rng.choice(len(emb), times, replace=False), rng.choice(len(emb), times, replace=False)
    return float(np.linalg.norm(emb[a] - emb[b], axis=1).mean())


def multimodality(emb: np.ndarray, times: int = 10, rng: np.random.Generator | None = None) -> float:
    """Embeddings (captions, repeats, D) of several samples per caption: mean distance between ``times``
    random pairs of samples of the same caption."""
    emb = np.asarray(emb, dtype=np.float64)
    if emb.ndim != 3 or emb.shape[1] <= times:
        raise SMFError(f"multimodality needs (captions, repeats > {times}, D) embeddings, got {emb.shape}")
    rng = rng or np.random.default_rng(0)
    a, b = rng.choice(emb.shape[1], times, replace=False), rng.choice(emb.shape[1], times, replace=False)
    return float(np.linalg.norm(emb[:, a] - emb[:, b], axis=-1).mean())


def mean_ci(values) -> tuple[float, float]:
    """Mean and 95% half-interval 1.96 * std / sqrt(N) over replications (std with ddof 0, as T2M)."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        raise SMFError("no values to summarise")
    return float(v.mean()), float(1.96 * v.std() / np.sqrt(v.size))


__all__ = ["fid", "frechet_distance", "activation_stats", "euclidean_matrix", "r_precision", "r_precision_batch",
           "diversity", "multimodality", "mean_ci"]
