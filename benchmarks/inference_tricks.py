"""AITS after each efficient-inference trick, cumulatively (the paper's Table 5 at our scale).

    python benchmarks/inference_tricks.py [--checkpoint RUN] [--teacher] [--frames 196] [--batch-size 1] [--repeats 3]

Rows: baseline (DDPM 1000 steps, text encoded by the language model on every call, conditional and
unconditional passes separately) -> + 10-step SDE DPM-Solver++ Karras -> + text embedding cache ->
+ batched CFG -> + float16 (only on CUDA). Prints a markdown table and JSON.

The baseline's 1,000 steps are past what a request may ask (steps 1-50, stablemofusion/core/limits.py): this research
benchmark resolves each row's settings with the model's own checks and then sets its step count, calling the
sampler below the request checks (stablemofusion.backends.torch_sampling.sample), as the paper's baseline ran.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import replace

import torch

from stablemofusion.pipelines.motion_pipeline import MotionPipeline
from stablemofusion.backends.torch_sampling import sample as sample_raw
from stablemofusion.core.settings import GUIDANCE, Settings


def aits(pipe: MotionPipeline, prompts, frames: int, *, sampler: str, steps: int, batched_cfg: bool, cached: bool,
         repeats: int, guidance: float) -> float:
    """Seconds per sentence, mean over ``repeats`` calls after one warm-up."""
    # the model's checks on a request's settings, then the row's step count (the baseline's 1,000 is past a request's)
    settings = replace(pipe.settings(Settings(guidance_scale=guidance, steps=10, sampler=sampler, footskate="off")),
                       steps=steps)

    def once(seed):
        if not cached:
            pipe.text_cache.clear()
        raw = sample_raw(pipe, prompts, [frames] * len(prompts), settings, seed, batched_cfg=batched_cfg)
        pipe.finish_many([r.numpy() for r in raw], "off")  # the final stage, as every motion has it

    once(0)
    times = []
    for r in range(repeats):
        if pipe.device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        once(r + 1)
        if pipe.device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - t0)
    return sum(times) / len(times) / len(prompts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default=None, help="checkpoint or run folder (default: shipped model)")
    ap.add_argument("--teacher", action="store_true", help="the model's teacher (the shipped model is a student)")
    ap.add_argument("--frames", type=int, default=196)
    ap.add_argument("--batch-size", type=int, default=1)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--baseline-steps", type=int, default=1000)
    ap.add_argument("--guidance", type=float, default=GUIDANCE,
                    help=f"guidance scale (default {GUIDANCE}, not the model's: at 1.0 there is no second pass to batch)")
    args = ap.parse_args()
    if args.guidance == 1.0:
        raise SystemExit("--guidance 1.0 has no unconditional pass: the CFG rows would measure nothing")
    device = "cuda" if torch.cuda.is_available() else "cpu"
    pipe = MotionPipeline.from_pretrained(args.checkpoint, teacher=args.teacher, device=device, dtype=torch.float32)
    if pipe.student:
        raise SystemExit("the tricks are a diffusion model's (classifier-free guidance, many steps): this is a "
                         "distilled student; pass --teacher")
    prompts = [f"a person walks forward and waves with the right hand {i}" for i in range(args.batch_size)]
    rows = []
    steps = [("Baseline: DDPM, language model every call, separate CFG passes", "ddpm", args.baseline_steps, False, False),
             ("+ SDE DPM-Solver++ 2M Karras, 10 steps", "sde-dpmsolver++-karras", 10, False, False),
             ("+ text embedding cache", "sde-dpmsolver++-karras", 10, False, True),
             ("+ batched CFG (one pass)", "sde-dpmsolver++-karras", 10, True, True)]
    for label, sampler, n, batched, cached in steps:
        s = aits(pipe, prompts, args.frames, sampler=sampler, steps=n, batched_cfg=batched, cached=cached,
                 repeats=1 if n > 100 else args.repeats, guidance=args.guidance)
        rows.append({"trick": label, "sampler": sampler, "steps": n, "aits_ms": s * 1000})
        print(f"{label:70s} {s * 1000:10.1f} ms", flush=True)
    if device == "cuda":
        half = MotionPipeline.from_pretrained(args.checkpoint, teacher=args.teacher, device=device, dtype=torch.float16)
        s = aits(half, prompts, args.frames, sampler="sde-dpmsolver++-karras", steps=10, batched_cfg=True, cached=True,
                 repeats=args.repeats, guidance=args.guidance)
        rows.append({"trick": "+ float16", "sampler": "sde-dpmsolver++-karras", "steps": 10, "aits_ms": s * 1000})
    else:
        rows.append({"trick": "+ float16", "sampler": "sde-dpmsolver++-karras", "steps": 10, "aits_ms": None,
                     "note": "GPU only; not measured on CPU"})
    print("\n| Trick (cumulative) | Sampler | Steps | AITS (ms) |\n|---|---|---:|---:|")
    for r in rows:
        ms = "n/a (GPU only)" if r["aits_ms"] is None else f"{r['aits_ms']:.1f}"
        print(f"| {r['trick']} | {r['sampler']} | {r['steps']} | {ms} |")
    print(json.dumps({"device": device, "cpu": platform.processor() or platform.machine(),
                      "threads": torch.get_num_threads(), "frames": args.frames, "batch_size": args.batch_size,
                      "guidance": args.guidance,
                      "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
