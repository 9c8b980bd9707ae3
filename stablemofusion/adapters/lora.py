"""Low-rank adapters (LoRA, Hu et al. 2021) of a denoiser: which layers, how they are trained, how they merge.

Training wraps the chosen layers with ``peft``'s LoRA layers (the base weights frozen); an adapter is the
``lora_A``/``lora_B`` pairs of those layers. Loading merges them into a plain denoiser once:
``W <- W + (alpha / rank) * B @ A`` for a linear layer; for a 1-D convolution (A: (r, in, k), B: (out, r, 1))
``W[o, i, k] += (alpha / rank) * sum_r B[o, r] A[r, i, k]``. The merged model is the base model's class with
other weights, so every engine and runtime runs it at the base model's speed.
"""

from __future__ import annotations

import math

from dataclasses import asdict, dataclass

import torch
from torch import nn

from ..errors import SMFError
from ..text.transformer import no_fast_path  # noqa: F401  (public here too: adapters train under it)

# the layers an adapter may change: every Linear and Conv1d of the denoiser except the text transformer's
# attention output projections (nn.MultiheadAttention reads their weight directly, so a wrapper would be skipped)
SKIPPED = ("self_attn.out_proj",)
LORA_A, LORA_B = ".lora_A.weight", ".lora_B.weight"


@dataclass(frozen=True)
class LoraConfig:
    """Rank and scale of the low-rank updates (``alpha / rank`` multiplies B @ A); ``text``: the trainable text
    transformer's layers too (else the denoiser's only)."""

    rank: int = 16
    alpha: float = 16.0
    text: bool = True

    def __post_init__(self):
        if isinstance(self.rank, bool) or not isinstance(self.rank, int) or self.rank < 1:
            raise SMFError(f"an adapter's rank is a whole number from 1, got {self.rank!r}")
        if isinstance(self.alpha, bool) or not isinstance(self.alpha, (int, float)) or not math.isfinite(self.alpha):
            raise SMFError(f"an adapter's alpha is a finite number, got {self.alpha!r}")
        if not isinstance(self.text, bool):
            raise SMFError(f"an adapter's text flag is true or false, got {self.text!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @property
    def scale(self) -> float:
        return self.alpha / self.rank


def target_layers(model: nn.Module, text: bool = True) -> list[str]:
    """Names of the layers an adapter trains (Linear and Conv1d, except :data:`SKIPPED`; without ``text`` not
    those of the text transformer either)."""
    return [n for n, m in model.named_modules()
            if isinstance(m, (nn.Linear, nn.Conv1d)) and not any(n.endswith(s) for s in SKIPPED)
            and (text or not n.startswith("text."))]


def add_lora(model: nn.Module, cfg: LoraConfig) -> nn.Module:
    """Wrap ``model``'s target layers with trainable LoRA layers (B zero-initialised, so the model starts as
    the base); every base weight is frozen. Changes ``model`` in place and returns it."""
    from peft import LoraConfig as PeftLoraConfig
    from peft import inject_adapter_in_model

    peft_cfg = PeftLoraConfig(r=cfg.rank, lora_alpha=cfg.alpha, target_modules=target_layers(model, cfg.text),
                              lora_dropout=0.0)
    return inject_adapter_in_model(peft_cfg, model)


def lora_state(model: nn.Module) -> dict[str, torch.Tensor]:
    """The LoRA weights of a wrapped model: ``<layer>.lora_A.weight`` and ``<layer>.lora_B.weight``."""
    from peft import get_peft_model_state_dict

    return {k: v.detach().cpu().clone() for k, v in get_peft_model_state_dict(model).items()}


def load_lora_state(model: nn.Module, state: dict[str, torch.Tensor]) -> None:
    """Put saved LoRA weights back into a wrapped model (resuming)."""
    from peft import set_peft_model_state_dict

    result = set_peft_model_state_dict(model, state)
    if getattr(result, "unexpected_keys", None):
        raise SMFError(f"adapter weights do not fit the model (e.g. {result.unexpected_keys[0]})")


MAX_SCALE = 1e3  # alpha / rank of an adapter: trained ones are about 1-2; beyond this the merged model is noise


def checked_pairs(state: dict[str, torch.Tensor], scale: float,
                  shapes: dict[str, tuple]) -> list[tuple[str, torch.Tensor, torch.Tensor]]:
    """``(layer, lora_A, lora_B)`` of each adapted layer, every pair checked against the model's weight shapes
    ``shapes`` (parameter name -> shape) and nothing multiplied: one-line SMFError for a layer the model lacks, a rank,
    shape or dimension that does not fit, a tensor that is not floating point, non-finite values or a scale beyond
    :data:`MAX_SCALE`. What passes asks for no more memory than the model's own weights when merged."""
    if not (math.isfinite(scale) and abs(scale) <= MAX_SCALE):
        raise SMFError(f"adapter scale (alpha / rank) must be finite and at most {MAX_SCALE:g}, got {scale:g}")
    pairs = []
    for key in state:
        if not key.endswith(LORA_A):
            if not key.endswith(LORA_B):
                raise SMFError(f"adapter tensor {key} is neither a lora_A nor a lora_B weight")
            if key[: -len(LORA_B)] + LORA_A not in state:
                raise SMFError(f"adapter layer {key[: -len(LORA_B)]} has lora_B but no lora_A")
            continue
        layer = key[: -len(LORA_A)]
        a, b = state[key], state.get(layer + LORA_B)
        if b is None:
            raise SMFError(f"adapter layer {layer} has lora_A but no lora_B")
        want = shapes.get(layer + ".weight")
        if want is None:
            raise SMFError(f"the adapter changes {layer}.weight, which this model lacks (an adapter fits only the base "
                           "model it was trained on)")
        want = tuple(want)
        fits = (len(want) == 2 and a.ndim == 2 and b.ndim == 2 and 1 <= a.shape[0] == b.shape[1]
                and a.shape[1] == want[1] and b.shape[0] == want[0]) or \
               (len(want) == 3 and a.ndim == 3 and b.ndim == 3 and 1 <= a.shape[0] == b.shape[1] and b.shape[2] == 1
                and a.shape[1:] == want[1:] and b.shape[0] == want[0])
        if not fits or a.shape[0] > min(want[0], want[1]):
            raise SMFError(f"adapter layer {layer}: lora_A {tuple(a.shape)} and lora_B {tuple(b.shape)} do not fit its "
                           f"weight {want} at a rank from 1 to {min(want[0], want[1])}")
        if not (a.is_floating_point() and b.is_floating_point()):
            raise SMFError(f"adapter layer {layer} holds {a.dtype} and {b.dtype} weights, not floating point")
        if not (torch.isfinite(a).all() and torch.isfinite(b).all()):
            raise SMFError(f"adapter layer {layer} holds values that are not finite")
        pairs.append((layer, a, b))
    return pairs


def layer_deltas(state: dict[str, torch.Tensor], scale: float, shapes: dict[str, tuple]) -> dict[str, torch.Tensor]:
    """``<layer>.weight`` -> the dense update ``scale * B @ A`` of each adapted layer (shape of the weight), once
    every pair has passed :func:`checked_pairs`, so a file cannot ask for more memory than the model's own weights."""
    out = {}
    for layer, a, b in checked_pairs(state, scale, shapes):
        a, b = a.float(), b.float()
        delta = b @ a if a.ndim == 2 else torch.einsum("or,rik->oik", b[..., 0], a)  # linear; conv1d
        out[layer + ".weight"] = scale * delta
    return out


def merge_into(model: nn.Module, deltas: dict[str, torch.Tensor]) -> None:
    """Add dense updates (:func:`layer_deltas`) to a plain model's weights, in place."""
    params = dict(model.named_parameters())
    for name, delta in deltas.items():
        p = params.get(name)
        if p is None or p.shape != delta.shape:
            raise SMFError(f"the adapter changes {name}, which this model {'lacks' if p is None else 'shapes differently'}"
                           " (an adapter fits only the base model it was trained on)")
        with torch.no_grad():
            p.add_(delta.to(device=p.device, dtype=p.dtype))


__all__ = ["LoraConfig", "add_lora", "checked_pairs", "no_fast_path", "layer_deltas", "load_lora_state", "lora_state", "merge_into", "target_layers"]
