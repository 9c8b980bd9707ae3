"""Median time of one denoiser forward (a CFG pair: batch 2) per preset, no grad.

Usage: python benchmarks/forward_speed.py [--frames 196] [--repeats 10] PRESET [PRESET ...]
"""

import argparse
import time

import torch

from stablemofusion.models.registry import build_denoiser
from stablemofusion.models.presets import get_preset

p = argparse.ArgumentParser()
p.add_argument("presets", nargs="+")
p.add_argument("--frames", type=int, default=196)
p.add_argument("--repeats", type=int, default=10)
a = p.parse_args()
for name in a.presets:
    torch.manual_seed(0)
    model = build_denoiser(get_preset(name)).eval()
    x, t = torch.randn(2, a.frames, 263), torch.tensor([10, 10])
    tok, tm = torch.randn(2, 12, model.text.proj.in_features), torch.ones(2, 12, dtype=torch.bool)
    times = []
    with torch.no_grad():
        model(x, t, tok, tm, None, None)
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            model(x, t, tok, tm, None, None)
            times.append(time.perf_counter() - t0)
    print(f"{name:<15} {model.num_parameters():>12,} params  median {sorted(times)[len(times) // 2] * 1000:8.1f} ms "
          f"({torch.get_num_threads()} threads)")
