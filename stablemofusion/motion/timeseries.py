"""Array-API building blocks along time for the final stage, loop-free so that the stage exports as a graph.

Every function takes series with time on axis 1: (N, T) or (N, T, C), N any batch (motions, joints). They are
written once against the array API (:mod:`~stablemofusion.motion.arrays`): numpy in, numpy out for the Python
runtimes; torch in, torch out when the final stage is exported as an ONNX graph for the page, Node.js and game
engines. A few ask which library they run on (:func:`cummax`, :func:`last_true`, :func:`sorted_in_time`, :func:`at`,
:func:`window`, :func:`atan2`): each has one definition and two ways to compute it, numpy's fastest call and one that
exports to ONNX (a traced length is symbolic, and ONNX Runtime has no float64 arctangent).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from .arrays import device, namespace

GRAPH_STEPS = 17  # doublings of a running maximum in a graph: motions of up to 2**17 frames


def frames(x):
    """(T,) int64: the frame indices 0 .. T-1 of ``x`` (N, T, ...)."""
    xp = namespace(x)
    return xp.arange(x.shape[1], device=device(x))


def cummax(x):
    """(N, T) running maximum along time (numpy's ``maximum.accumulate``; elsewhere by doubling, ceil(log2 T)
    steps). Here and below a numpy array takes numpy's path whatever numpy's version (1.x gives no array-API
    namespace of its own); anything else is a tensor."""
    if isinstance(x, np.ndarray):
        return np.maximum.accumulate(x, axis=1)
    import torch  # the exporter's path: torch is installed wherever a tensor came from

    out, k = x, 1
    T = x.shape[1]
    steps = (T - 1).bit_length() if isinstance(T, int) else GRAPH_STEPS  # a traced length is any length
    for _ in range(steps):
        out = torch.maximum(out, torch.cat([out[:, :1].expand(-1, k), out], 1)[:, :T])
        k *= 2
    return out


def sorted_in_time(x):
    """``x`` (N, T, ...) sorted along time, smallest first (values only, so stability does not matter; ONNX has no
    stable sort). Tensors are ordered by their float32 values (ONNX Runtime Web's WebGPU build sorts no float64),
    then read in their own precision: two values closer than float32 tells apart may swap places, nothing else."""
    if isinstance(x, np.ndarray):
        return np.sort(x, axis=1)
    import torch

    return torch.gather(x, 1, torch.sort(x.float(), dim=1).indices)


def count(x):
    """(1,) int64: the frame count T of ``x`` (N, T, ...) as an array (a traced length stays symbolic)."""
    return frames(x)[-1:] + 1


def last_true(m):
    """(N, T) int64: the last frame at or before t where ``m`` (N, T) holds, -1 where none does (numpy: a running
    maximum; elsewhere the k-th true frame of a row, k its running count: a scatter and a gather, O(T))."""
    t = frames(m)
    if isinstance(m, np.ndarray):
        return np.maximum.accumulate(np.where(m, t[None], -1), axis=1)
    import torch

    seen = torch.cumsum(m.to(torch.int64), 1)  # (N, T) true frames up to t
    slot = torch.where(m, seen - 1, torch.zeros_like(seen) + count(m))  # the k-th true frame goes to slot k - 1
    kth = torch.zeros_like(torch.cat([seen, seen[:, :1]], 1)).scatter(1, slot, t[None].expand_as(slot))
    return torch.where(seen > 0, torch.gather(kth, 1, torch.clamp(seen - 1, min=0)), torch.zeros_like(seen) - 1)


def next_true(m):
    """(N, T) int64: the first frame at or after t where ``m`` (N, T) holds, T where none does."""
    xp = namespace(m)
    T = count(m)
    back = last_true(xp.flip(m, axis=1))
    return xp.flip(xp.where(back >= 0, T - 1 - back, back * 0 + T), axis=1)


def shifted(x, k: int, fill):
    """``x`` (N, T, ...) moved ``k`` frames later (k > 0) or earlier (k < 0), ``fill`` where nothing comes in."""
    xp = namespace(x)
    if k == 0:
        return x
    T = x.shape[1]
    pad = xp.full_like(x[:, :1], fill)
    pad = xp.concat([pad] * abs(k), axis=1)
    if k > 0:
        return xp.concat([pad, x], axis=1)[:, :T]
    return xp.concat([x, pad], axis=1)[:, abs(k):]


def at(x, idx):
    """``x`` (N, T) or (N, T, C) read at frames ``idx`` (N, S) (clipped into 0 .. T-1): (N, S) or (N, S, C)."""
    if isinstance(x, np.ndarray):  # the same gather, by fancy indexing (a third of take_along_axis's time)
        return x[np.arange(x.shape[0])[:, None], np.minimum(np.maximum(idx, 0), x.shape[1] - 1)]
    import torch

    i = torch.clamp(idx, min=0)
    i = torch.minimum(i, count(x) - 1)
    if x.ndim == 3:
        i = i[..., None].expand(-1, -1, x.shape[2])
    return torch.gather(x, 1, i)


def window(x, weights, edge: bool):
    """sum_j weights[j] x[t + j - r] along time of ``x`` (N, T, ...), r = len(weights) // 2: outside the motion
    zero (``edge`` False: numpy's ``convolve(mode="same")`` of a symmetric kernel) or the nearest frame's value."""
    r = len(weights) // 2
    if isinstance(x, np.ndarray):  # the same sum as one product with a (T, T) matrix of the weights
        m = _window_matrix(x.shape[1], tuple(map(float, weights)), edge)
        return x @ m.T if x.ndim == 2 else m @ x
    import torch  # the same matrix, built in the graph for any T: a scatter of the weights

    T = x.shape[1]
    src = frames(x)[:, None] + torch.arange(-r, r + 1, device=x.device)[None]  # (T, 2r + 1) the frame each reads
    w = torch.as_tensor(np.asarray(weights, dtype=np.float64), dtype=x.dtype, device=x.device)[None].expand_as(src)
    if not edge:
        w = torch.where((src >= 0) & (src < count(x)), w, torch.zeros_like(w))
    src = torch.minimum(torch.clamp(src, min=0), count(x) - 1)
    m = torch.zeros_like(x[0, :1, ..., 0] if x.ndim == 3 else x[0, :1]).expand(T, T).contiguous()
    m = m.scatter_add(1, src, w)
    return x @ m.T if x.ndim == 2 else m @ x


@functools.lru_cache(maxsize=64)
def _window_matrix(T: int, weights: tuple[float, ...], edge: bool) -> np.ndarray:
    """(T, T): row t holds the weights :func:`window` gives each frame for frame t."""
    r = len(weights) // 2
    src = np.arange(T)[:, None] + np.arange(-r, r + 1)[None]  # (T, 2r + 1) the frame each weight reads
    w = np.broadcast_to(np.asarray(weights), src.shape)
    inside = (src >= 0) & (src < T)
    if not edge:
        w = np.where(inside, w, 0.0)
    m = np.zeros((T, T))
    np.add.at(m, (np.repeat(np.arange(T), 2 * r + 1), np.clip(src, 0, T - 1).ravel()), w.ravel())
    return m


def windows(x, r: int):
    """(N, T, 2r + 1): the values of ``x`` (N, T) at t - r .. t + r, the edges extended by their nearest value."""
    xp = namespace(x)
    first, last = x[:, :1], x[:, -1:]
    padded = xp.concat([xp.concat([first] * r, axis=1), x, xp.concat([last] * r, axis=1)], axis=1) if r else x
    T = x.shape[1]
    return xp.stack([padded[:, j:j + T] for j in range(2 * r + 1)], axis=-1)


def gradient(x):
    """numpy's ``gradient`` along time of ``x`` (N, T, ...), unit spacing: central differences inside, one-sided at
    the two ends (T >= 2)."""
    xp = namespace(x)
    inner = (x[:, 2:] - x[:, :-2]) / 2.0
    return xp.concat([x[:, 1:2] - x[:, :1], inner, x[:, -1:] - x[:, -2:-1]], axis=1)


def gaussian(sigma: float, truncate: float) -> np.ndarray:
    """The normalised Gaussian kernel of ``sigma`` frames reaching ``truncate`` sigmas (scipy's gaussian_filter1d)."""
    radius = int(truncate * float(sigma) + 0.5)
    taps = np.arange(-radius, radius + 1)
    kernel = np.exp(-0.5 * (taps / float(sigma)) ** 2)
    return kernel / kernel.sum()


def smoothstep(x):
    """3x^2 - 2x^3 of ``x`` clipped to [0, 1]: 0 and 1 with zero slope at both ends."""
    xp = namespace(x)
    x = xp.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def xz(v):
    """(..., 2) the floor components (x, z) of vectors ``v`` (..., 3), Y up."""
    xp = namespace(v)
    return xp.stack([v[..., 0], v[..., 2]], axis=-1)


def norm(v):
    """(...) the length of vectors ``v`` (..., C)."""
    xp = namespace(v)
    return xp.sqrt(xp.sum(v * v, axis=-1))


def atan2(y, x):
    """Elementwise atan2 in the arrays' precision (radians). ONNX Runtime has no float64 arctangent: tensors take a
    float32 arctangent refined by two Newton steps on sin/cos (float64 to the last bits)."""
    if isinstance(y, np.ndarray):
        return np.arctan2(y, x)
    import torch

    theta = torch.atan2(y.float(), x.float()).to(y.dtype)
    r = torch.sqrt(x * x + y * y)
    for _ in range(2):
        s, c = torch.sin(theta), torch.cos(theta)
        theta = theta + (y * c - x * s) / torch.where(r > 0, r, torch.ones_like(r))
    return theta


def unwrap(x):
    """``x`` (N, T) angles in radians with every jump between frames larger than pi made smaller by whole turns
    (numpy's ``unwrap``, written with array-API calls)."""
    xp = namespace(x)
    d = x[:, 1:] - x[:, :-1]
    pi = const(x, math.pi)
    wrapped = xp.remainder(d + pi, 2.0 * pi) - pi
    wrapped = xp.where((wrapped == -pi) & (d > 0), pi + xp.zeros_like(d), wrapped)
    fix = xp.where(xp.abs(d) < pi, xp.zeros_like(d), wrapped - d)
    return x + xp.concat([xp.zeros_like(x[:, :1]), xp.cumulative_sum(fix, axis=1)], axis=1)


def const(like, value: float):
    """``value`` as a number of ``like``'s precision: the float itself for numpy; for a tensor a 0-d tensor of its
    dtype (a graph exporter stores a bare Python number as float32, which would round 0.1, 9.81, 180 / pi ...)."""
    if type(like) is np.ndarray:
        return float(value)
    return namespace(like).asarray(float(value), dtype=like.dtype, device=device(like))


def degrees(x):
    return x * const(x, 180.0 / math.pi)


def radians(x):
    return x * const(x, math.pi / 180.0)


__all__ = ["at", "atan2", "const", "count", "cummax", "degrees", "frames", "gaussian", "gradient", "last_true", "next_true", "norm",
           "radians", "shifted", "smoothstep", "sorted_in_time", "unwrap", "window", "windows", "xz"]
