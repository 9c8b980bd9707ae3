"""Backends: what runs the network behind every task. :mod:`.base` is the seam (torch-free), :mod:`.torch_backend`
runs a checkpoint in PyTorch (its ``engine`` says how), :mod:`.onnx_backend` runs the exported graphs on ONNX
Runtime without torch. :func:`load_backend` is the one place that chooses between them."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from ..core.errors import SMFError
from ..core.limits import PORTABLE_ENGINE
from .base import Backend, Known

BACKENDS = ("torch", "onnx")
PORTABLE_ADAPTERS = ("--adapter needs PyTorch; the onnx backend runs adapters merged into graphs: "
                     "`smf export --onnx --adapter FILE --out DIR`, then --checkpoint DIR")


def torch_installed() -> bool:
    """Whether PyTorch is installed (the [train] extra), found without importing it."""
    try:
        return importlib.util.find_spec("torch") is not None
    except (ImportError, ValueError):  # found but unusable (or blocked)
        return False


def backend_for(backend: str | None = None, engine: str | None = None) -> str:
    """The backend a call runs on: ``backend`` ('torch', 'onnx'; None or 'auto': torch where it is installed, else
    onnx); the engine 'onnx' (the command line's spelling) means the onnx backend, any other engine the torch one.
    SMFError for a torch engine or backend asked for without PyTorch."""
    if backend not in (None, "auto") + BACKENDS:
        raise SMFError(f"backend must be one of auto, {', '.join(BACKENDS)}, got {backend!r}")
    if engine == PORTABLE_ENGINE:
        if backend == "torch":
            raise SMFError(f"the engine {PORTABLE_ENGINE!r} is the onnx backend, not the torch one")
        return "onnx"
    if backend in (None, "auto"):
        backend = "torch" if torch_installed() or engine not in (None, "auto") else "onnx"
    if backend == "torch" and not torch_installed():
        what = f"the engine {engine!r}" if engine not in (None, "auto") else "the torch backend"
        raise SMFError(f"{what} needs PyTorch, which this install lacks: pip install 'stablemofusion[train]' (the "
                       f"onnx backend, --engine {PORTABLE_ENGINE}, runs without it)")
    return backend


def load_backend(path: str | Path | None = None, *, backend: str | None = None, engine: str | None = None,
                 teacher: bool = False, threads: int | None = None, adapter=None, **torch_options) -> Backend:
    """The model in ``path`` (None: the shipped one; ``teacher``: the teacher it was distilled from) on the backend
    :func:`backend_for` chooses. ``threads``: CPU threads (None: the library's default); ``adapter``:
    adapter files merged into the torch weights; ``torch_options`` (device, dtype, rigid, text_cache_size):
    the torch backend's."""
    if backend in (None, "auto") and engine in (None, "auto") and path is not None and \
            (Path(path) / "graphs.json").is_file() and not (Path(path) / "config.json").is_file():
        backend = "onnx"  # a graphs folder: only the onnx backend runs it
    if backend_for(backend, engine) == "onnx":
        from .onnx_backend import OnnxBackend

        if adapter:
            raise SMFError(PORTABLE_ADAPTERS)
        unknown = set(torch_options) - {"device", "dtype"}
        if unknown:
            raise SMFError(f"the onnx backend takes no {', '.join(sorted(unknown))}")
        return OnnxBackend.from_pretrained(path, teacher=teacher, threads=threads)
    from .torch_backend import TorchBackend

    if threads is not None:
        import torch

        torch.set_num_threads(threads)
    if engine not in (None, "auto"):
        torch_options["engine"] = engine
    return TorchBackend.from_pretrained(path, teacher=teacher, adapter=adapter, **torch_options)


__all__ = ["BACKENDS", "Backend", "Known", "backend_for", "load_backend", "torch_installed"]
