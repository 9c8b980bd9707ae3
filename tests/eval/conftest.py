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
