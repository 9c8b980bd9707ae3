"""The adapter file: one ``.safetensors`` holding the low-rank weights of a student and its teacher, with what
they were taught (the actions and their captions), the base model they fit (sha256 of its weights files) and
the licence the user states for their clips.

Tensors: ``student/<layer>.lora_A.weight``, ``student/<layer>.lora_B.weight``, the same under ``teacher/``
(float16). Metadata (strings): ``format`` = ``stablemofusion-adapter``, ``info`` = :class:`AdapterInfo` as
JSON. An adapter never changes the base model's files: it is merged into a loaded copy
(:func:`stablemofusion.adapters.lora.merge_into`).
"""

from __future__ import annotations

import functools
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import torch

from ..core.errors import SMFError
from .check import FORMAT, PARTS, VERSION, AdapterInfo, check_adapter_files, model_part, read_header  # noqa: F401
from .lora import layer_deltas



def weights_hash(folder: str | Path) -> str:
    """sha256 of the weights a model folder loads (:func:`folder_weights_hash`), computed once per folder and
    version of its files in a process."""
    from ..diffusion.checkpoint import resolve

    folder = resolve(folder)
    stamp = tuple((p.name, p.stat().st_mtime_ns, p.stat().st_size) for p in sorted(folder.rglob("*")) if p.is_file())
    return _weights_hash(folder, stamp)


@functools.lru_cache(maxsize=8)
def _weights_hash(folder: Path, stamp: tuple) -> str:
    return folder_weights_hash(folder)


def folder_weights_hash(folder: str | Path) -> str:
    """sha256 of the weights file a model folder loads (its EMA weights if it has them): what an adapter records
    of its base and checks at load. A model whose weights are held by its portable graphs (the shipped model) is
    hashed as the weights file it would have: its weights in its export dtype, as ``smf export`` writes them (the
    same bytes as the file the shipped model had before its weights moved into its graphs, so an adapter of it
    still fits)."""
    from safetensors.torch import save

    from ..diffusion.checkpoint import EMA, MODEL, graphs_of, read_config, resolve, weights_from_graphs

    folder = resolve(folder)
    path = folder / EMA if (folder / EMA).is_file() else folder / MODEL
    graphs = None if path.is_file() else graphs_of(folder)
    if graphs is not None:
        export = read_config(folder).export
        dtype = getattr(torch, export.dtype) if export is not None else torch.float32
        data = save({k: v.to(dtype).contiguous() for k, v in weights_from_graphs(*graphs).items()})
        return hashlib.sha256(data).hexdigest()
    if not path.is_file():
        raise SMFError(f"{folder}: no weights file {MODEL}")
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass
class Adapter:
    """An adapter in memory: its info and, per part (student, teacher), its LoRA weights."""

    info: AdapterInfo
    weights: dict[str, dict[str, torch.Tensor]]

    def deltas(self, part: str, shapes: dict[str, tuple]) -> dict[str, torch.Tensor]:
        """Dense weight updates of ``part`` (layer weight name -> tensor) for a model whose weights have ``shapes``
        (parameter name -> shape), checked against them before any is computed (:func:`layer_deltas`); SMFError
        when it has none or they do not fit."""
        if part not in self.weights or not self.weights[part]:
            raise SMFError(f"adapter {self.info.name!r} has no {part} weights")
        return layer_deltas(self.weights[part], self.info.lora.scale, shapes)

    def check_base(self, part: str, folder: str | Path) -> None:
        """SMFError unless ``folder`` holds the very weights this adapter's ``part`` was trained on."""
        want = self.info.base.get(part)
        if want is None or weights_hash(folder) != want:
            raise SMFError(f"adapter {self.info.name!r} was trained on another base model than {folder} "
                           f"(its {part} weights differ); adapt this model again with `smf adapt --base {folder}`")

    def save(self, path: str | Path) -> Path:
        """Write the adapter file atomically (float16 weights)."""
        from safetensors.torch import save_file

        from ..core.io import atomic_path

        tensors = {f"{part}/{k}": v.to(torch.float16).contiguous() for part, w in self.weights.items()
                   for k, v in w.items()}
        path = Path(path)
        with atomic_path(path) as tmp:
            save_file(tensors, str(tmp), metadata={"format": FORMAT, "version": str(VERSION),
                                                   "info": json.dumps(self.info.to_dict())})
            tmp.chmod(0o644)
        return path

    @staticmethod
    def load(path: str | Path) -> "Adapter":
        """Read an adapter file, its container checked first (:func:`~stablemofusion.adapters.check.read_header`);
        a one-line SMFError for anything that is not one."""
        from safetensors import SafetensorError, safe_open

        info, tensors = read_header(path)
        try:
            with safe_open(str(path), framework="pt", device="cpu") as f:
                weights = {p: {name: f.get_tensor(f"{p}/{name}").float() for name in names}
                           for p, names in tensors.items()}
        except (SafetensorError, OSError) as e:
            raise SMFError(f"{path}: not a readable adapter file ({str(e).splitlines()[0]})") from None
        return Adapter(info, weights)


def load_adapters(paths) -> list[Adapter]:
    """Adapters from file paths (one path or several); their names must differ."""
    if paths is None:
        return []
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    adapters = [a if isinstance(a, Adapter) else Adapter.load(a) for a in paths]
    names = [a.info.name for a in adapters]
    if len(set(names)) != len(names):
        raise SMFError(f"two adapters share a name ({', '.join(names)}); name them apart with `smf adapt --name`")
    return adapters


def checked_adapters(paths, folder: str | Path) -> list[Adapter]:
    """Adapters from file paths, each checked against the model in ``folder`` before that model is loaded: first
    without PyTorch (:func:`~stablemofusion.adapters.check.check_adapter_files`: the container, every layer against
    the model's weight shapes, finite values), then that it was trained on this model's very weights. A crafted file
    is refused in one line here, by the CLI and by a server before it starts its worker."""
    check_adapter_files(paths, folder)
    adapters = load_adapters(paths)
    part = model_part(folder)
    for a in adapters:
        a.check_base(part, folder)
    return adapters


__all__ = ["Adapter", "AdapterInfo", "FORMAT", "checked_adapters", "load_adapters", "weights_hash"]
