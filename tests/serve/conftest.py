"""Serve fixtures: a tiny random-weight checkpoint and its pipeline (helpers: serve_helpers.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory, save_tiny_checkpoint):
    mean, std = np.zeros(263), np.full(263, 0.1)
    mean[3] = 0.9
    return save_tiny_checkpoint(tmp_path_factory.mktemp("serve-ckpt") / "checkpoint", mean, std)


@pytest.fixture(scope="module")
def pipe(checkpoint):
    from stablemofusion.pipeline import MotionPipeline

    torch.set_num_threads(1)
    return MotionPipeline.from_pretrained(checkpoint, device="cpu")
