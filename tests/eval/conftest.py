"""A mini corpus of real Bandai-Namco clips whose every split holds every motion, and tiny models."""

import numpy as np
import pytest
import torch

from stablemofusion.data.corpus_bandai import build_corpus
from stablemofusion.diffusion.checkpoint import save_checkpoint
from stablemofusion.models.base import build_denoiser
from stablemofusion.models.presets import get_preset


@pytest.fixture(scope="session")
def eval_corpus(bandai_mini_source, tmp_path_factory):
    out = tmp_path_factory.mktemp("eval-corpus")
    build_corpus(bandai_mini_source, out, workers=1)
    ids = sorted(p.stem for p in (out / "new_joint_vecs").glob("*.npy"))
    for split in ("train", "val", "test"):
        (out / f"{split}.txt").write_text("\n".join(ids) + "\n")
    return out


@pytest.fixture(scope="session")
def eval_text_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("eval-text-cache")


@pytest.fixture(scope="session")
def tiny_checkpoint(eval_corpus, tmp_path_factory):
    """A 'tiny' random-weight denoiser with the corpus's Mean/Std, saved like a trained checkpoint."""
    torch.manual_seed(0)
    cfg = get_preset("tiny")
    cfg.options.update(base_dim=32, groups=4)
    model = build_denoiser(cfg)
    with torch.no_grad():
        for p in model.parameters():
            if p.abs().sum() == 0:
                p.normal_(0, 0.02)
    path = tmp_path_factory.mktemp("eval-ckpt") / "checkpoint"
    mean, std = np.load(eval_corpus / "Mean.npy"), np.load(eval_corpus / "Std.npy")
    save_checkpoint(path, model=model, mean=mean, std=std + 1e-2, ema_state=model.state_dict(),
                    config={"model": cfg.to_dict(), "text_encoder": "minilm", "skeleton": "humanml3d", "fps": 20.0,
                            "max_frames": 196, "min_frames": 40, "train": {}})
    return path
