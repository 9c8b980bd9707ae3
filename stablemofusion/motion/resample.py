"""Resampling a motion in time (numpy)."""

from __future__ import annotations

import numpy as np


def resample(x: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Linearly resample a motion (T, ...) from ``src_fps`` to ``dst_fps`` over the same duration."""
    if abs(src_fps - dst_fps) < 1e-9 or len(x) < 2:
        return x
    t_src = np.arange(len(x)) / src_fps
    n = int(np.floor(t_src[-1] * dst_fps + 1e-9)) + 1
    pos = np.arange(n) / dst_fps * src_fps
    i0 = np.minimum(np.floor(pos).astype(int), len(x) - 2)
    w = (pos - i0).reshape((-1,) + (1,) * (x.ndim - 1))
    return x[i0] * (1 - w) + x[i0 + 1] * w
