"""`smf bench`: average inference time per sentence (AITS) per engine, sampler and step count; JSON output.

AITS is the time of the denoising loop (text already cached, after a warm-up); beside it the end-to-end time
per motion (a full pipeline call: denoising, the rigid final stage and cleanup, results built; text cached)
and the final stage alone (``TorchBackend.finish_many`` of the batch's raw features), per motion."""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path


def add_parser(sub, name: str) -> None:
    from ..core.limits import SAMPLER, STEPS, STUDENT_SAMPLER
    from .flags import add_teacher_flag
    from .options import add_adapter_flag

    p = sub.add_parser(name)
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    add_teacher_flag(p)
    add_adapter_flag(p)
    p.add_argument("--preset", default=None, help="time an untrained preset instead of a checkpoint")
    p.add_argument("--sampler", action="append", default=None, help=f"repeatable (default: the model's: {SAMPLER}, a "
                                                                      f"distilled student {STUDENT_SAMPLER})")
    p.add_argument("--steps", type=int, action="append", default=None,
                   help=f"repeatable (default: the model's: {STEPS}, a distilled student its own count)")
    p.add_argument("--engine", action="append", default=None,
                   help="eager, fast, compiled, aot, graph or auto; repeatable (default: eager and auto); the speed-up "
                        "is over eager; the warm-up of aot is its package's build (first use) or load")
    p.add_argument("--frames", type=int, default=None, help="motion length (default: the model's longest, 196)")
    p.add_argument("--batch-sizes", default="1,32")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--guidance", type=float, default=None, help="classifier-free guidance scale (default: the model's)")
    p.add_argument("--footskate", default="off", help="cleanup in the end-to-end time: off, post or loop")
    p.add_argument("--device", default=None)
    p.add_argument("--out", type=Path, default=None, help="write the JSON here too")
    p.set_defaults(func=run)


def _pipeline(args):
    import torch

    from ..backends.torch_backend import TorchBackend
    from ..pipelines.motion_pipeline import MotionPipeline

    if args.preset is None:
        return MotionPipeline.from_pretrained(args.checkpoint, backend="torch", teacher=args.teacher,
                                              device=args.device, adapter=args.adapter)
    if args.teacher or args.checkpoint is not None or args.adapter:
        from ..core.errors import SMFError

        raise SMFError("--preset times an untrained preset: not with --checkpoint, --teacher or --adapter")
    import numpy as np

    from ..diffusion.config import CheckpointConfig
    from ..models.registry import build_denoiser
    from ..models.presets import get_preset

    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    cfg = get_preset(args.preset)
    model = build_denoiser(cfg)
    config = CheckpointConfig.for_skeleton(cfg)
    dtype = torch.float16 if device.type == "cuda" else torch.float32
    mean = rest_features(config.skeleton)
    return MotionPipeline(TorchBackend(model, mean, np.ones_like(mean), config, device=device, dtype=dtype))


def rest_features(skeleton: str):
    """(D,) features of the skeleton standing still in its rest pose: the normalisation mean of an untrained
    preset. Its zero-initialised output layer predicts x0 = 0, i.e. the mean; with a mean of zeros every
    joint would sit on the origin (bones of length 0), where no skeleton can be fitted."""
    import numpy as np

    from ..motion.features import features_from_joints
    from ..motion.kinematics import forward_kinematics
    from ..motion.skeleton import get_skeleton

    sk = get_skeleton(skeleton)
    offsets = sk.target_offsets() if sk.bone_lengths is not None else sk.offsets_array * REST_BONE_M
    pose = forward_kinematics(np.asarray(offsets, np.float64), None, np.zeros(3), sk.parents)
    pose[:, 1] -= pose[:, 1].min()  # feet on the floor
    return features_from_joints(np.repeat(pose[None], 2, axis=0), sk)[0]


REST_BONE_M = 0.2  # bone length of the rest pose of a skeleton without target lengths (metres)


def run(args: argparse.Namespace) -> None:
    import torch

    from ..core.errors import SMFError
    from ..core.io import write_text

    pipe = _pipeline(args)
    args.frames = args.frames or pipe.max_frames
    from ..core.settings import Settings

    # the model's guidance, steps and sampler (a student's own)
    defaults = pipe.settings(Settings(guidance_scale=args.guidance))
    samplers = args.sampler or [defaults.sampler]
    steps_list = args.steps or [defaults.steps]
    try:
        batches = [int(b) for b in args.batch_sizes.split(",")]
    except ValueError:
        raise SMFError(f"--batch-sizes must be a comma list of integers, not {args.batch_sizes!r}") from None
    from ..diffusion.engine import check_engine

    engines = args.engine or ["eager", "auto"]
    for e in engines:
        check_engine(e, pipe.device)
    prompt = "a person walks forward and waves with the right hand"
    rows = []
    for sampler in samplers:
        for steps in steps_list:
            for b in batches:
                prompts = [f"{prompt} {i}" for i in range(b)]
                lengths = [args.frames] * b
                eager = None
                for engine in engines:
                    name = pipe.engine_for(sampler, engine)
                    t0 = time.perf_counter()  # warm-up: fills the text cache, compiles or captures
                    raw = pipe.denoise(prompts, lengths, guidance_scale=args.guidance, steps=steps, sampler=sampler,
                                       seed=0, engine=name)
                    warmup = time.perf_counter() - t0
                    mean = _mean_time(args.repeats, pipe, lambda r: pipe.denoise(
                        prompts, lengths, guidance_scale=args.guidance, steps=steps, sampler=sampler, seed=r,
                        engine=name))
                    features = [f.numpy() for f in raw]
                    finish = _mean_time(args.repeats, pipe, lambda r: pipe.finish_many(features)) / b
                    def whole(r: int) -> None:
                        pipe(prompts, frames=lengths, guidance_scale=args.guidance, steps=steps, sampler=sampler,
                             seed=[r * b + i for i in range(b)], batch_size=b, footskate=args.footskate, engine=name)

                    whole(args.repeats)  # warm-up of what only a whole call loads (known actions, cleanup)
                    e2e = _mean_time(args.repeats, pipe, whole) / b
                    eager = mean if name == "eager" else eager
                    row = {"engine": name, "sampler": sampler, "steps": steps, "batch_size": b, "frames": args.frames,
                           "seconds_per_batch": mean, "aits": mean / b, "warmup_seconds": warmup,
                           "speedup_over_eager": None if eager is None else eager / mean,
                           "final_stage_seconds_per_motion": finish, "end_to_end_seconds_per_motion": e2e,
                           "footskate": args.footskate}
                    rows.append(row)
                    speed = "" if eager is None else f"  x{eager / mean:5.2f} vs eager"
                    print(f"{name:<9} {sampler:<24} steps {steps:>4}  batch {b:>3}  AITS {mean / b * 1000:9.2f} ms"
                          f"{speed}  end to end {e2e * 1000:8.2f} ms/motion (rigid final stage {finish * 1000:.2f} "
                          f"ms/motion; warm-up {warmup:.1f} s)", flush=True)
    report = {"device": str(pipe.device), "frames": args.frames, "dtype": str(pipe.dtype).replace("torch.", ""),
              "device_name": torch.cuda.get_device_name() if pipe.device.type == "cuda" else platform.processor()
              or platform.machine(), "threads": torch.get_num_threads(),
              "parameters": pipe.model.num_parameters(), "guidance": defaults.guidance_scale, "student": pipe.student,
              "results": rows}
    text = json.dumps(report, indent=2)
    print(text)
    if args.out is not None:
        write_text(args.out, text + "\n")


def _mean_time(repeats: int, pipe, fn) -> float:
    """Mean seconds of ``fn(r)`` for r = 0 .. repeats-1 (the device synchronised around each call)."""
    times = []
    for r in range(repeats):
        _sync(pipe)
        t0 = time.perf_counter()
        fn(r)
        _sync(pipe)
        times.append(time.perf_counter() - t0)
    return sum(times) / len(times)


def _sync(pipe) -> None:
    import torch

    if pipe.device.type == "cuda":
        torch.cuda.synchronize()
