"""The sentence embedding of a caption: the frozen encoder's token states averaged over the valid tokens and
L2-normalised (what sentence-transformers computes for MiniLM). Written once against the array API: torch in
(the models' global condition, differentiable) or numpy in (the known actions, the portable runtime)."""

from __future__ import annotations

from ..motion.arrays import namespace


def sentence_embedding(tokens, mask, drop_cond=None):
    """Frozen token states (B, L, C), mask (B, L) bool -> (B, C) unit sentence embeddings (mean over valid
    tokens, L2-normalised); rows where ``drop_cond`` (B,) is True are zero (the unconditional branch)."""
    xp = namespace(tokens, mask)
    m = xp.astype(mask, tokens.dtype)[..., None]
    pooled = xp.sum(tokens * m, axis=1) / xp.clip(xp.sum(m, axis=1), min=1.0)
    pooled = pooled / xp.clip(xp.linalg.vector_norm(pooled, axis=-1, keepdims=True), min=1e-8)
    if drop_cond is not None:
        pooled = pooled * xp.astype(~xp.astype(drop_cond, xp.bool), pooled.dtype)[:, None]
    return pooled
