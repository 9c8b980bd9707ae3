"""A motion classifier for labelled corpora: content and style labels from motion features.

It measures prompt following where the evaluator cannot: a generated motion is "right" when the
classifier, trained on the corpus's real train-split motions, gives it the label the prompt asked for.
Labels come from the corpus's ``clips.csv`` (id, dataset, content, style; a mirrored ``M`` id takes the
mirrored content). A label is chosen among those of the prompt's dataset (``allowed``), since synonymous
labels of two datasets (old / elderly) describe the same motions.

Model: three strided 1-D convolutions over normalised features, masked mean+max pooling, two linear heads.
"""

from __future__ import annotations

import json
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..data.dataset import MotionTextDataset
from ..data.labels import LabelInfo, corpus_labels
from ..core.errors import SMFError
from ..core.io import write_text

WEIGHTS = "classifier.safetensors"
CONFIG = "classifier.json"


@dataclass
class ClassifierConfig:
    motion_dim: int = 263
    width: int = 128
    dropout: float = 0.2
    contents: tuple[str, ...] = ()
    styles: tuple[str, ...] = ()


class MotionClassifier(nn.Module):
    """(B, T, D) normalised features, lengths (B,) -> (content logits (B, C), style logits (B, S))."""

    def __init__(self, cfg: ClassifierConfig, mean: np.ndarray, std: np.ndarray):
        super().__init__()
        self.cfg = cfg
        w = cfg.width
        self.convs = nn.ModuleList([nn.Conv1d(cfg.motion_dim, w, 5, padding=2), nn.Conv1d(w, w, 5, stride=2, padding=2),
                                    nn.Conv1d(w, 2 * w, 5, stride=2, padding=2)])
        self.drop = nn.Dropout(cfg.dropout)
        self.content = nn.Linear(4 * w, len(cfg.contents))
        self.style = nn.Linear(4 * w, len(cfg.styles))
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(std, dtype=torch.float32))

    def forward(self, x: torch.Tensor, lengths: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mask = (torch.arange(x.shape[1], device=x.device)[None] < lengths[:, None]).float()[:, None]  # (B, 1, T)
        h = x.transpose(1, 2) * mask
        for conv in self.convs:
            h = F.gelu(conv(h))
            if conv.stride[0] > 1:
                mask = F.max_pool1d(mask, 2, ceil_mode=True)[..., :h.shape[-1]]
            h = h * mask
        mean = h.sum(-1) / mask.sum(-1).clamp(min=1)
        peak = h.masked_fill(mask == 0, -1e4).amax(-1)
        z = self.drop(torch.cat([mean, peak], 1))
        return self.content(z), self.style(z)

    @torch.no_grad()
    def probabilities(self, features: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Raw features [(n_i, D)] in dataset units -> (content probs (B, C), style probs (B, S))."""
        self.eval()
        T = max(len(f) for f in features)
        x = torch.zeros(len(features), T, self.cfg.motion_dim)
        for i, f in enumerate(features):
            x[i, :len(f)] = (torch.as_tensor(np.asarray(f), dtype=torch.float32) - self.mean) / self.std
        lengths = torch.tensor([len(f) for f in features])
        c, s = self(x, lengths)
        return c.softmax(-1).numpy(), s.softmax(-1).numpy()

    def predict(self, features: Sequence[np.ndarray], allowed: Sequence[tuple[Sequence[str], Sequence[str]]] | None = None,
                batch: int = 128) -> list[tuple[str, str]]:
        """(content, style) per motion; ``allowed[i]`` = (contents, styles) to choose among (empty = all)."""
        out = []
        for a in range(0, len(features), batch):
            pc, ps = self.probabilities(features[a:a + batch])
            for j in range(len(pc)):
                cs, ss = allowed[a + j] if allowed is not None else ((), ())
                out.append((_argmax(pc[j], self.cfg.contents, cs), _argmax(ps[j], self.cfg.styles, ss)))
        return out


def _argmax(p: np.ndarray, labels: Sequence[str], allowed: Sequence[str]) -> str:
    keep = np.array([not allowed or lab in allowed for lab in labels])
    if not keep.any():
        raise SMFError(f"none of the labels {list(allowed)} is known to the classifier")
    return labels[int(np.argmax(np.where(keep, p, -1.0)))]


def label_accuracy(predicted: Sequence[tuple[str, str]], wanted: Sequence[tuple[Sequence[str], Sequence[str] | None]]
                   ) -> dict[str, float]:
    """Fraction of motions whose predicted content is among the wanted contents (and style, where one is
    wanted). Returns {"content_acc", "style_acc", "n", "n_style"}."""
    c_ok = [p[0] in w[0] for p, w in zip(predicted, wanted)]
    s_ok = [p[1] in w[1] for p, w in zip(predicted, wanted) if w[1]]
    return {"content_acc": float(np.mean(c_ok)) if c_ok else float("nan"),
            "style_acc": float(np.mean(s_ok)) if s_ok else float("nan"), "n": len(c_ok), "n_style": len(s_ok)}


def dataset_labels(labels: dict[str, LabelInfo], dataset: int) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(contents, styles) that occur in one dataset of the corpus."""
    rows = [v for v in labels.values() if v.dataset == dataset]
    return tuple(sorted({r.content for r in rows})), tuple(sorted({r.style for r in rows}))


@dataclass
class ClassifierTrainConfig:
    steps: int = 3000
    batch_size: int = 64
    lr: float = 1e-3
    weight_decay: float = 0.01
    seed: int = 0


def _split_items(ds: MotionTextDataset, labels: dict[str, LabelInfo], cfg: ClassifierConfig):
    c_index = {c: i for i, c in enumerate(cfg.contents)}
    s_index = {s: i for i, s in enumerate(cfg.styles)}
    keep = [i for i, mid in enumerate(ds.ids) if mid in labels]
    return ([ds.motions[i] for i in keep], np.array([c_index[labels[ds.ids[i]].content] for i in keep]),
            np.array([s_index[labels[ds.ids[i]].style] for i in keep]), [ds.ids[i] for i in keep])


def _crop_batch(motions, idx, rng, min_len: int):
    lens = []
    crops = []
    for i in idx:
        m = motions[i]
        n = int(rng.integers(min(min_len, len(m)), len(m) + 1))
        a = int(rng.integers(0, len(m) - n + 1))
        crops.append(m[a:a + n])
        lens.append(n)
    x = torch.zeros(len(idx), max(lens), motions[0].shape[1])
    for j, c in enumerate(crops):
        x[j, :len(c)] = torch.from_numpy(c)
    return x, torch.tensor(lens)


def real_accuracy(model: MotionClassifier, data: str | Path, split: str, labels: dict[str, LabelInfo]) -> dict:
    """The classifier's own accuracy on a split's real motions (whole motions), per dataset, labels chosen
    among the motion's dataset's labels."""
    ds = MotionTextDataset(data, split, feat_bias=1.0)
    feats = [ds.denormalize(m) for m in ds.motions]
    out = {}
    for d in sorted({labels[m].dataset for m in ds.ids if m in labels}):
        sel = [i for i, m in enumerate(ds.ids) if m in labels and labels[m].dataset == d]
        allowed = dataset_labels(labels, d)
        pred = model.predict([feats[i] for i in sel], [allowed] * len(sel))
        want = [((labels[ds.ids[i]].content,), (labels[ds.ids[i]].style,)) for i in sel]
        out[f"dataset-{d}"] = label_accuracy(pred, want)
    return out


def train_classifier(data: str | Path, out: str | Path, cfg: ClassifierTrainConfig = ClassifierTrainConfig(),
                     progress: bool = True) -> dict:
    """Train on the train split's real motions (random crops >= 40 frames); save to ``out``; returns a
    summary with the accuracy on the val and test splits."""
    from safetensors.torch import save_file
    from tqdm import tqdm

    labels = corpus_labels(data)
    ds = MotionTextDataset(data, "train", feat_bias=1.0)
    mcfg = ClassifierConfig(motion_dim=int(ds.mean.shape[0]), contents=tuple(sorted({v.content for v in labels.values()})),
                            styles=tuple(sorted({v.style for v in labels.values()})))
    torch.manual_seed(cfg.seed)
    model = MotionClassifier(mcfg, ds.mean, ds.std)
    motions, yc, ys, _ = _split_items(ds, labels, mcfg)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.steps)
    rng = np.random.default_rng(cfg.seed)
    t0 = time.perf_counter()
    for step in tqdm(range(cfg.steps), desc="classifier", disable=not progress):
        idx = rng.integers(0, len(motions), cfg.batch_size)
        x, lens = _crop_batch(motions, idx, rng, ds.min_frames)
        x = x + 0.05 * torch.randn_like(x)
        model.train()
        c, s = model(x, lens)
        loss = F.cross_entropy(c, torch.from_numpy(yc[idx])) + F.cross_entropy(s, torch.from_numpy(ys[idx]))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    model.eval()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    summary = {"config": asdict(mcfg), "train": asdict(cfg), "seconds": time.perf_counter() - t0,
               "accuracy": {split: real_accuracy(model, data, split, labels) for split in ("val", "test")}}
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(out / WEIGHTS))
    write_text(out / CONFIG, json.dumps(summary, indent=2) + "\n")
    return summary


def load_classifier(path: str | Path) -> MotionClassifier:
    from safetensors.torch import load_file

    path = Path(path)
    if not (path / WEIGHTS).is_file() or not (path / CONFIG).is_file():
        raise SMFError(f"{path}: not a classifier folder (from `smf train-classifier`)")
    meta = json.loads((path / CONFIG).read_text())
    c = meta["config"]
    cfg = ClassifierConfig(c["motion_dim"], c["width"], c["dropout"], tuple(c["contents"]), tuple(c["styles"]))
    state = load_file(str(path / WEIGHTS))
    model = MotionClassifier(cfg, state["mean"].numpy(), state["std"].numpy())
    model.load_state_dict(state)
    return model.eval()


__all__ = ["ClassifierConfig", "ClassifierTrainConfig", "LabelInfo", "MotionClassifier", "corpus_labels",
           "dataset_labels", "label_accuracy", "load_classifier", "real_accuracy", "train_classifier"]
