"""The one interface every denoiser implements, and the registry that builds one from its config."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any, ClassVar

import torch
from torch import nn

from ..core.errors import SMFError
from ..text.frozen import sentence_embedding
from ..text.transformer import TextTransformer


@dataclass
class TextConfig:
    """The trainable text transformer on top of the frozen encoder (whose width is ``in_dim``)."""

    in_dim: int = 384
    latent: int = 256
    layers: int = 4
    heads: int = 4
    ff: int = 1024
    dropout: float = 0.1
    max_tokens: int = 77
    # The frozen encoder's sentence embedding (mean of its valid token states, L2-normalised: what
    # sentence-transformers computes for MiniLM) as a global condition added to the timestep embedding,
    # beside the token cross-attention. Paraphrases land close together there. Off in the paper's design.
    sentence: bool = False


@dataclass
class TextCondition:
    """What a denoiser uses of the text, computed once per sampling call (:meth:`Denoiser.condition`) and
    reused at every step: features (B, L, latent) of the text transformer, zero where the text is dropped;
    mask (B, L) bool, True on real tokens; keep (B,) bool, False where the text is dropped (None: kept
    everywhere); sentence (B, C) the sentence conditioning (None for models without it)."""

    features: torch.Tensor
    mask: torch.Tensor
    keep: torch.Tensor | None
    sentence: torch.Tensor | None

    def repeat(self, n: int) -> "TextCondition":
        """The batch repeated ``n`` times along dim 0 (for several samples per prompt)."""
        rep = (lambda v: None if v is None else torch.cat([v] * n))
        return TextCondition(rep(self.features), rep(self.mask), rep(self.keep), rep(self.sentence))


class Denoiser(nn.Module):
    """Base class: ``forward(x_t, t, text_tokens, text_mask, drop_cond, motion_mask) -> x0``.

    x_t (B, T, D) noisy normalised features; t (B,) diffusion steps; text_tokens (B, L, C) frozen
    language-model token embeddings; text_mask (B, L) bool, True on real tokens; drop_cond (B,) bool,
    True where the text is dropped (classifier-free guidance: the text features become zeros);
    motion_mask (B, T) bool, True on valid frames (None = all valid). Returns x0 (B, T, D).

    ``forward`` is :meth:`condition` (the text part, once per call at inference) then :meth:`denoise` (the
    motion part, once per step); samplers call the two separately.
    """

    config_class: ClassVar[type]

    def __init__(self, text: TextConfig):
        super().__init__()
        self.text_config = text
        self.sentence_proj: nn.Linear | None = None
        self.guidance_embed: nn.Module | None = None  # a distilled student's (ModelConfig.guidance)
        self.condition_dim: int | None = None  # width of the global conditioning vector (the timestep embedding)
        self.text = TextTransformer(text.in_dim, text.latent, text.layers, text.heads, text.ff, text.dropout,
                                    text.max_tokens)

    def init_sentence_condition(self, out_dim: int) -> None:
        """Create the zero-initialised map from the sentence embedding to a ``out_dim`` conditioning vector
        (when the text config asks for it); a model trained without it therefore starts unchanged."""
        self.sentence_proj = None
        self.condition_dim = out_dim
        if self.text_config.sentence:
            self.sentence_proj = nn.Linear(self.text_config.in_dim, out_dim)
            nn.init.zeros_(self.sentence_proj.weight)
            nn.init.zeros_(self.sentence_proj.bias)

    def init_guidance_condition(self) -> None:
        """Add the guidance-scale input of a distilled student (zero-initialised: the model is unchanged until
        trained); needs :meth:`init_sentence_condition` called by the architecture first (its width)."""
        from .embeddings import GuidanceEmbedding

        if self.condition_dim is None:
            raise SMFError(f"{type(self).__name__} has no global conditioning vector for a guidance input")
        self.guidance_embed = GuidanceEmbedding(self.condition_dim)

    @property
    def takes_guidance(self) -> bool:
        """Whether the guidance scale is an input (a distilled student: one forward per step, no CFG pair)."""
        return self.guidance_embed is not None

    def condition(self, tokens: torch.Tensor, mask: torch.Tensor,
                  drop_cond: torch.Tensor | None = None, guidance: torch.Tensor | float | None = None) -> TextCondition:
        """(B, L, C) frozen tokens, (B, L) mask, (B,) drop flags -> the text condition of :meth:`denoise`.
        ``guidance`` (B,) or a number: the guidance scale of a model that takes it as input (required there,
        ignored otherwise)."""
        mask = mask.bool()
        h = self.text(tokens, mask)
        keep = None if drop_cond is None else ~drop_cond.bool()
        if keep is not None:
            h = h * keep.to(h.dtype)[:, None, None]
        sentence = None
        if self.sentence_proj is not None:
            emb = sentence_embedding(tokens, mask, drop_cond)
            sentence = self.sentence_proj(emb.to(self.sentence_proj.weight.dtype))
        if self.guidance_embed is not None:
            if guidance is None:
                raise SMFError("this model is a distilled student: it needs the guidance scale as input")
            w = torch.as_tensor(guidance, dtype=torch.float32, device=tokens.device).expand(tokens.shape[0])
            g = self.guidance_embed(w).to(h.dtype)
            sentence = g if sentence is None else sentence + g
        return TextCondition(h, mask, keep, sentence)

    def forward(self, x_t: torch.Tensor, t: torch.Tensor, text_tokens: torch.Tensor, text_mask: torch.Tensor,
                drop_cond: torch.Tensor | None = None, motion_mask: torch.Tensor | None = None,
                guidance: torch.Tensor | float | None = None) -> torch.Tensor:
        return self.denoise(x_t, t, self.condition(text_tokens, text_mask, drop_cond, guidance), motion_mask)

    def denoise(self, x_t: torch.Tensor, t: torch.Tensor, cond: TextCondition,
                motion_mask: torch.Tensor | None = None) -> torch.Tensor:
        """x_t (B, T, D), t (B,), the text condition, motion_mask (B, T) bool or None -> x0 (B, T, D)."""
        raise NotImplementedError

    def frame_bucket(self, frames: int, multiple: int) -> int:
        """The padded length to run ``frames`` frames at: ``frames`` rounded up to ``multiple`` when the
        prediction on valid frames does not depend on padding (masked models) and the model takes that many
        frames, else ``frames``."""
        padded = -(-frames // multiple) * multiple
        limit = getattr(getattr(self, "config", None), "max_frames", None)
        return padded if self.padding_invariant and (limit is None or padded <= limit) else frames

    @property
    def padding_invariant(self) -> bool:
        """Whether frames past the motion mask leave the prediction on valid frames unchanged."""
        return True

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())


DENOISERS: dict[str, type[Denoiser]] = {}


def register(name: str):
    """Class decorator adding a denoiser to the registry under ``name``."""

    def wrap(cls):
        DENOISERS[name] = cls
        return cls

    return wrap


@dataclass
class ModelConfig:
    """Everything needed to rebuild a denoiser: its architecture name and that architecture's options;
    ``guidance``: the guidance scale is an input (a distilled student, ``smf distil``)."""

    arch: str = "unet"
    motion_dim: int = 263
    text: TextConfig = field(default_factory=TextConfig)
    options: dict[str, Any] = field(default_factory=dict)
    guidance: bool = False

    def to_dict(self) -> dict:
        d = asdict(self)
        if not self.guidance:  # configs of ordinary models stay as they were written before the field existed
            del d["guidance"]
        return d

    @staticmethod
    def from_dict(d: dict) -> "ModelConfig":
        known = {f.name for f in fields(TextConfig)}
        text = TextConfig(**{k: v for k, v in d.get("text", {}).items() if k in known})
        return ModelConfig(arch=d["arch"], motion_dim=d.get("motion_dim", 263), text=text,
                           options=dict(d.get("options", {})), guidance=bool(d.get("guidance", False)))
