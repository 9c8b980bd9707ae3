"""The seeded noise made where the model runs, against the same numbers made by numpy on the host.

Prints, as JSON lines:

1. ``check``: the noise of a sampling call made on the device against numpy's (the spec), over several draws,
   batch sizes and per-item seeds: elements compared, elements that differ, the largest difference in float32
   ulps;
2. ``noise``: seconds to make one call's initial noise (batch B, the model's longest motion) with numpy on the
   host and copied to the device (how every version before this one drew it), and made on the device;
3. ``denoise``: milliseconds per motion of the denoising call (text cached; noise, the network's steps, the copy
   back), with the noise made on the host then copied ("host") and made on the device ("device"), per engine and
   batch size; motions per second;
4. ``profile``: with ``--profile``, the largest self times of one call at the largest batch, from
   ``torch.profiler`` (CPU and CUDA).

Usage (a CUDA GPU; on a CPU it runs too, with ``--device cpu``)::

    python benchmarks/device_noise.py [--teacher] [--checkpoint MODEL] [--batch-sizes 1,32,256]
        [--engines eager,graph] [--repeats 5] [--profile] [--text-cache DIR]

``--text-cache DIR`` reads the prompts' frozen text tokens from a :class:`~stablemofusion.text.cache.TextEmbeddingCache`
folder (written by ``--make-text-cache DIR`` where the text encoder is installed), so that a machine without the text
encoder's package can run it: the timed calls take cached text either way.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from stablemofusion.diffusion import sampling
from stablemofusion.core.noise import draws
from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.core.settings import Settings
from stablemofusion.text.cache import TextEmbeddingCache

PROMPT = "a person walks forward and waves with the right hand"


def host_draws(seed, lengths, dims, draw_indices, *, like=None):
    """The noise as every version before this one made it: numpy on the host, then copied to ``like``'s device."""
    out = torch.from_numpy(draws(seed, lengths, dims, draw_indices))
    return out if like is None else out.to(like.device)


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(device, fn, repeats: int) -> float:
    """Median seconds of ``fn(r)`` over ``repeats`` calls after one warm-up, the device synchronised around each."""
    fn(repeats)
    return float(np.median([once(device, fn, r) for r in range(repeats)]))


def once(device, fn, r: int) -> float:
    sync(device)
    t0 = time.perf_counter()
    fn(r)
    sync(device)
    return time.perf_counter() - t0


def check(device: torch.device, frames: int, dims: int) -> dict:
    like = torch.empty(0, device=device)
    compared = differ = worst = 0
    for seed, lengths, indices in [(0, [frames], range(11)), (12345, [frames] * 64, range(3)),
                                   (list(range(100, 132)), [frames - 3 * k for k in range(32)], range(2)),
                                   (2**53 - 1, [frames] * 256, [0])]:
        want = draws(seed, lengths, dims, indices)
        got = draws(seed, lengths, dims, indices, like=like).cpu().numpy()
        ulps = np.abs(got.view(np.int32).astype(np.int64) - want.view(np.int32).astype(np.int64))
        compared += want.size
        differ += int((ulps > 0).sum())
        worst = max(worst, int(ulps.max()))
    return {"what": "check", "device": str(device), "elements": compared, "differ": differ, "max_ulps": worst}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--checkpoint", default=None)
    p.add_argument("--teacher", action="store_true")
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--batch-sizes", default="1,32,256")
    p.add_argument("--engines", default="eager,graph")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--profile", action="store_true")
    p.add_argument("--text-cache", default=None, help="a folder of the prompts' frozen text tokens")
    p.add_argument("--make-text-cache", default=None, help="write the prompts' frozen text tokens here and stop")
    a = p.parse_args()
    batches = [int(b) for b in a.batch_sizes.split(",")]
    prompts_of = lambda b: [f"{PROMPT} {i}" for i in range(b)]  # noqa: E731
    if a.make_text_cache:
        with TextEmbeddingCache(a.make_text_cache, "minilm") as cache:
            cache.precompute(prompts_of(max(batches)))
        return
    device = torch.device(a.device)
    pipe = MotionPipeline.from_pretrained(a.checkpoint, teacher=a.teacher, device=device)
    if a.text_cache:
        pipe.text_cache = TextEmbeddingCache(a.text_cache, "minilm")
    frames, dims = pipe.max_frames, int(pipe.mean.shape[0])
    name = "teacher" if a.teacher else (a.checkpoint or "student")
    print(json.dumps(check(device, frames, dims)), flush=True)
    like = torch.empty(0, device=device)
    for b in batches:
        lengths = [frames] * b
        host = timed(device, lambda r: host_draws(r, lengths, dims, [0], like=like), a.repeats)
        made = timed(device, lambda r: draws(r, lengths, dims, [0], like=like), a.repeats)
        print(json.dumps({"what": "noise", "batch": b, "frames": frames, "host_s": host, "device_s": made}), flush=True)
    for engine in a.engines.split(","):
        engine = pipe.engine_for(None, engine)
        for b in batches:
            prompts, lengths = prompts_of(b), [frames] * b
            row = {"what": "denoise", "model": name, "engine": engine, "batch": b, "frames": frames,
                   "steps": pipe.settings(Settings()).steps, "dtype": str(pipe.dtype).removeprefix("torch.")}
            for where, fn in (("host", host_draws), ("device", draws)):
                sampling.draws = fn
                s = timed(device, lambda r: pipe.denoise(prompts, lengths, seed=r, engine=engine), a.repeats)
                row[f"{where}_ms_per_motion"] = 1000 * s / b
                row[f"{where}_motions_per_s"] = b / s
            sampling.draws = draws
            print(json.dumps(row), flush=True)
    if a.profile:
        from torch.profiler import ProfilerActivity, profile

        b = batches[-1]
        prompts, lengths = prompts_of(b), [frames] * b
        engine = pipe.engine_for(None, a.engines.split(",")[-1])
        for where, fn in (("host", host_draws), ("device", draws)):
            sampling.draws = fn
            pipe.denoise(prompts, lengths, seed=0, engine=engine)
            acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if device.type == "cuda" else [])
            with profile(activities=acts) as prof:
                pipe.denoise(prompts, lengths, seed=1, engine=engine)
                sync(device)
            key = "self_cuda_time_total" if device.type == "cuda" else "self_cpu_time_total"
            print(f"--- profile: noise made on the {where}, {engine}, batch {b}, sorted by self CPU time")
            print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=12))
            if device.type == "cuda":
                print("--- the same, sorted by self CUDA time")
                print(prof.key_averages().table(sort_by=key, row_limit=8))
        sampling.draws = draws


if __name__ == "__main__":
    main()
