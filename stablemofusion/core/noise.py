"""One seeded noise for every runtime: standard normal draws that are a pure function of their coordinates.

The same (seed, stream, draw, index) gives the same number in numpy, in torch on the CPU or a CUDA GPU (the same
functions, written once against the array API: the numbers are made where the model runs) and in JavaScript
(``assets/runtime/noise.js``), so a prompt, seed and length make the same motion everywhere. Nothing is
sequential: any element can be computed alone, and a motion's first n frames do not depend on its length.

Definition (all integers unsigned 32-bit, ``*`` wrapping multiplication, ``^`` xor, ``>>`` logical shift):

- ``mix(x)``: ``x ^= x >> 16; x *= 0x7FEB352D; x ^= x >> 15; x *= 0x846CA68B; x ^= x >> 16`` (a bijection of
  32-bit words with full avalanche, C. Wellons' "lowbias32");
- the key of a draw: ``k = mix(seed_lo ^ 0x9E3779B9); k = mix(k ^ seed_hi); k = mix(k ^ stream); k = mix(k ^
  draw)``, where seed_lo and seed_hi are the low and high 32 bits of the seed (0 <= seed < 2**53);
- element i of the draw (flat index, C order over (frames, dims): ``i = frame * dims + dim``) belongs to the
  pair p = i >> 1, whose two words are ``a = mix(mix(2p) ^ k)``, ``b = mix(mix(2p + 1) ^ k)``;
- Box-Muller in float64 on 24-bit uniforms: ``u = ((a >> 8) + 1) / 2**24`` in (0, 1], ``v = (b >> 8) / 2**24``;
  ``r = sqrt(-2 ln u)``; element 2p is ``r cos(2 pi v)``, element 2p + 1 is ``r sin(2 pi v)``; rounded to
  float32. |values| <= 5.77;
- the uniform of a draw: ``((a >> 8) + 0.5) / 2**24`` in (0, 1), ``a`` the first word of its pair 0.

How the pipeline uses it: a sampling call's item k draws with ``stream`` k when the call has one seed, with
stream 0 and its own seed when each item has one; the initial noise is ``draw`` 0, a sampler's step noise draws
1, 2, ... in order. A motion whose length the model predicts takes the length at the quantile ``uniform(seed,
stream, LENGTH_DRAW)`` of the length model's distribution, with its noise's seed and stream (a prompt's part k of
a timeline: stream k of the timeline's seed).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..motion.arrays import device as device_of
from ..motion.arrays import namespace, on_like

NOISE_VERSION = 1  # bump when any number above changes
_MASK = 0xFFFFFFFF
_M1, _M2, _GOLDEN = 0x7FEB352D, 0x846CA68B, 0x9E3779B9
SEED_LIMIT = 2**53
LENGTH_DRAW = 0xFFFFFFFF  # the draw of a motion's length quantile (a sampler's draws count up from 0)
CHUNK = 1 << 22  # elements made at once on a CPU (about 100 MB of temporaries); a GPU takes 16 times more


def _mul(x, m: int):
    """``x * m`` modulo 2**32 of 32-bit words: numpy's uint32 wraps by itself; elsewhere (torch, whose unsigned
    integers lack most operations) the words are int64 in [0, 2**32) and the product is taken in 16-bit halves
    of ``m``, so that nothing exceeds 2**49."""
    if isinstance(x, np.ndarray):
        return x * np.uint32(m)
    return (x * (m & 0xFFFF) + (((x * (m >> 16)) & 0xFFFF) << 16)) & _MASK


def mix(x):
    """The 32-bit mixing bijection of the definition on an array of words: a numpy uint32 array (other numpy
    integers are taken as uint32), or int64 words in [0, 2**32) of another library (a new array)."""
    if isinstance(x, (np.ndarray, np.generic, list, tuple, int)):
        x = np.asarray(x, dtype=np.uint32)
    x = x ^ (x >> 16)
    x = _mul(x, _M1)
    x = x ^ (x >> 15)
    x = _mul(x, _M2)
    return x ^ (x >> 16)


def _mix_int(x: int) -> int:
    x &= _MASK
    x ^= x >> 16
    x = (x * _M1) & _MASK
    x ^= x >> 15
    x = (x * _M2) & _MASK
    return x ^ (x >> 16)


def draw_key(seed: int, stream: int = 0, draw: int = 0) -> int:
    """The 32-bit key of one draw (see the module docstring)."""
    seed = int(seed)
    if not 0 <= seed < SEED_LIMIT:
        raise ValueError(f"noise seeds are whole numbers from 0 to {SEED_LIMIT - 1}, got {seed}")
    k = _mix_int((seed & _MASK) ^ _GOLDEN)
    k = _mix_int(k ^ (seed >> 32))
    k = _mix_int(k ^ (int(stream) & _MASK))
    return _mix_int(k ^ (int(draw) & _MASK))


_NUMPY = np.zeros(0)  # asks namespace() for numpy's array API (numpy 1.x, as in Blender, has none of its own)
_MIXED: dict[str, Any] = {}  # mix(c) for the counters c = 0, 1, ... (the same for every key), per library and device


def _on_numpy(like) -> bool:
    return like is None or isinstance(like, np.ndarray)


def _words(values, like=None):
    """32-bit words as ``like``'s library holds them (numpy when None): numpy uint32, elsewhere int64 on its
    device (see :func:`_mul`)."""
    return np.asarray(values, dtype=np.uint32) if _on_numpy(like) else on_like(np.asarray(values, np.int64), like)


def _mixed_counters(n: int, like=None):
    """mix(0), ..., mix(n - 1) as words of ``like``'s library and device (numpy when None), kept between calls
    (they do not depend on the seed)."""
    place = "numpy" if _on_numpy(like) else f"{type(like).__module__}:{device_of(like)}"
    have = _MIXED.get(place)
    if have is None or have.shape[0] < n:
        have = mix(_words(np.arange(max(n, 2 * (0 if have is None else have.shape[0]))), like))
        _MIXED[place] = have
    return have[:n]


def _box_muller(keys, count: int, like=None):
    """(N, count) float32: elements 0..count-1 of the draws of the N ``keys`` (Python ints), made by ``like``'s
    library on its device (numpy when None)."""
    pairs = (int(count) + 1) // 2
    counters = _mixed_counters(2 * pairs, like)
    xp = namespace(_NUMPY if like is None else like)
    k = _words(keys, like)
    words = mix(counters[None, :] ^ k[:, None])  # (N, 2 pairs)
    a, b = words[:, 0::2], words[:, 1::2]
    u = (xp.astype(a >> 8, xp.float64) + 1.0) * (1.0 / 2**24)
    v = xp.astype(b >> 8, xp.float64) * (2.0 * np.pi / 2**24)
    r = xp.sqrt(-2.0 * xp.log(u))
    out = xp.reshape(xp.stack([r * xp.cos(v), r * xp.sin(v)], axis=-1), (k.shape[0], 2 * pairs))
    return xp.astype(out[:, :count], xp.float32)


def normal(seed: int, count: int, *, stream: int = 0, draw: int = 0) -> np.ndarray:
    """Elements 0..count-1 of one draw: (count,) float32 standard normal values."""
    return _box_muller([draw_key(seed, stream, draw)], count)[0]


def uniform(seed: int, *, stream: int = 0, draw: int = 0) -> float:
    """The uniform of one draw: a float in (0, 1), a multiple of 2**-25 (the definition above)."""
    a = _mix_int(_mix_int(0) ^ draw_key(seed, stream, draw))
    return ((a >> 8) + 0.5) / 2**24


def length_level(seed: int, stream: int = 0) -> float:
    """The quantile of the length model's distribution at which a motion of this seed and stream takes its length
    (:data:`LENGTH_DRAW`)."""
    return uniform(seed, stream=stream, draw=LENGTH_DRAW)


def noise(seed: int, frames: int, dims: int, *, stream: int = 0, draw: int = 0) -> np.ndarray:
    """(frames, dims) float32: one item's draw (its first n frames are the same for any ``frames`` >= n)."""
    return normal(seed, int(frames) * int(dims), stream=stream, draw=draw).reshape(int(frames), int(dims))


def draws(seed: int | Sequence[int], lengths: Sequence[int], dims: int, draw_indices: Sequence[int], *,
          like=None):
    """(len(draw_indices), B, max(lengths), dims) float32: the draws of one sampling call, made by ``like``'s
    library on its device (numpy when None; a torch tensor on a GPU makes them there). Item k's own frames come
    from stream k of ``seed`` (one int) or from stream 0 of ``seed[k]`` (one per item); zeros past each item's
    length. Made a few items at a time (at most :data:`CHUNK` elements on a CPU), whatever the batch."""
    lengths = [int(n) for n in lengths]
    per_item = isinstance(seed, (list, tuple))
    if per_item and len(seed) != len(lengths):
        raise ValueError(f"one seed per item: {len(seed)} seeds for {len(lengths)} items")
    B, T, D = len(lengths), max(lengths, default=0), int(dims)
    numpy = _on_numpy(like)
    xp = namespace(_NUMPY if numpy else like)
    where = None if numpy else device_of(like)
    chunk = CHUNK if where is None or str(where) == "cpu" else 16 * CHUNK
    items = max(1, chunk // max(1, T * D))
    if B == 0 or not len(draw_indices):
        return xp.zeros((len(draw_indices), B, T, D), dtype=xp.float32, device=where)
    frame = xp.arange(T, device=where)
    out = []
    for d in draw_indices:
        parts = []
        for lo in range(0, B, items):
            hi = min(B, lo + items)
            keys = [draw_key(*((seed[k], 0) if per_item else (seed, k)), int(d)) for k in range(lo, hi)]
            x = xp.reshape(_box_muller(keys, T * D, like), (hi - lo, T, D))
            n = xp.asarray(lengths[lo:hi], device=where)
            parts.append(xp.where((frame[None, :] < n[:, None])[:, :, None], x, xp.zeros_like(x)))
        out.append(parts[0] if len(parts) == 1 else xp.concat(parts, axis=0))
    return xp.stack(out)


def batch_noise(seed: int | list[int], lengths: list[int], dims: int, *, draw: int = 0) -> np.ndarray:
    """(B, max(lengths), dims) float32 of one sampling call, in numpy: :func:`draws` of one draw index."""
    return draws(seed, lengths, dims, [draw])[0]


__all__ = ["LENGTH_DRAW", "NOISE_VERSION", "batch_noise", "draw_key", "draws", "length_level", "mix", "noise", "normal",
           "uniform"]
