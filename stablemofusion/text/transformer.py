"""The small trainable text transformer on top of a frozen language model's token embeddings."""

from __future__ import annotations

import contextlib

import torch
from torch import nn

from ..models.dropout import Dropout


@contextlib.contextmanager
def no_fast_path():
    """Within it, nn.TransformerEncoderLayer runs its layers as modules: its inference fast path reads the
    linear weights directly (skipping the LoRA wrappers of an adapted model) and is one fused operator that ONNX
    export does not know."""
    before = torch.backends.mha.get_fastpath_enabled()
    torch.backends.mha.set_fastpath_enabled(False)
    try:
        yield
    finally:
        torch.backends.mha.set_fastpath_enabled(before)


class TextTransformer(nn.Module):
    """Frozen token embeddings (B, L, in_dim) -> contextual tokens (B, L, latent), padding masked.

    A linear projection, learned positions, then ``layers`` pre-norm transformer encoder layers.
    """

    def __init__(self, in_dim: int, latent: int = 256, layers: int = 4, heads: int = 4, ff: int = 1024,
                 dropout: float = 0.1, max_tokens: int = 77):
        super().__init__()
        self.proj = nn.Linear(in_dim, latent)
        self.pos = nn.Parameter(torch.zeros(1, max_tokens, latent))
        nn.init.normal_(self.pos, std=0.02)
        layer = nn.TransformerEncoderLayer(latent, heads, ff, dropout, activation="gelu", batch_first=True,
                                           norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        for block in self.encoder.layers:  # the cheaper CPU mask (weights and checkpoints unchanged)
            block.dropout, block.dropout1, block.dropout2 = Dropout(dropout), Dropout(dropout), Dropout(dropout)
        self.norm = nn.LayerNorm(latent)
        self.max_tokens = max_tokens

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """tokens (B, L, in_dim), mask (B, L) bool True on real tokens -> (B, L, latent), zero on padding."""
        L = tokens.shape[1]
        if L > self.max_tokens:
            raise ValueError(f"text has {L} tokens, more than the {self.max_tokens} this model takes")
        x = self.proj(tokens) + self.pos[:, :L]
        x = self.encoder(x, src_key_padding_mask=~mask)
        # where() rather than a product: a caption with no valid token gives NaN rows, which must become 0
        return torch.where(mask[..., None], self.norm(x), torch.zeros((), dtype=x.dtype, device=x.device))
