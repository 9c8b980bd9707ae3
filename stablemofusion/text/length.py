"""Length from text: a small estimator of a motion's length from the frozen encoder's tokens.

A two-layer MLP maps a summary of the caption to a distribution over lengths in ``unit``-frame bins from
``min_frames`` to ``max_frames``; a motion takes the distribution's quantile at its seed's level
(:func:`~stablemofusion.core.noise.length_level`: different seeds, different lengths, as real takes of one action
differ), the median (the value that minimises the expected absolute error) where no level is given. The summary (``LengthConfig.inputs``) is the frozen encoder's sentence embedding
(``"sentence"``, :func:`~stablemofusion.text.frozen.sentence_embedding`), the pooled tokens of a frozen copy of a
trained model's text transformer (``"text"``, kept inside the estimator; that transformer was trained to tell
motions apart, and tells held-out verbs apart where the sentence embedding does not: docs/history.md), or the two
side by side (``"both"``).
Trained with cross-entropy on the train split's (caption, length) pairs. Saved beside a model as
``length.safetensors`` + ``length.json``; the pipeline uses it when no length is given.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..core.errors import SMFError
from ..motion.skeleton import HUMANML3D
from .frozen import sentence_embedding
from .names import LENGTH_CONFIG, LENGTH_WEIGHTS
from .transformer import TextTransformer

WEIGHTS, CONFIG = LENGTH_WEIGHTS, LENGTH_CONFIG
INPUTS = ("sentence", "text", "both")  # what the estimator reads of a caption (LengthConfig.inputs)
TEXT_DIMS = ("in_dim", "latent", "layers", "heads", "ff", "max_tokens")  # of the copied text transformer


@dataclass
class LengthConfig:
    """The estimator's input (the frozen encoder it was trained with; ``inputs``, one of INPUTS, and the MLP's
    input width ``in_dim``; for ``"text"`` and ``"both"`` the copied text transformer's dimensions ``text``,
    TEXT_DIMS), hidden width, and the length bins."""

    text_encoder: str = "minilm"
    in_dim: int = 384
    hidden: int = 256
    dropout: float = 0.1
    min_frames: int = HUMANML3D.min_frames
    max_frames: int = HUMANML3D.max_frames
    unit: int = 4
    inputs: str = "sentence"
    text: dict | None = None

    def __post_init__(self):
        if self.inputs not in INPUTS:
            raise SMFError(f"length estimator inputs must be one of {', '.join(INPUTS)}, got {self.inputs!r}")
        needs_text = self.inputs != "sentence"
        if needs_text != (self.text is not None) or (needs_text and set(self.text) != set(TEXT_DIMS)):
            raise SMFError(f"a length estimator on text inputs needs the text transformer's {', '.join(TEXT_DIMS)}")

    @property
    def bins(self) -> int:
        return (self.max_frames - self.min_frames) // self.unit + 1

    def bin_of(self, frames: np.ndarray) -> np.ndarray:
        """Length bin of each length (frames, clipped to the range)."""
        f = np.clip(np.asarray(frames), self.min_frames, self.max_frames)
        return (f - self.min_frames) // self.unit

    def frames_of(self, bins: torch.Tensor) -> torch.Tensor:
        return self.min_frames + self.unit * bins


def _mlp(config: LengthConfig) -> nn.Sequential:
    """(B, in_dim) features -> (B, bins) logits."""
    return nn.Sequential(nn.Linear(config.in_dim, config.hidden), nn.GELU(), nn.Dropout(config.dropout),
                         nn.Linear(config.hidden, config.bins))


class LengthEstimator(nn.Module):
    """Frozen tokens (B, L, C) and mask (B, L) -> :meth:`features` (B, in_dim) -> (B, bins) logits over lengths.

    With ``inputs`` "text" or "both" it holds ``text``, a frozen copy of a model's text transformer (fill it with
    :meth:`copy_text` before training); the MLP ``net`` is all that trains."""

    def __init__(self, config: LengthConfig):
        super().__init__()
        self.config = config
        self.text: TextTransformer | None = None
        if config.text is not None:
            self.text = TextTransformer(**config.text, dropout=0.0).requires_grad_(False).eval()
        self.net = _mlp(config)

    def train(self, mode: bool = True) -> "LengthEstimator":
        """Train mode for the MLP only: the copied text transformer stays frozen in eval mode."""
        super().train(mode)
        if self.text is not None:
            self.text.eval()
        return self

    def copy_text(self, text: TextTransformer) -> "LengthEstimator":
        """Take a model's text transformer weights (the ``"text"`` and ``"both"`` inputs)."""
        if self.text is None:
            raise SMFError("this length estimator reads the sentence embedding: it has no text transformer")
        self.text.load_state_dict(text.state_dict())
        return self

    @torch.no_grad()
    def features(self, tokens: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Frozen tokens (B, L, C), mask (B, L) bool -> (B, in_dim): the sentence embedding and/or the copied text
        transformer's tokens averaged over the valid ones, each a unit vector."""
        tokens, mask = tokens.float(), mask.bool()
        parts = []
        if self.config.inputs in ("sentence", "both"):
            parts.append(sentence_embedding(tokens, mask))
        if self.text is not None:
            parts.append(sentence_embedding(self.text(tokens, mask), mask))
        return torch.cat(parts, -1)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.net(features)

    @torch.no_grad()
    def predict_frames(self, tokens: torch.Tensor, mask: torch.Tensor, levels: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) predicted lengths in frames for frozen tokens (B, L, C), mask (B, L): each predicted distribution's
        quantile at ``levels`` (B,) in (0, 1) (None: its median)."""
        return self.quantile_frames(self.features(tokens, mask), levels)

    @torch.no_grad()
    def median_frames(self, features: torch.Tensor) -> torch.Tensor:
        """(B,) predicted lengths in frames from :meth:`features` (B, in_dim): each distribution's median."""
        return self.quantile_frames(features)

    @torch.no_grad()
    def quantile_frames(self, features: torch.Tensor, levels: torch.Tensor | None = None) -> torch.Tensor:
        """(B,) lengths in frames from :meth:`features` (B, in_dim): the first bin of each predicted distribution
        whose cumulative probability reaches its level (``levels`` (B,) float32 in (0, 1); None: 0.5, the median)."""
        p = self(features.float()).softmax(-1).cumsum(-1)
        q = torch.full(p.shape[:1], 0.5) if levels is None else levels.to(p.dtype)
        return self.config.frames_of((p < q[:, None]).sum(-1).clamp(max=self.config.bins - 1))

    def save(self, folder: str | Path, metrics: dict | None = None) -> None:
        """Write ``length.safetensors`` and ``length.json`` (config and training metrics) into ``folder``; the
        copied text transformer in float16 (as a shipped model holds it)."""
        from safetensors.torch import save_file

        from ..core.io import write_text

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / (WEIGHTS + ".tmp")
        save_file({k: (v.half() if k.startswith("text.") else v).detach().cpu().contiguous()
                   for k, v in self.state_dict().items()}, tmp)
        tmp.replace(folder / WEIGHTS)
        write_text(folder / CONFIG, json.dumps({"config": asdict(self.config), "metrics": metrics or {}}, indent=2) + "\n")

    @staticmethod
    def load(folder: str | Path) -> "LengthEstimator":
        from safetensors.torch import load_file

        folder = Path(folder)
        try:
            meta = json.loads((folder / CONFIG).read_text(encoding="utf-8"))
            model = LengthEstimator(LengthConfig(**meta["config"]))
            model.load_state_dict({k: v.float() for k, v in load_file(folder / WEIGHTS).items()})
        except (OSError, KeyError, TypeError, RuntimeError, json.JSONDecodeError) as e:
            raise SMFError(f"{folder}: cannot load the length estimator ({e})") from None
        return model.eval()


def caption_lengths(data: str | Path, split: str, unit: int = 4) -> tuple[list[str], np.ndarray]:
    """Every (caption, length in frames) pair of a corpus split, as the training crops see them: the item's
    length floored to ``unit`` frames, at most the skeleton's ``max_frames``."""
    from ..data.dataset import MotionTextDataset

    ds = MotionTextDataset(data, split, feat_bias=1.0)
    texts, lengths = [], []
    for e in ds.entries:
        n = min(e.end - e.start, ds.max_frames) // unit * unit
        for c in e.captions:
            texts.append(c.caption)
            lengths.append(n)
    return texts, np.asarray(lengths)


def caption_features(model: LengthEstimator, texts: list[str], cache, batch: int = 512) -> torch.Tensor:
    """(N, in_dim) :meth:`LengthEstimator.features` of ``texts`` through a text cache (``get_or_compute``)."""
    out = []
    for a in range(0, len(texts), batch):
        tokens, mask = cache.get_or_compute(texts[a:a + batch], device="cpu")
        out.append(model.features(tokens, mask))
    return torch.cat(out)


def train_length_estimator(model: LengthEstimator, train: tuple[torch.Tensor, np.ndarray], *, steps: int = 2000,
                           batch_size: int = 256, lr: float = 1e-3, weight_decay: float = 0.01,
                           seed: int = 0) -> LengthEstimator:
    """Fit the estimator's MLP (initialised afresh from ``seed``) on (its :meth:`~LengthEstimator.features`
    (N, in_dim), lengths (N,)) with cross-entropy over the bins."""
    emb, lengths = train
    config = model.config
    target = torch.from_numpy(config.bin_of(lengths)).long()
    torch.manual_seed(seed)
    model.net = _mlp(config)
    opt = torch.optim.AdamW(model.net.parameters(), lr=lr, weight_decay=weight_decay)
    g = torch.Generator().manual_seed(seed)
    model.train()
    for _ in range(steps):
        idx = torch.randint(0, len(target), (min(batch_size, len(target)),), generator=g)
        loss = nn.functional.cross_entropy(model(emb[idx]), target[idx])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return model.eval()


def length_errors(model: LengthEstimator, emb: torch.Tensor, lengths: np.ndarray, baseline: float) -> dict:
    """Mean absolute error (frames) of the estimator and of a constant ``baseline`` on (its features (N, in_dim),
    lengths)."""
    pred = model.median_frames(emb).numpy()
    mae, base = float(np.abs(pred - lengths).mean()), float(np.abs(baseline - lengths).mean())
    return {"mae_frames": mae, "baseline_mae_frames": base, "reduction": 1 - mae / base, "pairs": int(len(lengths))}
