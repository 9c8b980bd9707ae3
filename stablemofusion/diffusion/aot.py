"""The ``aot`` engine's model: ``model.denoise`` exported once (``torch.export``, dynamic batch, frame and text
dims) and compiled ahead of time by AOTInductor into a ``.pt2`` package kept in a cache folder, so that a new
process loads compiled code (about 2 s) instead of compiling it (tens of seconds per shape with ``compiled``).

The package is keyed by the model's weights and options, the torch version, the device type and the dtype
(:func:`artefact_key`); it lives in ``$SMF_AOT_CACHE`` or ``~/.cache/stablemofusion/aot``. The first use on a
machine builds it (about 50-60 s on a 2-core CPU, written atomically); every later process only loads it.
One package serves every batch (1..:data:`MAX_ITEMS` forward items), every length that is a multiple of 16
frames (32..:data:`MAX_FRAMES`) and every text length (1..:data:`MAX_TOKENS` tokens), so the engine pads only
the frames (as ``compiled`` does), never the batch.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import tempfile
import time
from pathlib import Path

import torch

from ..core.errors import SMFError
from ..models.base import TextCondition

FRAME_MULTIPLE = 16  # the exported frame dim is 16 * k (what the engine pads to)
MAX_FRAMES = 256
MAX_ITEMS = 256  # forward items (a guided batch of B motions is 2B items)
MAX_TOKENS = 128
FORMAT = 2  # bump when the exported signature changes

_LOADED: dict[str, object] = {}  # key -> loaded runner (one per process)


def cache_dir() -> Path:
    return Path(os.environ.get("SMF_AOT_CACHE") or Path.home() / ".cache" / "stablemofusion" / "aot")


def _has_sentence(model) -> bool:
    """Whether the model's condition has a global vector (a sentence map, or a student's guidance input)."""
    return getattr(model, "sentence_proj", None) is not None or getattr(model, "guidance_embed", None) is not None


def artefact_key(model, device: torch.device, dtype: torch.dtype) -> str:
    """A hash of what the compiled package depends on: weights (names, shapes, bytes), the model's class and
    config, the torch version, the device type, the dtype and this module's format."""
    h = hashlib.sha256()
    config = getattr(model, "config", None)
    h.update(json.dumps([FORMAT, torch.__version__, device.type, str(dtype), type(model).__qualname__,
                         repr(config)]).encode())
    for name, v in model.state_dict().items():
        v = v.detach().to("cpu").contiguous()
        h.update(f"{name}{tuple(v.shape)}{v.dtype}".encode())
        h.update(v.view(-1).view(torch.uint8).numpy().tobytes() if v.numel() else b"")
    return h.hexdigest()[:24]


class _Flat(torch.nn.Module):
    """``model.denoise`` with flat tensor arguments (what torch.export takes)."""

    def __init__(self, model, sentence: bool):
        super().__init__()
        self.model, self.sentence = model, sentence

    def forward(self, x, t, features, mask, keep, motion_mask, sentence):
        cond = TextCondition(features, mask, keep, sentence if self.sentence else None)
        return self.model.denoise(x, t, cond, motion_mask)


@contextlib.contextmanager
def _exportable_pooling():
    """``F.max_pool1d(mask, 2)`` (the UNet's coarse masks) as a reshape and max over pairs while exporting: equal
    for the even lengths the engine runs (multiples of 16), and free of the guard on the frame count with
    which the pooling's decomposition specialises the exported frame dim to the example's."""
    import torch.nn.functional as F

    orig = F.max_pool1d

    def pool(x, kernel_size, *args, **kwargs):
        if kernel_size != 2 or args or kwargs:
            return orig(x, kernel_size, *args, **kwargs)
        return x.unflatten(-1, (-1, 2)).amax(-1)

    F.max_pool1d = pool
    try:
        yield
    finally:
        F.max_pool1d = orig


def _example(model, device, dtype, sentence: bool):
    """Example inputs of the export: 4 items, 208 frames, 32 tokens."""
    N, T, L = 4, 208, 32
    D, latent = int(model.motion_dim), int(model.text_config.latent)
    args = [torch.randn(N, T, D), torch.full((N,), 500.0), torch.randn(N, L, latent),
            torch.ones(N, L, dtype=torch.bool), torch.ones(N, dtype=torch.bool), torch.ones(N, T, dtype=torch.bool)]
    args.append(torch.randn(N, model.condition_dim) if sentence else torch.zeros(N, 1))  # unused without
    return tuple(a.to(device, dtype) if a.is_floating_point() else a.to(device) for a in args)


def build(model, path: Path, device: torch.device, dtype: torch.dtype) -> Path:
    """Export and AOT-compile ``model.denoise`` into the package ``path`` (written atomically)."""
    from torch.export import Dim

    sentence = _has_sentence(model)
    flat = _Flat(model, sentence).eval()
    items = Dim("items", min=1, max=MAX_ITEMS)
    k = Dim("k", min=2, max=MAX_FRAMES // FRAME_MULTIPLE)
    frames = FRAME_MULTIPLE * k
    tokens = Dim("tokens", min=1, max=MAX_TOKENS)
    dyn = [{0: items, 1: frames}, {0: items}, {0: items, 1: tokens}, {0: items, 1: tokens}, {0: items},
           {0: items, 1: frames}, {0: items}]
    path.parent.mkdir(parents=True, exist_ok=True)
    with torch.no_grad(), _exportable_pooling():
        ep = torch.export.export(flat, _example(model, device, dtype, sentence), dynamic_shapes=tuple(dyn))
    fd, tmp = tempfile.mkstemp(suffix=".pt2", dir=path.parent)
    os.close(fd)
    try:
        torch._inductor.aoti_compile_and_package(ep, package_path=tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def check_model(model) -> None:
    if not hasattr(model, "motion_dim"):
        raise SMFError(f"the aot engine supports the UNet denoiser, not {type(model).__name__}; use 'fast' or "
                       "'compiled'")
    if not getattr(model, "padding_invariant", False):
        raise SMFError("the aot engine needs a model whose valid frames do not depend on padding (lengths are padded "
                       "to multiples of 16); use 'fast' or 'compiled'")


class AOTDenoise:
    """The compiled package of ``model.denoise``, callable like it: built on first use on this machine (or
    loaded from the cache folder), loaded once per process. ``seconds`` and ``built`` tell what the first use
    cost and whether it compiled."""

    def __init__(self, model, device: torch.device | None = None, dtype: torch.dtype | None = None):
        check_model(model)
        p = next(model.parameters())
        self.device, self.dtype = device or p.device, dtype or p.dtype
        self.model, self.sentence = model, _has_sentence(model)
        t0 = time.perf_counter()
        self.key = artefact_key(model, self.device, self.dtype)
        self.path = cache_dir() / f"denoise-{self.key}.pt2"
        self.built = False
        if self.key not in _LOADED:
            if not self.path.exists():
                build(model, self.path, self.device, self.dtype)
                self.built = True
            _LOADED[self.key] = torch._inductor.aoti_load_package(str(self.path))
        self.runner = _LOADED[self.key]
        self.seconds = time.perf_counter() - t0

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, cond: TextCondition,
                motion_mask: torch.Tensor | None = None) -> torch.Tensor:
        N, T = x_t.shape[:2]
        if T % FRAME_MULTIPLE or not FRAME_MULTIPLE * 2 <= T <= MAX_FRAMES or N > MAX_ITEMS:
            raise SMFError(f"the aot engine runs 32..{MAX_FRAMES} frames in multiples of {FRAME_MULTIPLE} and at most "
                           f"{MAX_ITEMS} items per forward, got {N} x {T}")
        keep = cond.keep if cond.keep is not None else torch.ones(N, dtype=torch.bool, device=x_t.device)
        mm = motion_mask if motion_mask is not None else torch.ones(N, T, dtype=torch.bool, device=x_t.device)
        args = [x_t.contiguous(), t.to(x_t.dtype).contiguous(), cond.features.contiguous(), cond.mask.contiguous(),
                keep.contiguous(), mm.bool().contiguous()]
        args.append(cond.sentence.contiguous() if self.sentence else x_t.new_zeros(N, 1))
        return self.runner(*args)


def artefact_exists(model) -> bool:
    """Whether this model's package is already in the cache folder (then the engine starts in seconds)."""
    p = next(model.parameters())
    return (cache_dir() / f"denoise-{artefact_key(model, p.device, p.dtype)}.pt2").exists()


__all__ = ["AOTDenoise", "artefact_key", "artefact_exists", "build", "cache_dir"]
