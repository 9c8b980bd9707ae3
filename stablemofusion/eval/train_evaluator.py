"""Contrastive training of the text/motion evaluator on a corpus's train split.

Loss: symmetric InfoNCE over a batch with logits = -distance / temperature (the metrics use the same
Euclidean distance); pairs whose captions are identical, or which come from the same motion, are not
treated as negatives of each other. Every draw of step ``s`` is seeded from (seed, s).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ..data.dataset import MotionTextDataset
from ..data.batches import get_batch
from ..core.errors import SMFError
from .evaluator import Evaluator, EvaluatorConfig, save_evaluator
from .metrics import r_precision


@dataclass
class EvaluatorTrainConfig:
    """Optimisation settings of the evaluator (saved in its config.json)."""

    steps: int = 2000
    batch_size: int = 64
    lr: float = 2e-4
    weight_decay: float = 0.01
    temperature: float = 0.1
    grad_clip: float = 1.0
    seed: int = 0
    text_encoder: str = "minilm"
    max_frames: int | None = None  # None: the corpus skeleton's
    bucket: int = 0
    eval_every: int = 500


def contrastive_loss(text: torch.Tensor, motion: torch.Tensor, same: torch.Tensor, temperature: float) -> torch.Tensor:
    """Symmetric InfoNCE on -distance/temperature; ``same`` (B, B) bool marks off-diagonal pairs that are
    not negatives (identical captions or the same motion)."""
    logits = -torch.cdist(text, motion) / temperature
    eye = torch.eye(len(text), dtype=torch.bool, device=text.device)
    logits = logits.masked_fill(same & ~eye, float("-inf"))
    target = torch.arange(len(text), device=text.device)
    return 0.5 * (torch.nn.functional.cross_entropy(logits, target)
                  + torch.nn.functional.cross_entropy(logits.T, target))


def _same_pairs(batch: dict) -> torch.Tensor:
    caps, ids = batch["caption"], batch["id"]
    n = len(caps)
    return torch.tensor([[caps[i] == caps[j] or ids[i] == ids[j] for j in range(n)] for i in range(n)])


@torch.no_grad()
def embed_split(model: Evaluator, ds: MotionTextDataset, cache, *, epoch: int = 0, batch_size: int = 64
                ) -> tuple[np.ndarray, np.ndarray]:
    """(text, motion) embeddings of every item of ``ds`` in its order for ``epoch`` (crops seeded)."""
    model.eval()
    ds.set_epoch(epoch)
    texts, motions = [], []
    for a in range(0, len(ds), batch_size):
        items = [ds[i] for i in range(a, min(len(ds), a + batch_size))]
        T = max(it["length"] for it in items)
        x = torch.stack([it["motion"][:T] for it in items])
        lengths = torch.tensor([it["length"] for it in items])
        tokens, tmask = cache.get_or_compute([it["caption"] for it in items])
        motions.append(model.motion_encoder(x, lengths).numpy())
        texts.append(model.embed_text(tokens, tmask).numpy())
    return np.concatenate(texts), np.concatenate(motions)


def train_evaluator(data: str | Path, out: str | Path, cfg: EvaluatorTrainConfig, *, progress: bool = True,
                    text_cache: str | Path | None = None, model_cfg: EvaluatorConfig | None = None) -> dict:
    """Train an evaluator on ``data``'s train split, save it to ``out``; returns its validation figures."""
    from ..text.cache import TextEmbeddingCache
    from ..text.frozen import load_text_encoder

    out = Path(out)
    if cfg.steps < 1 or cfg.batch_size < 2:
        raise SMFError("evaluator training needs steps >= 1 and batch_size >= 2")
    ds = MotionTextDataset(data, "train", seed=cfg.seed, max_frames=cfg.max_frames, feat_bias=1.0)
    try:
        val = MotionTextDataset(data, "val", seed=cfg.seed + 1, max_frames=cfg.max_frames, feat_bias=1.0)
    except SMFError:
        val = None
    encoder = load_text_encoder(cfg.text_encoder)
    cache = TextEmbeddingCache(text_cache or (out.parent / f".{out.name}-text-cache"), encoder)
    mcfg = model_cfg or EvaluatorConfig()
    mcfg.motion_dim, mcfg.text_dim = int(ds.mean.shape[0]), int(encoder.dim)
    torch.manual_seed(cfg.seed)
    model = Evaluator(mcfg, ds.mean, ds.std)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    history: list[dict] = []
    t0 = time.perf_counter()

    def validate(step: int) -> None:
        if val is None or len(val) < 32:
            return
        t, m = embed_split(model, val, cache)
        top, match = r_precision(t, m)
        history.append({"step": step, "val_top1": float(top[0]), "val_top2": float(top[1]),
                        "val_top3": float(top[2]), "val_matching": match})
        model.train()

    bar = tqdm(range(cfg.steps), desc="evaluator", unit="step", disable=not progress)
    loss_value = float("nan")
    for step in bar:
        model.train()
        batch = get_batch(ds, step, cfg.batch_size, cfg.seed, cfg.bucket)
        tokens, tmask = cache.get_or_compute(batch["caption"])
        torch.manual_seed(cfg.seed * 1_000_003 + step)  # dropout
        tm = model.embed_text(tokens, tmask)
        mm = model.motion_encoder(batch["motion"], batch["length"])
        loss = contrastive_loss(tm, mm, _same_pairs(batch), cfg.temperature)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        loss_value = float(loss.detach())
        if not np.isfinite(loss_value):
            raise SMFError(f"evaluator training diverged at step {step}")
        bar.set_postfix(loss=f"{loss_value:.3f}")
        if (step + 1) % cfg.eval_every == 0 and step + 1 < cfg.steps:
            validate(step + 1)
    validate(cfg.steps)
    cache.flush()
    meta = {"train": asdict(cfg), "text_encoder": encoder.name, "skeleton": ds.skeleton.name, "steps": cfg.steps,
            "final_loss": loss_value, "seconds": round(time.perf_counter() - t0, 1), "validation": history,
            "data": str(Path(data).resolve().name)}
    save_evaluator(out, model.eval(), meta)
    cache.close()
    return meta


__all__ = ["EvaluatorTrainConfig", "train_evaluator", "contrastive_loss", "embed_split"]
