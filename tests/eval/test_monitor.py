"""A training run's self-evaluation: probe accuracy and FID of a checkpoint, as `smf train --eval-every` uses it."""

import json

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.data.labels import corpus_labels
from stablemofusion.core.errors import SMFError
from stablemofusion.eval.monitor import MonitorConfig, TrainingMonitor


def test_monitor_measures_a_checkpoint(eval_corpus, classifier_dir, evaluator_dir, save_tiny_checkpoint, tmp_path):
    import torch

    torch.set_num_threads(1)
    labels = corpus_labels(eval_corpus)
    probe = tmp_path / "probe.jsonl"
    lines = [{"prompt": f"a person does {v.content}", "content": v.content, "style": v.style, "dataset": v.dataset}
             for v in list(labels.values())[:3]]
    probe.write_text("".join(json.dumps(d) + "\n" for d in lines))
    run = tmp_path / "run"
    mean, std = np.load(eval_corpus / "Mean.npy"), np.load(eval_corpus / "Std.npy")
    save_tiny_checkpoint(run / "checkpoint", mean, std)
    monitor = TrainingMonitor(eval_corpus, MonitorConfig(probe, classifier_dir, evaluator_dir, fid_items=8,
                                                         batch_size=4, split="test"))
    figures = monitor(run, 10)
    assert figures["guidance"] == 2.5  # the tiny model names no scale: the package's fallback
    assert 0 <= figures["probe_all_content_acc"] <= 1 and 0 <= figures["probe_all_style_acc"] <= 1
    assert {f"probe_dataset-{v.dataset}_content_acc" for v in list(labels.values())[:3]} <= set(figures)
    assert np.isfinite(figures["val_fid"]) and 0 <= figures["val_top3"] <= 1
    with pytest.raises(SMFError, match="no such classifier"):
        TrainingMonitor(eval_corpus, MonitorConfig(probe, tmp_path / "none"))


def test_monitor_samples_at_the_guidance_it_is_given(eval_corpus, classifier_dir, evaluator_dir,
                                                     save_tiny_checkpoint, tmp_path, monkeypatch):
    import torch

    from stablemofusion.backends.torch_backend import TorchBackend
    from stablemofusion.pipelines.motion_pipeline import MotionPipeline

    torch.set_num_threads(1)
    labels = corpus_labels(eval_corpus)
    probe = tmp_path / "probe.jsonl"
    v = next(iter(labels.values()))
    probe.write_text(json.dumps({"prompt": "a person moves", "content": v.content, "style": v.style,
                                 "dataset": v.dataset}) + "\n")
    run = tmp_path / "run"
    save_tiny_checkpoint(run / "checkpoint", np.load(eval_corpus / "Mean.npy"), np.load(eval_corpus / "Std.npy"))
    seen = {"__call__": [], "denoise": []}
    owner = {"__call__": MotionPipeline, "denoise": TorchBackend}  # the task's call, the backend's batch call

    def spy(name):
        method = getattr(owner[name], name)

        def wrapped(self, *args, **kwargs):
            seen[name].append(kwargs.get("guidance_scale"))
            return method(self, *args, **kwargs)
        return wrapped

    for name in seen:
        monkeypatch.setattr(owner[name], name, spy(name))
    monitor = TrainingMonitor(eval_corpus, MonitorConfig(probe, classifier_dir, evaluator_dir, fid_items=4,
                                                         batch_size=4, split="test", guidance=1.0))
    figures = monitor(run, 10)
    assert figures["guidance"] == 1.0
    assert set(seen["__call__"]) == {1.0} and set(seen["denoise"]) == {1.0}  # probe and FID samples alike


def test_train_rejects_a_bad_eval_guidance(eval_corpus, tmp_path, capsys):
    code = main(["train", "--data", str(eval_corpus), "--out", str(tmp_path / "r"), "--preset", "tiny",
                 "--eval-every", "5", "--probe", str(tmp_path / "p.jsonl"), "--classifier", str(tmp_path),
                 "--eval-guidance", "-1", "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and "--eval-guidance" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "r").exists()


def test_train_needs_a_probe_and_classifier_to_evaluate(eval_corpus, tmp_path, capsys):
    code = main(["train", "--data", str(eval_corpus), "--out", str(tmp_path / "r"), "--preset", "tiny",
                 "--eval-every", "5", "--no-progress"])
    assert code == 2 and "--eval-every N needs" in capsys.readouterr().err
