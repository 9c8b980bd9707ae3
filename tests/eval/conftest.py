"""A mini corpus of real Bandai-Namco clips whose every split holds every motion, and tiny models."""

import numpy as np
import pytest

from stablemofusion.data.corpus_bandai import build_corpus


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
def tiny_checkpoint(eval_corpus, tmp_path_factory, save_tiny_checkpoint):
    """A 'tiny' random-weight denoiser with the corpus's Mean/Std."""
    mean, std = np.load(eval_corpus / "Mean.npy"), np.load(eval_corpus / "Std.npy")
    return save_tiny_checkpoint(tmp_path_factory.mktemp("eval-ckpt") / "checkpoint", mean, std + 1e-2)


@pytest.fixture(scope="session")
def classifier_dir(eval_corpus, tmp_path_factory):
    """A motion classifier trained briefly on the mini corpus (good enough to tell its clips apart)."""
    import torch

    from stablemofusion.eval.classifier import ClassifierTrainConfig, train_classifier

    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("classifier") / "cl"
    train_classifier(eval_corpus, out, ClassifierTrainConfig(steps=60, batch_size=16), progress=False)
    return out


@pytest.fixture(scope="session")
def evaluator_dir(eval_corpus, tmp_path_factory):
    """A small random-weight evaluator for the mini corpus (the protocol's arithmetic, not its meaning)."""
    import torch

    from stablemofusion.data.dataset import MotionTextDataset
    from stablemofusion.eval.evaluator import Evaluator, EvaluatorConfig, save_evaluator

    torch.manual_seed(0)
    ds = MotionTextDataset(eval_corpus, "train", feat_bias=1.0)
    ev = Evaluator(EvaluatorConfig(conv_dim=32, motion_hidden=32, text_hidden=32, out_dim=16), ds.mean, ds.std)
    path = tmp_path_factory.mktemp("ev") / "evaluator"
    save_evaluator(path, ev, {"text_encoder": "minilm"})
    return path
