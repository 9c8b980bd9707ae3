"""Low-rank adapters (LoRA, Hu et al. 2021) of a denoiser: which layers, how they are trained, how they merge.

Training wraps the chosen layers with ``peft``'s LoRA layers (the base weights frozen); an adapter is the
``lora_A``/``lora_B`` pairs of those layers. Loading merges them into a plain denoiser once:
``W <- W + (alpha / rank) * B @ A`` for a linear layer; for a 1-D convolution (A: (r, in, k), B: (out, r, 1))
``W[o, i, k] += (alpha / rank) * sum_r B[o, r] A[r, i, k]``. The merged model is the base model's class with
other weights, so every engine and runtime runs it at the base model's speed.
"""

from __future__ import annotations

import torch
from torch import nn

from ..core.errors import SMFError
from ..text.transformer import no_fast_path  # noqa: F401  (public here too: adapters train under it)
from .check import LORA_A, LORA_B, MAX_SCALE, LoraConfig, fit_layers  # noqa: F401  (public here too)

# the layers an adapter may change: every Linear and Conv1d of the denoiser except the text transformer's
# attention output projections (nn.MultiheadAttention reads their weight directly, so a wrapper would be skipped)
SKIPPED = ("self_attn.out_proj",)


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




def checked_pairs(state: dict[str, torch.Tensor], scale: float,
                  shapes: dict[str, tuple]) -> list[tuple[str, torch.Tensor, torch.Tensor]]:
    """``(layer, lora_A, lora_B)`` of each adapted layer of loaded tensors, every pair checked against the model's
    weight shapes ``shapes`` (:func:`~stablemofusion.adapters.check.fit_layers`), floating point and finite; nothing
    multiplied. One-line SMFError for the first problem."""
    pairs = []
    for layer, ka, kb in fit_layers({k: tuple(v.shape) for k, v in state.items()}, scale, shapes):
        a, b = state[ka], state[kb]
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
