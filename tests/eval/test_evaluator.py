"""Evaluator networks, contrastive training on real clips, save/load."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.data.dataset import MotionTextDataset
from stablemofusion.core.errors import SMFError
from stablemofusion.eval.evaluator import Evaluator, EvaluatorConfig, load_evaluator, save_evaluator
from stablemofusion.eval.train_evaluator import EvaluatorTrainConfig, contrastive_loss, embed_split, train_evaluator
from stablemofusion.text.cache import TextEmbeddingCache

SMALL = EvaluatorConfig(conv_dim=32, motion_hidden=32, text_hidden=32, out_dim=16)


def test_motion_embedding_ignores_padding_and_contacts():
    torch.manual_seed(0)
    ev = Evaluator(SMALL).eval()
    x = torch.randn(2, 48, 263)
    y = x.clone()
    y[0, 40:] = 1e3  # garbage beyond the length
    y[:, :, -4:] = 7.0  # foot contacts are not seen
    a = ev.embed_motion(x, [40, 48])
    b = ev.embed_motion(y, [40, 48])
    assert a.shape == (2, 16)
    torch.testing.assert_close(a, b)
    with pytest.raises(SMFError, match="263-dim"):
        ev.embed_motion(torch.zeros(1, 8, 251), [8])


def test_contrastive_loss_prefers_matched_pairs_and_skips_duplicates():
    t = torch.eye(4) * 5
    same = torch.zeros(4, 4, dtype=torch.bool)
    matched = contrastive_loss(t, t, same, 1.0)
    assert matched < contrastive_loss(t, t.roll(1, 0), same, 1.0)
    same[0, 1] = same[1, 0] = True  # 0 and 1 share a caption: pairing 0 with 1's motion is not penalised
    swapped = t.clone()
    swapped[[0, 1]] = swapped[[1, 0]]
    assert contrastive_loss(t, swapped, same, 1.0) < contrastive_loss(t, swapped, torch.zeros_like(same), 1.0)


def test_save_load_roundtrip(tmp_path):
    ev = Evaluator(SMALL, np.arange(263.0), np.full(263, 2.0))
    save_evaluator(tmp_path / "ev", ev, {"text_encoder": "minilm"})
    ev2, cfg = load_evaluator(tmp_path / "ev")
    assert cfg["text_encoder"] == "minilm" and ev2.config == ev.config
    x = torch.randn(1, 20, 263)
    torch.testing.assert_close(ev.eval().embed_motion(x, [20]), ev2.embed_motion(x, [20]))
    with pytest.raises(SMFError, match="not an evaluator folder"):
        load_evaluator(tmp_path)


def test_training_on_real_clips_separates_them(eval_corpus, eval_text_cache, tmp_path):
    torch.set_num_threads(1)
    cfg = EvaluatorTrainConfig(steps=160, batch_size=8, lr=2e-3, eval_every=1000)
    meta = train_evaluator(eval_corpus, tmp_path / "ev", cfg, progress=False, text_cache=eval_text_cache,
                           model_cfg=EvaluatorConfig(conv_dim=48, motion_hidden=48, text_hidden=48, out_dim=32))
    assert np.isfinite(meta["final_loss"]) and meta["steps"] == 160
    ev, _ = load_evaluator(tmp_path / "ev")
    ds = MotionTextDataset(eval_corpus, "test", seed=1, feat_bias=1.0)
    with TextEmbeddingCache(eval_text_cache, "minilm") as cache:
        t, m = embed_split(ev, ds, cache)
    d = np.linalg.norm(t[:, None] - m[None], axis=-1)
    own = np.diag(d).mean()
    other = d[~np.eye(len(d), dtype=bool)].mean()
    assert own < 0.7 * other  # a caption is nearer its own motion than others on average
    assert (d.argmin(1) == np.arange(len(d))).mean() > 2 / len(d)  # top-1 well above chance


def test_cli_train_evaluator_bad_input(tmp_path, capsys):
    assert main(["train-evaluator", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "ev")]) == 2
    assert "smf: error" in capsys.readouterr().err
