"""Training throughput (samples/s) of a preset on this machine: forward + backward + AdamW step.

Usage: python benchmarks/train_speed.py [--preset small] [--batch-size 64] [--steps 20] [--device cpu|cuda]
       [--bf16] [--compile] [--fused]   (what `smf train --mixed-precision bf16 --compile` uses on a GPU)
Random normalised features and text tokens (the data pipeline is timed separately by the loader).
"""

import argparse
import json
import platform
import time

import torch

from stablemofusion.diffusion.schedule import make_train_scheduler
from stablemofusion.diffusion.train import masked_mse
from stablemofusion.models.base import build_denoiser
from stablemofusion.models.presets import get_preset

p = argparse.ArgumentParser()
p.add_argument("--preset", default="small")
p.add_argument("--batch-size", type=int, default=64)
p.add_argument("--frames", type=int, default=196)
p.add_argument("--steps", type=int, default=20)
p.add_argument("--warmup", type=int, default=3)
p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
p.add_argument("--bf16", action="store_true", help="autocast to bfloat16 (GPU)")
p.add_argument("--compile", action="store_true", help="torch.compile the forward")
p.add_argument("--fused", action="store_true", help="fused AdamW (CUDA)")
a = p.parse_args()

torch.manual_seed(0)
dev = torch.device(a.device)
model = build_denoiser(get_preset(a.preset)).to(dev).train()
opt = torch.optim.AdamW(model.parameters(), lr=2e-4, weight_decay=0.01, fused=a.fused)
forward = torch.compile(model) if a.compile else model
sched = make_train_scheduler()
B, T = a.batch_size, a.frames
x0 = torch.randn(B, T, 263, device=dev)
mask = torch.ones(B, T, dtype=torch.bool, device=dev)
tokens = torch.randn(B, 16, model.text.proj.in_features, device=dev)
tmask = torch.ones(B, 16, dtype=torch.bool, device=dev)


def step():
    t = torch.randint(0, 1000, (B,), device=dev)
    x_t = sched.add_noise(x0, torch.randn_like(x0), t)
    with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=a.bf16):
        loss = masked_mse(forward(x_t, t, tokens, tmask, torch.rand(B, device=dev) < 0.1, mask).float(), x0, mask)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
    opt.step()
    opt.zero_grad(set_to_none=True)


for _ in range(a.warmup):
    step()
if dev.type == "cuda":
    torch.cuda.synchronize()
t0 = time.perf_counter()
for _ in range(a.steps):
    step()
if dev.type == "cuda":
    torch.cuda.synchronize()
dt = time.perf_counter() - t0
print(json.dumps({"preset": a.preset, "parameters": model.num_parameters(), "device": str(dev),
                  "device_name": torch.cuda.get_device_name(dev) if dev.type == "cuda" else platform.processor(),
                  "threads": torch.get_num_threads(), "batch_size": B, "frames": T, "bf16": a.bf16, "compile": a.compile, "fused": a.fused,
                  "seconds_per_step": dt / a.steps, "samples_per_s": B * a.steps / dt}))
