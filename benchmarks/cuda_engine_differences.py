"""Largest |difference| of each engine's raw features from the `fast` engine's on a CUDA device, for 1 and 10
sampling steps (the tiny random model of tests/diffusion/test_sampling.py's CUDA test). It chose that test's
tolerance: `python benchmarks/cuda_engine_differences.py` (needs CUDA; results/h100/)."""
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import _save_tiny_checkpoint
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
path = _save_tiny_checkpoint(Path(tempfile.mkdtemp()) / "c", np.zeros(263), np.full(263, 0.1))
p = MotionPipeline.from_pretrained(path, device="cuda", dtype=torch.float32)
prompts, lengths = ["a person walks forward", "a person waves", "a person bows"], [40, 57, 196]
for steps in (1, 10):
    a = p.denoise(prompts, lengths, steps=steps, seed=[1, 2, 3], engine="fast")
    e = p.denoise(prompts, lengths, steps=steps, seed=[1, 2, 3], engine="eager")
    print("steps", steps, "eager vs fast", (a - e).abs().max().item(), "scale", a.abs().max().item(), flush=True)
    for engine in ["graph", "compiled", "compiled-graph"]:
        b = p.denoise(prompts, lengths, steps=steps, seed=[1, 2, 3], engine=engine)
        d = (a - b).abs()
        print("steps", steps, engine, "max", d.max().item(), "p99", d.flatten().quantile(0.99).item() if d.numel() < 2**24 else None, flush=True)
