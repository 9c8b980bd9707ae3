"""Training on real corpus clips: the loss goes down, and a killed run resumes exactly."""

import json

import numpy as np
import pytest
import torch

from stablemofusion.cli.main import main
from stablemofusion.diffusion.checkpoint import load_checkpoint
from stablemofusion.diffusion.train import TrainConfig, masked_mse, train
from stablemofusion.core.errors import SMFError


@pytest.fixture(scope="module")
def corpus(bandai_mini_corpus):
    return bandai_mini_corpus


@pytest.fixture(scope="module")
def text_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("text-cache")  # shared: MiniLM runs once for all tests here


def test_tiny_model_lowers_its_loss(corpus, text_cache, tmp_path):
    cfg = TrainConfig(preset="tiny", steps=60, batch_size=8, lr=2e-3, checkpoint_every=60, min_frames=16)
    losses = train(corpus, tmp_path / "run", cfg, progress=False, text_cache=text_cache)
    assert len(losses) == 60
    assert np.mean(losses[-10:]) < 0.9 * np.mean(losses[:10])  # 1.95 -> 1.59 when written
    ck = load_checkpoint(tmp_path / "run")  # the run folder resolves to its checkpoint/
    assert ck.config.step == 60 and ck.config.model.arch == "unet" and ck.config.text_encoder == "minilm"
    log = (tmp_path / "run" / "log.csv").read_text().splitlines()
    assert log[0] == "step,loss,lr,seconds,samples_per_s" and len(log) == 61


def test_killed_run_resumes_exactly(corpus, text_cache, tmp_path):
    args = ["train", "--data", corpus, "--out", None, "--preset", "tiny", "--steps", "12", "--batch-size", "4",
            "--checkpoint-every", "4", "--min-frames", "16", "--lr-decay-every", "5", "--text-cache", text_cache,
            "--no-progress"]

    def run(out, *extra):
        a = [str(out) if x is None else str(x) for x in args] + list(extra)
        assert main(a) == 0
        return [float(r.split(",")[1]) for r in (out / "log.csv").read_text().splitlines()[1:]]

    full = run(tmp_path / "full")
    part = run(tmp_path / "part", "--stop-after", "8")  # killed after the step-8 checkpoint
    assert len(part) == 8 and json.loads((tmp_path / "part" / "checkpoint" / "config.json").read_text())["step"] == 8
    resumed = run(tmp_path / "part", "--resume")
    assert resumed == full  # the same 12 losses, bit for bit
    a = load_checkpoint(tmp_path / "full").model.state_dict()
    b = load_checkpoint(tmp_path / "part").model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_a_resumed_run_can_be_extended_with_new_optimisation_settings(corpus, text_cache, tmp_path, capsys):
    out = tmp_path / "run"
    base = ["train", "--data", str(corpus), "--out", str(out), "--preset", "tiny", "--batch-size", "4",
            "--min-frames", "16", "--text-cache", str(text_cache), "--no-progress"]
    assert main(base + ["--steps", "4", "--checkpoint-every", "2"]) == 0
    assert main(base + ["--steps", "6", "--checkpoint-every", "3", "--lr", "1e-3", "--resume"]) == 0
    log = (out / "log.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in log] == [1, 2, 3, 4, 5, 6]
    assert float(log[3].split(",")[2]) == pytest.approx(2e-4) and float(log[5].split(",")[2]) == pytest.approx(1e-3)
    ck = load_checkpoint(out)
    assert ck.config.step == 6 and ck.config.train.lr == 1e-3 and ck.config.train.steps == 6
    # the architecture must match
    assert main(base + ["--steps", "8", "--preset", "small", "--resume"]) == 2
    assert "differs from the saved one in model" in capsys.readouterr().err


def test_resume_needs_a_checkpoint(tmp_path, corpus, capsys):
    code = main(["train", "--data", str(corpus), "--out", str(tmp_path / "none"), "--preset", "tiny", "--resume",
                 "--no-progress"])
    assert code == 2 and "cannot resume" in capsys.readouterr().err


def test_masked_mse_ignores_padding():
    pred, target = torch.zeros(1, 4, 3), torch.ones(1, 4, 3)
    target[0, 2:] = 100.0
    mask = torch.tensor([[True, True, False, False]])
    assert masked_mse(pred, target, mask).item() == pytest.approx(1.0)


def test_init_from_starts_from_those_weights(corpus, text_cache, tmp_path):
    base = TrainConfig(preset="tiny", steps=3, batch_size=4, checkpoint_every=3, min_frames=16)
    train(corpus, tmp_path / "base", base, progress=False, text_cache=text_cache)
    # lr 0: the fine-tuned model's weights stay exactly the ones it started from
    tuned = TrainConfig(preset="tiny", steps=1, batch_size=4, checkpoint_every=1, min_frames=16, lr=0.0,
                        init_from=str(tmp_path / "base"))
    train(corpus, tmp_path / "tuned", tuned, progress=False, text_cache=text_cache)
    a = load_checkpoint(tmp_path / "base").model.state_dict()  # EMA weights of the base run
    b = load_checkpoint(tmp_path / "tuned", ema=False).model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    bad = TrainConfig(preset="dit", steps=1, batch_size=4, min_frames=16, init_from=str(tmp_path / "base"))
    with pytest.raises(SMFError, match="do not fit this model"):
        train(corpus, tmp_path / "bad", bad, progress=False, text_cache=text_cache)


def test_text_augmentation_encodes_perturbed_captions_afresh(corpus, text_cache, tmp_path):
    import random

    from stablemofusion.data.augment import augment_caption
    from stablemofusion.diffusion.train import _augmented_text, _synonyms
    from stablemofusion.text.cache import TextEmbeddingCache
    from stablemofusion.text.frozen import load_text_encoder

    synonyms = _synonyms(corpus)  # the corpus names its lexicon in stats.json
    assert synonyms["tired"] and "weary" in synonyms["tired"]
    encoder = load_text_encoder("minilm")
    cache = TextEmbeddingCache(text_cache, encoder)
    captions = ["A tired man walks forward slowly.", "Someone waves the left hand happily."]
    cfg = TrainConfig(text_augment=1.0)
    tokens, mask = _augmented_text(captions, cache, encoder, cfg, synonyms, seed=5, device="cpu")
    rng = random.Random(5)
    texts = [augment_caption(c, rng, synonyms) if rng.random() < 1.0 else c for c in captions]
    assert texts != captions
    want, want_mask = encoder.encode(texts)
    assert torch.equal(mask, want_mask) and torch.allclose(tokens, want, atol=1e-5)
    losses = train(corpus, tmp_path / "aug", TrainConfig(preset="tiny", steps=2, batch_size=4, checkpoint_every=2,
                                                         min_frames=16, text_augment=0.5),
                   progress=False, text_cache=text_cache)
    assert len(losses) == 2 and all(np.isfinite(losses))


def test_learning_rate_schedules():
    from stablemofusion.diffusion.train import learning_rate

    step = TrainConfig(lr=1e-3, lr_decay=0.5, lr_decay_every=10)
    assert [learning_rate(step, s) for s in (0, 9, 10, 25)] == pytest.approx([1e-3, 1e-3, 5e-4, 2.5e-4])
    warm = TrainConfig(lr=1e-3, warmup=4, lr_schedule="cosine", steps=104, min_lr=1e-4)
    assert learning_rate(warm, 0) == pytest.approx(2.5e-4) and learning_rate(warm, 3) == pytest.approx(1e-3)
    assert learning_rate(warm, 54) == pytest.approx(5.5e-4) and learning_rate(warm, 104) == pytest.approx(1e-4)
    wsd = TrainConfig(lr=1e-3, lr_schedule="wsd", steps=100, decay_steps=20, min_lr=0.0)
    assert learning_rate(wsd, 79) == pytest.approx(1e-3) and learning_rate(wsd, 90) == pytest.approx(5e-4)
    assert learning_rate(wsd, 100) == pytest.approx(0.0)
    with pytest.raises(SMFError, match="lr-schedule"):
        from stablemofusion.diffusion.train import check_train_config

        check_train_config(TrainConfig(lr_schedule="linear"))
    with pytest.raises(SMFError, match="time-warp"):
        check_train_config(TrainConfig(time_warp=1.5))


def test_label_balance_repeats_rare_labels_with_distinct_crops(corpus):
    from collections import Counter

    from stablemofusion.data.batches import _draws, label_repeats
    from stablemofusion.data.dataset import MotionTextDataset
    from stablemofusion.diffusion.train import label_balance

    assert label_repeats(["a"] * 8 + ["b"] * 2, 1.0, 16) == (1,) * 8 + (4, 4)
    assert label_repeats(["a"] * 8 + ["b"] * 2, 0.5, 16) == (1,) * 8 + (2, 2)
    assert label_repeats(["a"] * 100 + ["b"], 1.0, 16)[-1] == 16  # capped
    ds = MotionTextDataset(corpus, "train", seed=0, min_frames=16)
    repeats = label_balance(corpus, ds, 1.0)
    assert len(repeats) == len(ds) and max(repeats) > 1
    draws = _draws(0, sum(repeats), len(ds), 0, None, 0, repeats)  # one whole epoch
    assert Counter(i for _, i, _ in draws) == {i: r for i, r in enumerate(repeats)}
    i = repeats.index(max(repeats))
    crops = set()
    for c in range(repeats[i]):
        ds.set_epoch(0, c)
        item = ds[i]
        crops.add((item["frames"], item["caption"]))
    assert len(crops) > 1  # each copy is its own draw of crop and caption
    assert label_balance(corpus, ds, 0.0) is None


def test_time_warp_contents_tempo_free_slows_only_the_lexicons_gestures(corpus):
    """warpable_items: None for "all"; for "tempo-free" exactly the items whose content the lexicon lists (mirrored
    labels too: wave-right-hand with wave-left-hand), never run or walk; get_batch slows only those items."""
    from stablemofusion.data.batches import batch_warp, get_batch
    from stablemofusion.data.dataset import MotionTextDataset
    from stablemofusion.data.labels import corpus_labels
    from stablemofusion.data.lexicon import load_lexicon
    from stablemofusion.diffusion.train import warpable_items

    free = load_lexicon("bandai").tempo_free
    assert {"wave-left-hand", "wave-right-hand", "raise-up-right-hand", "bow"} <= free
    assert not free & {"run", "walk", "dash", "walk-turn-left", "kick"}
    ds = MotionTextDataset(corpus, "train", seed=0, min_frames=16)
    labels = corpus_labels(corpus)
    flags = warpable_items(corpus, ds, "tempo-free")
    assert warpable_items(corpus, ds, "all") is None and len(flags) == len(ds) and any(flags) and not all(flags)
    assert flags == tuple(labels[ds.ids[e.index]].content in free for e in ds.entries)
    step = next(s for s in range(50) if batch_warp(s, 0, 1.0) > 1.2)
    batch = get_batch(ds, step, 16, 0, time_warp=1.0, warpable=flags)
    slowed = [labels[i].content in free for i in batch["id"]]
    assert any(slowed) and not all(slowed)
    assert [w > 1.0 for w in batch["warp"].tolist()] == slowed
    with pytest.raises(SMFError, match="time-warp-contents"):
        from stablemofusion.diffusion.train import check_train_config

        check_train_config(TrainConfig(time_warp=0.3, time_warp_contents="slow"))


def test_self_evaluation_goes_into_eval_jsonl_and_the_curve(corpus, text_cache, tmp_path):
    calls = []

    def on_eval(run, step):
        calls.append((run, step))
        return {"probe_all_content_acc": 0.1 * step, "val_fid": 10.0 / step}

    cfg = TrainConfig(preset="tiny", steps=6, batch_size=4, checkpoint_every=6, min_frames=16)
    losses = train(corpus, tmp_path / "run", cfg, progress=False, text_cache=text_cache, eval_every=3, on_eval=on_eval)
    plain = train(corpus, tmp_path / "plain", cfg, progress=False, text_cache=text_cache)
    assert losses == plain  # evaluating does not change training
    assert calls == [(tmp_path / "run", 3), (tmp_path / "run", 6)]
    rows = [json.loads(r) for r in (tmp_path / "run" / "eval.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [3, 6] and rows[1]["val_fid"] == pytest.approx(10 / 6)
    log = (tmp_path / "run" / "log.csv").read_text().splitlines()
    assert all(float(r.split(",")[4]) > 0 for r in log[1:])  # samples/s
    out = tmp_path / "curve.png"
    assert main(["curve", str(tmp_path / "run"), "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert main(["curve", str(tmp_path / "nothing"), "--out", str(out)]) == 2
    assert main(["curve", str(tmp_path / "run"), "--out", str(tmp_path / "curve.jpg")]) == 2


def test_curve_compares_runs(tmp_path, capsys):
    for name, acc in (("a", 0.4), ("b", 0.5)):
        run = tmp_path / name
        run.mkdir()
        (run / "log.csv").write_text("step,loss,lr,seconds,samples_per_s\n1,0.5,1e-4,1.0,64\n")
        (run / "eval.jsonl").write_text("".join(json.dumps({"step": s, "train_seconds": 3600.0 * s,
                                                            "probe_all_content_acc": acc * s, "val_fid": 2.0 / s})
                                                + "\n" for s in (1, 2)))
    out = tmp_path / "compare.png"
    assert main(["curve", str(tmp_path / "a"), str(tmp_path / "b"), "--label", "arm A", "--label", "arm B",
                 "--out", str(out)]) == 0
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    table = [x for x in capsys.readouterr().out.splitlines() if x.startswith("| arm")]
    assert table == ["| arm A | 1 | 1.00 | 0.400 | - | - | 2.000 |", "| arm A | 2 | 2.00 | 0.800 | - | - | 1.000 |",
                     "| arm B | 1 | 1.00 | 0.500 | - | - | 2.000 |", "| arm B | 2 | 2.00 | 1.000 | - | - | 1.000 |"]
    assert main(["curve", str(tmp_path / "a"), str(tmp_path / "b"), "--label", "x", "--out", str(out)]) == 2
