"""`smf generate "TEXT" --seconds 4 --out DIR [--format npy,mp4,gif,bvh,json] ...`: text to motion files."""

from __future__ import annotations

import argparse
import json
import re
import warnings
from pathlib import Path

from .character import add_character_arguments, load_rig, write_character_files

FORMATS = ("npy", "mp4", "gif", "bvh", "json", "glb")


def add_parser(sub, name: str) -> None:
    from ..diffusion.engine import ENGINES
    from ..diffusion.samplers import DEFAULT_SAMPLER

    p = sub.add_parser(name, help="generate motions from text",
                       description="Generate one motion per prompt and write joints/features .npy, video and BVH.")
    p.add_argument("text", nargs="?", default=None, help="the prompt (or use --prompts FILE)")
    p.add_argument("--prompts", type=Path, default=None, help="file with one prompt per line")
    p.add_argument("--timeline", default=None,
                   help="one continuous motion from segments 'PROMPT:SECONDS; PROMPT:SECONDS; ...' (any total length)")
    p.add_argument("--seconds", type=float, default=None,
                   help="length of each motion (default: predicted from the text by the model's length estimator; "
                        "4 s for a model without one)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--format", default="npy,mp4,bvh", help=f"comma list of {','.join(FORMATS)} (default npy,mp4,bvh)")
    p.add_argument("--guidance", type=float, default=2.5, help="classifier-free guidance scale (default 2.5)")
    p.add_argument("--steps", type=int, default=10, help="sampling steps (default 10)")
    p.add_argument("--sampler", default=DEFAULT_SAMPLER, help=f"sampler name (default {DEFAULT_SAMPLER})")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    p.add_argument("--engine", default="auto", choices=("auto",) + ENGINES,
                   help="denoising engine (default auto: CUDA graphs on a GPU, the precomputed solver loop on a CPU; "
                        "docs/inference.md)")
    add_footskate_arguments(p)
    add_character_arguments(p)  # --rig, --joint-map (cli/character.py)
    p.set_defaults(func=run)


def add_footskate_arguments(p) -> None:
    """--footskate off|post|loop, --contacts, --vgrf-model, --underpressure (shared with other commands)."""
    p.add_argument("--footskate", default="off", choices=("off", "post", "loop"),
                   help="footskate cleanup: off, post (after sampling) or loop (inside the last denoising steps)")
    p.add_argument("--contacts", default="kinematic", choices=("kinematic", "vgrf"),
                   help="contact route for the cleanup (vgrf needs --vgrf-model or --underpressure)")
    p.add_argument("--vgrf-model", type=Path, default=None,
                   help="distilled 22-joint vGRF model (.safetensors): adds the vGRF loss (non-commercial)")
    p.add_argument("--underpressure", type=Path, default=None,
                   help="UnderPressure pretrained.tar used directly as vGRF model (non-commercial, slower)")


def footskate_options_from_args(args):
    """FootskateOptions for the pipeline from the arguments of :func:`add_footskate_arguments`."""
    from ..footskate import CleanupConfig, FootskateOptions
    from .footskate import vgrf_model_from_args

    model = None
    if args.vgrf_model is not None or args.underpressure is not None or args.contacts == "vgrf":
        model = vgrf_model_from_args(args.vgrf_model, args.underpressure, required=True)
    return FootskateOptions(config=CleanupConfig(contacts=args.contacts), vgrf_model=model)


def _slug(text: str, i: int) -> str:
    words = re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:48].rstrip("_")
    return f"{i:03d}_{words or 'motion'}"


def parse_formats(text: str) -> list[str]:
    from ..errors import SMFError

    formats = [f.strip().lower() for f in text.split(",") if f.strip()]
    bad = [f for f in formats if f not in FORMATS]
    if bad or not formats:
        raise SMFError(f"unknown format(s) {bad or text!r}; choose from {', '.join(FORMATS)}")
    return formats


def write_results(results, out: Path, formats: list[str], skeleton, meta: dict) -> None:
    """Write each MotionResult as joints/features .npy, BVH, video and JSON (``meta`` added to the JSON),
    named from its prompt; prints one line per motion."""
    from ..io import save_npy, write_text
    from ..motion.files import save_bvh, save_rigid_bvh

    if any(f in formats for f in ("mp4", "gif")):
        from ..render import render_video
    for i, r in enumerate(results):
        stem = out / _slug(r.prompt, i)
        if "npy" in formats:
            save_npy(stem.with_name(stem.name + "_joints.npy"), r.joints.astype("float32"))
            save_npy(stem.with_name(stem.name + "_features.npy"), r.features.astype("float32"))
        if "bvh" in formats:
            if r.motion is not None:  # the rigid body the joints come from, so the BVH is the same motion
                save_rigid_bvh(r.motion, stem.with_suffix(".bvh"), r.fps)
            else:
                save_bvh(r.joints, stem.with_suffix(".bvh"), skeleton, r.fps)
        for fmt in ("mp4", "gif"):
            if fmt in formats:
                render_video(r.joints, stem.with_suffix("." + fmt), skeleton=skeleton, fps=r.fps, title=r.prompt)
        if "json" in formats:
            write_text(stem.with_suffix(".json"), json.dumps({
                "prompt": r.prompt, "fps": r.fps, "frames": len(r.joints), "seed": r.seed, **meta,
                **(r.domain.to_dict(r.prompt) if r.domain else {}), "joints": r.joints.round(5).tolist()}) + "\n")
        print(f"wrote {stem}.* ({len(r.joints)} frames, {len(r.joints) / r.fps:.1f} s)")


def run(args: argparse.Namespace) -> None:
    from ..errors import SMFError

    formats = parse_formats(args.format)
    if sum(x is not None for x in (args.text, args.prompts, args.timeline)) != 1:
        raise SMFError("give one of: a prompt text, --prompts FILE, --timeline 'PROMPT:SECONDS; ...'")
    if args.prompts is not None:
        if not args.prompts.is_file():
            raise SMFError(f"no such file: {args.prompts}")
        try:
            text = args.prompts.read_text(encoding="utf-8")
        except UnicodeDecodeError as e:
            raise SMFError(f"{args.prompts}: not UTF-8 text (byte {e.start}); save the prompts file as UTF-8") from None
        prompts = [ln.strip() for ln in text.splitlines() if ln.strip()]
        if not prompts:
            raise SMFError(f"{args.prompts} holds no prompts")
    elif args.timeline is not None:
        from ..timeline import parse_timeline

        segments = parse_timeline(args.timeline)
        prompts = [p for p, _ in segments]
    else:
        prompts = [args.text]
    if any(not p.strip() for p in prompts):
        raise SMFError("the prompt is empty")
    if args.seconds is not None and not args.seconds > 0:
        raise SMFError(f"--seconds must be positive, got {args.seconds}")

    rig = load_rig(args)  # --rig/--joint-map checked before the model loads
    from ..pipeline import LengthClampedWarning, MotionPipeline, OutOfDomainWarning

    options = footskate_options_from_args(args) if args.footskate != "off" else None
    pipe = MotionPipeline.from_pretrained(args.checkpoint, device=args.device, engine=args.engine)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        common = dict(guidance_scale=args.guidance, steps=args.steps, sampler=args.sampler, seed=args.seed,
                      footskate=args.footskate, footskate_options=options)
        if args.timeline is not None:
            results = [pipe.timeline(segments, **common)]
        else:
            results = pipe(prompts, seconds=args.seconds, batch_size=args.batch_size, progress=len(prompts) > 1,
                           **common)
    shown = (LengthClampedWarning, OutOfDomainWarning)
    for w in dict.fromkeys(str(c.message) for c in caught if issubclass(c.category, shown)):
        print(f"smf: warning: {w}")
    write_results(results, args.out, formats, pipe.skeleton,
                  {"sampler": args.sampler, "steps": args.steps, "guidance": args.guidance})
    write_character_files(results, args.out, formats, rig, _slug)  # .glb and the rig's BVH (cli/character.py)
