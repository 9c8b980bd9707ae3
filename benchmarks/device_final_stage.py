"""The final stage (rigid fit, footskate cleanup, pose and write-back) on the host's numpy against the same functions
with the fit and the cleanup on the GPU, for the torch backend's raw motions.

For each batch size: the shipped student's raw features of B motions of the longest length (text cached), then
``TorchBackend.finish_many`` of them with the math on the host (numpy) and on the device, footskate post and off:
milliseconds per motion (median of ``--repeats`` after one warm-up), the largest difference of the features and
joints between the two, whether the held feet are the same; and the denoising call's own milliseconds per motion
beside them (noise, network, copy back), so that the two add up to what a motion costs before its files.

Usage (a CUDA GPU)::

    python benchmarks/device_final_stage.py [--batch-sizes 1,32,256] [--repeats 3] [--text-cache DIR]

``--text-cache DIR``: as in benchmarks/device_noise.py (a machine without the text encoder's package).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.core.final import finish_many
from stablemofusion.text.cache import TextEmbeddingCache

PROMPT = "a person walks forward and waves with the right hand"


def median_s(fn, repeats: int) -> float:
    sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)
    fn()
    times = []
    for _ in range(repeats):
        sync()
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--batch-sizes", default="1,32,256")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--text-cache", default=None)
    p.add_argument("--device", default="cuda", help="cpu: a dry run of the script (torch on the CPU)")
    a = p.parse_args()
    pipe = MotionPipeline.from_pretrained(device=a.device)
    if a.text_cache:
        pipe.text_cache = TextEmbeddingCache(a.text_cache, "minilm")
    like = torch.empty(0, dtype=torch.float64, device=a.device)
    for b in [int(x) for x in a.batch_sizes.split(",")]:
        prompts, lengths = [f"{PROMPT} {i}" for i in range(b)], [pipe.max_frames] * b
        denoise = median_s(lambda: pipe.denoise(prompts, lengths, seed=0), a.repeats)
        raw = pipe.denoise(prompts, lengths, seed=0)
        features = [raw[i].numpy() for i in range(b)]
        for footskate in ("post", "off"):
            run = lambda where: finish_many(features, pipe.skeleton, pipe.fps, pipe.rigid, footskate,  # noqa: E731
                                            None, where)
            host, device = run(None), run(like)
            row = {"batch": b, "frames": pipe.max_frames, "footskate": footskate,
                   "denoise_ms_per_motion": 1000 * denoise / b,
                   "host_ms_per_motion": 1000 * median_s(lambda: run(None), a.repeats) / b,
                   "device_ms_per_motion": 1000 * median_s(lambda: run(like), a.repeats) / b,
                   "features_max_diff": max(float(np.abs(h[0] - d[0]).max()) for h, d in zip(host, device)),
                   "joints_max_diff_m": max(float(np.abs(h[1].joints() - d[1].joints()).max())
                                            for h, d in zip(host, device)),
                   "held_same": all((h[1].planted is None and d[1].planted is None)
                                    or np.array_equal(h[1].planted, d[1].planted) for h, d in zip(host, device))}
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
