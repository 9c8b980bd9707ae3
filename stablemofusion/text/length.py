"""Length from text: a small estimator of a motion's length from the frozen sentence embedding.

A two-layer MLP maps the sentence embedding (:func:`~stablemofusion.text.frozen.sentence_embedding` of the
frozen encoder's tokens) to a distribution over lengths in ``unit``-frame bins from ``min_frames`` to
``max_frames``; the prediction is the distribution's median (the value that minimises the expected absolute
error). Trained with cross-entropy on the train split's (caption, length) pairs. Saved beside a model as
``length.safetensors`` + ``length.json``; the pipeline uses it when no length is given.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import SMFError
from ..motion.skeleton import HUMANML3D

WEIGHTS, CONFIG = "length.safetensors", "length.json"


@dataclass
class LengthConfig:
    """The estimator's input (the frozen encoder it was trained with, and its width), hidden width, and the
    length bins."""

    text_encoder: str = "minilm"
    in_dim: int = 384
    hidden: int = 256
    dropout: float = 0.1
    min_frames: int = HUMANML3D.min_frames
    max_frames: int = HUMANML3D.max_frames
    unit: int = 4

    @property
    def bins(self) -> int:
        return (self.max_frames - self.min_frames) // self.unit + 1

    def bin_of(self, frames: np.ndarray) -> np.ndarray:
        """Length bin of each length (frames, clipped to the range)."""
        f = np.clip(np.asarray(frames), self.min_frames, self.max_frames)
        return (f - self.min_frames) // self.unit

    def frames_of(self, bins: torch.Tensor) -> torch.Tensor:
        return self.min_frames + self.unit * bins


class LengthEstimator(nn.Module):
    """(B, in_dim) sentence embeddings -> (B, bins) logits over lengths."""

    def __init__(self, config: LengthConfig):
        super().__init__()
        self.config = config
        self.net = nn.Sequential(nn.Linear(config.in_dim, config.hidden), nn.GELU(), nn.Dropout(config.dropout),
                                 nn.Linear(config.hidden, config.bins))

    def forward(self, sentence: torch.Tensor) -> torch.Tensor:
        return self.net(sentence)

    @torch.no_grad()
    def predict_frames(self, sentence: torch.Tensor) -> torch.Tensor:
        """(B,) predicted lengths in frames: the median of each predicted distribution."""
        p = self(sentence.float()).softmax(-1).cumsum(-1)
        return self.config.frames_of((p < 0.5).sum(-1).clamp(max=self.config.bins - 1))

    def save(self, folder: str | Path, metrics: dict | None = None) -> None:
        """Write ``length.safetensors`` and ``length.json`` (config and training metrics) into ``folder``."""
        from safetensors.torch import save_file

        from ..io import write_text

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / (WEIGHTS + ".tmp")
        save_file({k: v.detach().cpu().contiguous() for k, v in self.state_dict().items()}, tmp)
        tmp.replace(folder / WEIGHTS)
        write_text(folder / CONFIG, json.dumps({"config": asdict(self.config), "metrics": metrics or {}}, indent=2) + "\n")

    @staticmethod
    def load(folder: str | Path) -> "LengthEstimator":
        from safetensors.torch import load_file

        folder = Path(folder)
        try:
            meta = json.loads((folder / CONFIG).read_text(encoding="utf-8"))
            model = LengthEstimator(LengthConfig(**meta["config"]))
            model.load_state_dict(load_file(folder / WEIGHTS))
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


def sentence_embeddings(texts: list[str], cache, batch: int = 512) -> torch.Tensor:
    """(N, C) sentence embeddings of ``texts`` through a text cache (``get_or_compute``)."""
    from .frozen import sentence_embedding

    out = []
    for a in range(0, len(texts), batch):
        tokens, mask = cache.get_or_compute(texts[a:a + batch], device="cpu")
        out.append(sentence_embedding(tokens.float(), mask.bool()))
    return torch.cat(out)


def train_length_estimator(train: tuple[torch.Tensor, np.ndarray], config: LengthConfig, *, steps: int = 2000,
                           batch_size: int = 256, lr: float = 1e-3, weight_decay: float = 0.01,
                           seed: int = 0) -> LengthEstimator:
    """Fit the estimator on (sentence embeddings (N, C), lengths (N,)) with cross-entropy over the bins."""
    emb, lengths = train
    target = torch.from_numpy(config.bin_of(lengths)).long()
    torch.manual_seed(seed)
    model = LengthEstimator(config)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=weight_decay)
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
    """Mean absolute error (frames) of the estimator and of a constant ``baseline`` on (emb, lengths)."""
    pred = model.predict_frames(emb).numpy()
    mae, base = float(np.abs(pred - lengths).mean()), float(np.abs(baseline - lengths).mean())
    return {"mae_frames": mae, "baseline_mae_frames": base, "reduction": 1 - mae / base, "pairs": int(len(lengths))}
