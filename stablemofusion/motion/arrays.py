"""The one place where numpy meets torch in the motion math.

The functions of rotation.py, features.py and footskate/underpressure.py are written once, in torch.
Those that also take numpy arrays are wrapped by :func:`numpy_edge`: numpy arguments become tensors on the
way in and tensor results become numpy arrays on the way out, so that numpy in gives numpy out (same dtype:
float64 stays float64) and torch in gives torch out (same device and dtype, differentiable).
"""

from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar

import numpy as np
import torch

Array = TypeVar("Array", np.ndarray, torch.Tensor)
F = TypeVar("F", bound=Callable[..., Any])


def to_torch(x: np.ndarray | np.generic | torch.Tensor, dtype: torch.dtype | None = None,
             device: torch.device | str | None = None) -> torch.Tensor:
    """A tensor of ``x``: a tensor as it is (cast when ``dtype``/``device`` are given), a numpy array without a
    copy where torch can share its memory (writable, native byte order, no negative strides), else copied."""
    if isinstance(x, torch.Tensor):
        return x if dtype is None and device is None else x.to(dtype=dtype, device=device)
    a = np.asarray(x)
    if not a.flags.writeable or not a.dtype.isnative or any(s < 0 for s in a.strides):
        a = np.array(a)  # torch cannot share read-only views (np.broadcast_to), swapped bytes or flipped strides
    t = torch.from_numpy(a)
    return t if dtype is None and device is None else t.to(dtype=dtype, device=device)


def to_numpy(x: Any) -> Any:
    """Tensors (also inside tuples and lists) -> numpy arrays of the same dtype; anything else as it is."""
    if isinstance(x, torch.Tensor):
        return x.detach().cpu().numpy()
    if isinstance(x, (tuple, list)):
        return type(x)(to_numpy(v) for v in x)
    return x


def _is_numpy(x: Any) -> bool:
    return isinstance(x, (np.ndarray, np.generic))


def numpy_edge(fn: F | None = None, *, numpy_dtype: torch.dtype | None = None) -> F:
    """Let a torch function take numpy arrays too: its numpy arguments (positional or keyword) become tensors
    (``numpy_dtype`` when given, e.g. torch.float64 for float64 math, else their own dtype; on the device of
    the first tensor argument, if any), and when no argument was a tensor its results come back as numpy.
    Calls without numpy arguments go straight to the function."""

    def wrap(f: F) -> F:
        @functools.wraps(f)
        def edge(*args: Any, **kwargs: Any) -> Any:
            values = (*args, *kwargs.values())
            if not any(_is_numpy(v) for v in values):
                return f(*args, **kwargs)
            device = next((v.device for v in values if isinstance(v, torch.Tensor)), None)
            back = device is None

            def conv(v: Any) -> Any:
                return to_torch(v, numpy_dtype, device) if _is_numpy(v) else v

            out = f(*(conv(v) for v in args), **{k: conv(v) for k, v in kwargs.items()})
            return to_numpy(out) if back else out

        edge.__wrapped_torch__ = f  # type: ignore[attr-defined]  # the torch function itself
        return edge  # type: ignore[return-value]

    return wrap(fn) if fn is not None else wrap  # type: ignore[return-value]
