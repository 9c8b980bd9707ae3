"""The one place where the motion math asks what kind of array it has.

The functions of rotation.py, kinematics.py and features.py are written once against the array API
(:func:`namespace` gives numpy's or torch's, through ``array_api_compat``): numpy in gives numpy out, torch in
gives torch out (device and dtype kept, differentiable), and the portable runtime runs them with numpy alone
(torch is never imported here). :func:`float64_numpy` marks those that promise float64 math on numpy input.
The UnderPressure port is written in torch only; :func:`numpy_edge` lets it take numpy arrays.
"""

from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar

import numpy as np
from array_api_compat import array_namespace, device, is_numpy_array, is_torch_array

Array = TypeVar("Array")
F = TypeVar("F", bound=Callable[..., Any])

__all__ = ["Array", "device", "float64_numpy", "namespace", "numpy_edge", "on_like", "to_numpy", "to_torch"]


# numpy 2.1 and later is itself an array API namespace (no compatibility layer to import: 0.1 s on first use)
_NUMPY_IS_ARRAY_API = all(hasattr(np, f) for f in ("concat", "unstack", "cumulative_sum", "astype", "isdtype"))


def namespace(*arrays: Any):
    """The array namespace (numpy's or torch's, array API) of the arrays given (None and numbers ignored)."""
    if _NUMPY_IS_ARRAY_API and type(arrays[0]) is np.ndarray and all(type(a) is np.ndarray for a in arrays[1:]):
        return np  # the common case, first: the final stage asks this a few hundred times a motion
    xs = [a for a in arrays if a is not None and not isinstance(a, (int, float, bool))]
    if _NUMPY_IS_ARRAY_API and all(type(a) is np.ndarray for a in xs):
        return np
    return array_namespace(*xs)


def float64_numpy(fn: F) -> F:
    """Let a function written against the array API do float64 math on numpy input: numpy arguments (positional
    or keyword) become float64 arrays; tensors pass as they are."""

    @functools.wraps(fn)
    def edge(*args: Any, **kwargs: Any) -> Any:
        conv = (lambda v: np.asarray(v, dtype=np.float64) if isinstance(v, (np.ndarray, np.generic)) else v)
        return fn(*(conv(v) for v in args), **{k: conv(v) for k, v in kwargs.items()})

    return edge  # type: ignore[return-value]


def to_torch(x, dtype=None, device=None):
    """A tensor of ``x``: a tensor as it is (cast when ``dtype``/``device`` are given), a numpy array without a
    copy where torch can share its memory (writable, native byte order, no negative strides), else copied."""
    import torch

    if is_torch_array(x):
        return x if dtype is None and device is None else x.to(dtype=dtype, device=device)
    a = np.asarray(x)
    if not a.flags.writeable or not a.dtype.isnative or any(s < 0 for s in a.strides):
        a = np.array(a)  # torch cannot share read-only views (np.broadcast_to), swapped bytes or flipped strides
    t = torch.from_numpy(a)
    return t if dtype is None and device is None else t.to(dtype=dtype, device=device)


def on_like(x: np.ndarray, like: Any = None) -> Any:
    """``x`` as an array of ``like``'s library on its device, its dtype kept (``like`` None or numpy: ``x`` as it
    is): where the final stage runs when its inputs are numpy but its math should run elsewhere (a GPU)."""
    if like is None or isinstance(like, np.ndarray):
        return x
    return namespace(like).asarray(x, device=device(like))


def to_numpy(x: Any) -> Any:
    """Tensors (also inside tuples and lists) -> numpy arrays of the same dtype; anything else as it is."""
    if is_torch_array(x):
        return x.detach().cpu().numpy()
    if isinstance(x, (tuple, list)):
        return type(x)(to_numpy(v) for v in x)
    return x


def numpy_edge(fn: F | None = None, *, numpy_dtype=None) -> F:
    """Let a torch-only function take numpy arrays too: its numpy arguments become tensors (``numpy_dtype`` when
    given, else their own dtype; on the device of the first tensor argument, if any), and when no argument was a
    tensor its results come back as numpy. Calls without numpy arguments go straight to the function."""

    def wrap(f: F) -> F:
        @functools.wraps(f)
        def edge(*args: Any, **kwargs: Any) -> Any:
            values = (*args, *kwargs.values())
            if not any(is_numpy_array(v) for v in values):
                return f(*args, **kwargs)
            dev = next((v.device for v in values if is_torch_array(v)), None)

            def conv(v: Any) -> Any:
                return to_torch(v, numpy_dtype, dev) if is_numpy_array(v) else v

            out = f(*(conv(v) for v in args), **{k: conv(v) for k, v in kwargs.items()})
            return to_numpy(out) if dev is None else out

        edge.__wrapped_torch__ = f  # type: ignore[attr-defined]  # the torch function itself
        return edge  # type: ignore[return-value]

    return wrap(fn) if fn is not None else wrap  # type: ignore[return-value]
