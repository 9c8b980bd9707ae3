"""One seeded noise for every runtime: standard normal draws that are a pure function of their coordinates.

The same (seed, stream, draw, index) gives the same number in numpy, in torch (which takes these arrays) and in
JavaScript (``assets/runtime/noise.js``), so a prompt, seed and length make the same motion everywhere. Nothing
is sequential: any element can be computed alone, and a motion's first n frames do not depend on its length.

Definition (all integers unsigned 32-bit, ``*`` wrapping multiplication, ``^`` xor, ``>>`` logical shift):

- ``mix(x)``: ``x ^= x >> 16; x *= 0x7FEB352D; x ^= x >> 15; x *= 0x846CA68B; x ^= x >> 16`` (a bijection of
  32-bit words with full avalanche, C. Wellons' "lowbias32");
- the key of a draw: ``k = mix(seed_lo ^ 0x9E3779B9); k = mix(k ^ seed_hi); k = mix(k ^ stream); k = mix(k ^
  draw)``, where seed_lo and seed_hi are the low and high 32 bits of the seed (0 <= seed < 2**53);
- element i of the draw (flat index, C order over (frames, dims): ``i = frame * dims + dim``) belongs to the
  pair p = i >> 1, whose two words are ``a = mix(mix(2p) ^ k)``, ``b = mix(mix(2p + 1) ^ k)``;
- Box-Muller in float64 on 24-bit uniforms: ``u = ((a >> 8) + 1) / 2**24`` in (0, 1], ``v = (b >> 8) / 2**24``;
  ``r = sqrt(-2 ln u)``; element 2p is ``r cos(2 pi v)``, element 2p + 1 is ``r sin(2 pi v)``; rounded to
  float32. |values| <= 5.77.

How the pipeline uses it: a sampling call's item k draws with ``stream`` k when the call has one seed, with
stream 0 and its own seed when each item has one; the initial noise is ``draw`` 0, a sampler's step noise draws
1, 2, ... in order.
"""

from __future__ import annotations

import numpy as np

NOISE_VERSION = 1  # bump when any number above changes
_MASK = 0xFFFFFFFF
_M1, _M2, _GOLDEN = 0x7FEB352D, 0x846CA68B, 0x9E3779B9
SEED_LIMIT = 2**53


def mix(x: np.ndarray) -> np.ndarray:
    """The 32-bit mixing bijection of the definition, on a uint32 array (a new array)."""
    x = np.asarray(x, dtype=np.uint32)
    x = x ^ (x >> np.uint32(16))
    x = x * np.uint32(_M1)
    x ^= x >> np.uint32(15)
    x *= np.uint32(_M2)
    x ^= x >> np.uint32(16)
    return x


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


def normal(seed: int, count: int, *, stream: int = 0, draw: int = 0) -> np.ndarray:
    """Elements 0..count-1 of one draw: (count,) float32 standard normal values."""
    pairs = (int(count) + 1) // 2
    k = np.uint32(draw_key(seed, stream, draw))
    words = mix(_mixed_counters(2 * pairs) ^ k)
    a, b = words[0::2], words[1::2]
    u = ((a >> np.uint32(8)).astype(np.float64) + 1.0) * (1.0 / 2**24)
    v = (b >> np.uint32(8)).astype(np.float64) * (2.0 * np.pi / 2**24)
    r = np.sqrt(-2.0 * np.log(u))
    out = np.empty(2 * pairs, dtype=np.float64)
    out[0::2] = r * np.cos(v)
    out[1::2] = r * np.sin(v)
    return out[:count].astype(np.float32)


_MIXED = np.zeros(0, dtype=np.uint32)  # mix(c) for the counters c = 0, 1, ... (the same for every key)


def _mixed_counters(n: int) -> np.ndarray:
    """mix(0), ..., mix(n - 1), kept between calls (they do not depend on the seed)."""
    global _MIXED
    if len(_MIXED) < n:
        _MIXED = mix(np.arange(max(n, 2 * len(_MIXED)), dtype=np.uint32))
    return _MIXED[:n]


def noise(seed: int, frames: int, dims: int, *, stream: int = 0, draw: int = 0) -> np.ndarray:
    """(frames, dims) float32: one item's draw (its first n frames are the same for any ``frames`` >= n)."""
    return normal(seed, int(frames) * int(dims), stream=stream, draw=draw).reshape(int(frames), int(dims))


def batch_noise(seed: int | list[int], lengths: list[int], dims: int, *, draw: int = 0) -> np.ndarray:
    """(B, max(lengths), dims) float32 of one sampling call: item k's own frames from stream k of ``seed`` (one
    int) or from stream 0 of ``seed[k]`` (one per item); zeros past each item's length."""
    lengths = [int(n) for n in lengths]
    per_item = isinstance(seed, (list, tuple))
    if per_item and len(seed) != len(lengths):
        raise ValueError(f"one seed per item: {len(seed)} seeds for {len(lengths)} items")
    out = np.zeros((len(lengths), max(lengths, default=0), int(dims)), dtype=np.float32)
    for k, n in enumerate(lengths):
        s, stream = (seed[k], 0) if per_item else (seed, k)
        out[k, :n] = noise(s, n, dims, stream=stream, draw=draw)
    return out


__all__ = ["NOISE_VERSION", "batch_noise", "draw_key", "mix", "noise", "normal"]
