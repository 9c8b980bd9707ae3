"""Text/motion evaluator in the T2M design: two encoders into one 512-d space, trained contrastively.

* Motion: features without the 4 foot-contact dims, normalised with the evaluator's own Mean/Std ->
  two strided temporal convolutions (time / 4) -> bidirectional GRU over the valid frames -> 512-d.
* Text: frozen language-model token embeddings (MiniLM by default, from the disk cache) ->
  bidirectional GRU -> 512-d.

Matching distance is the Euclidean distance between the two embeddings (smaller = better match).
Saved as a folder: ``evaluator.safetensors``, ``config.json``, ``Mean.npy``, ``Std.npy``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence

from ..core.errors import SMFError

WEIGHTS = "evaluator.safetensors"
CONFIG = "config.json"
CONTACT_DIMS = 4  # the last 4 feature dims (foot contacts) are not seen, as in the original evaluator
UNIT = 4  # temporal downsampling of the motion encoder (frames per GRU step)


@dataclass
class EvaluatorConfig:
    """Sizes of the evaluator (saved in config.json)."""

    motion_dim: int = 263
    text_dim: int = 384
    conv_dim: int = 256  # the original uses 512 / 1024 / 512; 256 trains ~4x faster on a CPU
    motion_hidden: int = 256
    text_hidden: int = 256
    out_dim: int = 512
    dropout: float = 0.2

    @classmethod
    def from_dict(cls, d: dict) -> "EvaluatorConfig":
        return cls(**{k: d[k] for k in cls.__dataclass_fields__ if k in d})


def _last_states(gru: nn.GRU, x: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
    """Concatenated final forward/backward hidden states of a bidirectional GRU over valid steps: (B, 2H)."""
    packed = pack_padded_sequence(x, lengths.clamp_min(1).cpu(), batch_first=True, enforce_sorted=False)
    _, h = gru(packed)  # (2, B, H)
    return torch.cat([h[0], h[1]], dim=-1)


class MotionEncoder(nn.Module):
    """(B, T, D) normalised features (contacts dropped inside), lengths (B,) -> (B, out_dim)."""

    def __init__(self, cfg: EvaluatorConfig):
        super().__init__()
        d_in = cfg.motion_dim - CONTACT_DIMS
        self.conv = nn.Sequential(
            nn.Conv1d(d_in, cfg.conv_dim, 4, 2, 1), nn.Dropout(cfg.dropout), nn.LeakyReLU(0.2),
            nn.Conv1d(cfg.conv_dim, cfg.conv_dim, 4, 2, 1), nn.Dropout(cfg.dropout), nn.LeakyReLU(0.2),
        )
        self.proj = nn.Linear(cfg.conv_dim, cfg.conv_dim)
        self.gru = nn.GRU(cfg.conv_dim, cfg.motion_hidden, batch_first=True, bidirectional=True)
        self.head = nn.Sequential(nn.Linear(2 * cfg.motion_hidden, cfg.motion_hidden), nn.LayerNorm(cfg.motion_hidden),
                                  nn.LeakyReLU(0.2), nn.Linear(cfg.motion_hidden, cfg.out_dim))

    def forward(self, motion: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        x = motion[..., :-CONTACT_DIMS]
        T = x.shape[1]
        valid = (torch.arange(T, device=x.device)[None] < lengths[:, None]).to(x.dtype)
        x = x * valid[..., None]  # padded frames never reach the encoder
        pad = (-T) % UNIT
        if pad:
            x = torch.nn.functional.pad(x, (0, 0, 0, pad))
        h = self.proj(self.conv(x.transpose(1, 2)).transpose(1, 2))
        steps = torch.div(lengths, UNIT, rounding_mode="floor").clamp(1, h.shape[1])
        return self.head(_last_states(self.gru, h, steps))


class TextEncoder(nn.Module):
    """(B, L, text_dim) frozen token embeddings, mask (B, L) -> (B, out_dim)."""

    def __init__(self, cfg: EvaluatorConfig):
        super().__init__()
        self.proj = nn.Linear(cfg.text_dim, cfg.text_hidden)
        self.gru = nn.GRU(cfg.text_hidden, cfg.text_hidden, batch_first=True, bidirectional=True)
        self.head = nn.Sequential(nn.Linear(2 * cfg.text_hidden, cfg.text_hidden), nn.LayerNorm(cfg.text_hidden),
                                  nn.LeakyReLU(0.2), nn.Linear(cfg.text_hidden, cfg.out_dim))

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.head(_last_states(self.gru, self.proj(tokens), mask.sum(1)))


class Evaluator(nn.Module):
    """Both encoders plus the normalisation of raw features (Mean/Std as buffers)."""

    def __init__(self, cfg: EvaluatorConfig, mean: np.ndarray | None = None, std: np.ndarray | None = None):
        super().__init__()
        self.config = cfg
        self.motion_encoder = MotionEncoder(cfg)
        self.text_encoder = TextEncoder(cfg)
        self.register_buffer("mean", torch.as_tensor(np.zeros(cfg.motion_dim) if mean is None else mean,
                                                     dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(np.ones(cfg.motion_dim) if std is None else std,
                                                    dtype=torch.float32))

    def embed_motion(self, features: torch.Tensor, lengths: torch.Tensor | list[int]) -> torch.Tensor:
        """Raw features (B, T, D) in dataset units, lengths (B,) frames -> embeddings (B, out_dim)."""
        if features.shape[-1] != self.config.motion_dim:
            raise SMFError(f"evaluator expects {self.config.motion_dim}-dim features, got {features.shape[-1]}")
        lengths = torch.as_tensor(lengths, device=features.device)
        x = (features.to(self.mean.dtype) - self.mean) / self.std
        return self.motion_encoder(x, lengths)

    def embed_text(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Frozen token embeddings (B, L, text_dim), mask (B, L) -> embeddings (B, out_dim)."""
        return self.text_encoder(tokens.to(self.mean.dtype), mask)


def save_evaluator(path: str | Path, model: Evaluator, meta: dict) -> Path:
    """Write an evaluator folder atomically: weights, config.json (sizes + ``meta``), Mean.npy, Std.npy."""
    from safetensors.torch import save_file

    from ..core.io import atomic_dir

    with atomic_dir(path) as tmp:
        state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
        save_file(state, tmp / WEIGHTS)
        (tmp / CONFIG).write_text(json.dumps({"evaluator": asdict(model.config), **meta}, indent=2) + "\n")
        np.save(tmp / "Mean.npy", model.mean.cpu().numpy())
        np.save(tmp / "Std.npy", model.std.cpu().numpy())
    return Path(path)


def load_evaluator(path: str | Path, device: str | torch.device = "cpu") -> tuple[Evaluator, dict]:
    """Load an evaluator folder (eval mode) and its config dict."""
    from safetensors.torch import load_file

    path = Path(path)
    if not (path / CONFIG).is_file() or not (path / WEIGHTS).is_file():
        raise SMFError(f"not an evaluator folder (needs {CONFIG} and {WEIGHTS}): {path}")
    try:
        config = json.loads((path / CONFIG).read_text())
        cfg = EvaluatorConfig.from_dict(config["evaluator"])
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise SMFError(f"{path / CONFIG}: not an evaluator config ({e})") from None
    model = Evaluator(cfg)
    missing, unexpected = model.load_state_dict(load_file(path / WEIGHTS), strict=False)
    if missing or unexpected:
        raise SMFError(f"{path / WEIGHTS}: weights do not fit the config (missing {missing[:3]})")
    return model.to(device).eval(), config


__all__ = ["EvaluatorConfig", "Evaluator", "MotionEncoder", "TextEncoder", "save_evaluator", "load_evaluator",
           "CONTACT_DIMS"]
