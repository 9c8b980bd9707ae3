"""A training run's self-evaluation: probe accuracy and FID of a checkpoint, as `smf train --eval-every` uses it."""

import json

import numpy as np
import pytest

from stablemofusion.cli.main import main
from stablemofusion.data.labels import corpus_labels
from stablemofusion.errors import SMFError
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
    assert 0 <= figures["probe_all_content_acc"] <= 1 and 0 <= figures["probe_all_style_acc"] <= 1
    assert {f"probe_dataset-{v.dataset}_content_acc" for v in list(labels.values())[:3]} <= set(figures)
    assert np.isfinite(figures["val_fid"]) and 0 <= figures["val_top3"] <= 1
    with pytest.raises(SMFError, match="no such classifier"):
        TrainingMonitor(eval_corpus, MonitorConfig(probe, tmp_path / "none"))


def test_train_needs_a_probe_and_classifier_to_evaluate(eval_corpus, tmp_path, capsys):
    code = main(["train", "--data", str(eval_corpus), "--out", str(tmp_path / "r"), "--preset", "tiny",
                 "--eval-every", "5", "--no-progress"])
    assert code == 2 and "--eval-every N needs" in capsys.readouterr().err
