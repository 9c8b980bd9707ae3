"""Training throughput (samples/s) of a preset on this machine: forward + backward + AdamW step.

Usage: python benchmarks/train_speed.py [--preset small] [--batch-size 64] [--steps 20] [--device cpu|cuda]
       [--bf16] [--compile] [--fused]   (what `smf train --mixed-precision bf16 --compile` uses on a GPU)
Random normalised features and text tokens (the data pipeline is timed separately by the loader).

With ``--data CORPUS`` it runs the real training loop (`smf train`'s own code: batches, text cache, caption
augmentation, EMA) for each ``--recipe`` in turn, ``--rounds`` times interleaved (so a busy machine slows
each alike), and prints the median of `smf train`'s own samples/s (log.csv) over the steps after the first
few. Recipes: ``fp32`` (fp32, captions perturbed with probability 0.5), ``balanced`` (bf16 autocast, captions
perturbed with probability 0.1, label balancing), ``shipped`` (the shipped teacher's: bf16, captions perturbed with
probability 0.5, short crops 0.5) and ``shipped-lean`` (``shipped`` with captions perturbed with probability
0.1). ``--recipe NAME@CHECKOUT`` runs that recipe with the code of another checkout (e.g. ``git
worktree add --detach /tmp/old COMMIT``), so a speed-up in the code is measured against the code before it.
The text cache is warmed first, so no run pays for encoding the corpus's captions.
"""

import argparse
import json
import platform
import time

import torch

from stablemofusion.diffusion.schedule import make_train_scheduler
from stablemofusion.diffusion.train import masked_mse
from stablemofusion.models.registry import build_denoiser
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
p.add_argument("--data", default=None, help="a corpus: time the real training loop for each --recipe")
p.add_argument("--recipe", action="append", default=None,
               help="fp32 | balanced | shipped | shipped-lean, optionally @CHECKOUT (repeatable)")
p.add_argument("--rounds", type=int, default=2)
p.add_argument("--text-cache", default=None, help="text cache folder (default: a temporary one)")
p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
a = p.parse_args()
if a.threads:
    torch.set_num_threads(a.threads)

RECIPES = {"fp32": ["--mixed-precision", "no", "--text-augment", "0.5", "--bucket", "16"],
           "balanced": ["--mixed-precision", "bf16", "--text-augment", "0.1", "--bucket", "16", "--balance", "0.5"],
           "shipped": ["--mixed-precision", "bf16", "--text-augment", "0.5", "--bucket", "16", "--balance", "0",
                  "--short-crops", "0.5"],
           "shipped-lean": ["--mixed-precision", "bf16", "--text-augment", "0.1", "--bucket", "16", "--balance", "0",
                       "--short-crops", "0.5"]}
# run `smf` from another checkout: an editable install's import hook would win over PYTHONPATH, so drop it first
LAUNCH_FROM = ("import sys; sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in "
               "(getattr(f, '__module__', '') + repr(f)).lower()]; sys.path.insert(0, sys.argv.pop(1)); "
               "from stablemofusion.cli.main import main; sys.exit(main())")


def real_loop() -> None:
    """`smf train` itself, one process per run (accelerate's precision is fixed per process)."""
    import os
    import statistics
    import subprocess
    import sys
    import tempfile

    skip = 3
    cache = a.text_cache or tempfile.mkdtemp(prefix="smf-text-")
    rates: dict[str, list[float]] = {r: [] for r in a.recipe or ["fp32", "balanced"]}
    runs = {name: name.partition("@")[::2] for name in rates}  # name -> (recipe, checkout or "")
    for name, (recipe, _) in runs.items():
        if recipe not in RECIPES:
            raise SystemExit(f"unknown recipe {name!r}: one of {', '.join(RECIPES)} (optionally @CHECKOUT)")
    for rnd in range(a.rounds):
        for name, (recipe, code) in runs.items():
            entry = ["-c", LAUNCH_FROM, str(Path(code).resolve())] if code else ["-m", "stablemofusion.cli.main"]
            with tempfile.TemporaryDirectory() as out:
                cmd = [sys.executable, *entry, "train", "--data", a.data, "--out", out,
                       "--preset", a.preset, "--steps", str(a.steps + skip), "--batch-size", str(a.batch_size),
                       "--seed", str(rnd), "--checkpoint-every", str(10**9), "--text-cache", cache, "--no-progress",
                       *(["--threads", str(a.threads)] if a.threads else []), *RECIPES[recipe]]
                subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, env=os.environ)
                rows = (Path(out) / "log.csv").read_text().splitlines()[1 + skip:]
                rates[name] += [float(r.split(",")[4]) for r in rows]
    print(json.dumps({"preset": a.preset, "threads": a.threads or torch.get_num_threads(), "batch_size": a.batch_size,
                      "steps_per_round": a.steps, "rounds": a.rounds, "cpu": platform.processor(),
                      "samples_per_s": {k: round(statistics.median(v), 1) for k, v in rates.items()}}))


if a.data:
    from pathlib import Path

    real_loop()
    raise SystemExit

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
