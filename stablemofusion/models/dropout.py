"""Dropout for every trainable model (the denoisers and their text transformer), with a keep mask that costs a
quarter of torch's on the CPU.

torch's CPU dropout draws one random number per element (``bernoulli_``: 4.4 ms for 64 x 128 x 112 elements on
one thread of a Xeon, 9% of a training step). Here one 64-bit draw gives the keep bits of four elements, 16 bits
each, so ``p`` is rounded to a multiple of 1/65536 (0.1 -> 0.10000610) and the kept values are scaled by the
exact ``1 / (1 - p)`` of that rounding, so the expectation is unchanged. On other devices it is torch's own
(fused) dropout. In evaluation mode it is the identity, as ``nn.Dropout``; it has no weights, so checkpoints do
not change. Measured in docs/models.md, "Training speed on this CPU".
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

KEEP_BITS = 16  # random bits per element: four elements per 64-bit draw
_LEVELS = 1 << KEEP_BITS


def dropout(x: torch.Tensor, p: float, training: bool = True) -> torch.Tensor:
    """Zero each element of ``x`` with probability ``p`` (rounded to 1/65536) and scale the rest by 1/(1-p)."""
    if not training or p == 0.0:
        return x
    if x.device.type != "cpu" or not 0.0 < p < 1.0:
        return F.dropout(x, p, True)
    n = x.numel()
    cut = round(p * _LEVELS)  # drop where the 16-bit draw (as a signed int16) falls below cut - 32768
    bits = torch.empty((n + 3) // 4, dtype=torch.int64).random_(-(1 << 63), None).view(torch.int16)[:n]
    keep = (bits >= cut - _LEVELS // 2).view(x.shape).to(x.dtype)
    return x * keep.mul_(_LEVELS / (_LEVELS - cut))


class Dropout(nn.Module):
    """``nn.Dropout`` with :func:`dropout`'s cheaper mask on the CPU."""

    def __init__(self, p: float = 0.5):
        super().__init__()
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"dropout probability must be in [0, 1], got {p}")
        self.p = p

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return dropout(x, self.p, self.training)

    def extra_repr(self) -> str:
        return f"p={self.p}"


__all__ = ["Dropout", "KEEP_BITS", "dropout"]
