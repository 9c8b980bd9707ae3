"""`smf info [--preset NAME ...]`: parameter counts of the model presets (and a checkpoint's config)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..core.errors import escape


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name)
    p.add_argument("--preset", action="append", default=None, help="preset name (repeatable; default: all)")
    p.add_argument("--checkpoint", type=Path, default=None, help="describe a checkpoint folder instead")
    p.add_argument("--adapter", type=Path, default=None, help="describe an adapter file (smf adapt) instead")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..models.registry import build_denoiser
    from ..models.presets import PRESETS, describe, get_preset

    if args.adapter is not None:
        from ..adapters.file import Adapter

        a = Adapter.load(args.adapter)
        i, t = a.info, a.info.training
        print(f"{args.adapter}: adapter {i.name!r}, rank {i.lora.rank}, {len(i.clips)} clip captions from "
              f"{t.get('clips', '?')} clips ({t.get('motion_seconds', '?')} s of motion), trained in {t.get('seconds', '?')} s")
        print(f"licence of the clips: {escape(i.licence)}")
        print(f"base model weights (sha256): student {i.base.get('student', '-')[:12]}, teacher "
              f"{i.base.get('teacher', '-')[:12]}")
        for label, captions in i.actions.items():
            # a file's captions are printed escaped: an ANSI escape in one cannot drive the terminal
            print(f"action {escape(label)!r}: " + "; ".join(escape(c) for c in captions[:8])
                  + (f"; ... ({len(captions)} captions)" if len(captions) > 8 else ""))
        return
    if args.checkpoint is not None:
        from ..diffusion.checkpoint import load_checkpoint
        from ..core.settings import model_defaults

        ck = load_checkpoint(args.checkpoint)
        c = ck.config
        print(f"{ck.path}: {c.model.arch}, {ck.model.num_parameters():,} parameters, text encoder {c.text_encoder}, "
              f"{c.skeleton} at {c.fps:g} fps, {c.min_frames}-{c.max_frames} frames, step {c.step or '?'}")
        if c.student:
            print(f"distilled few-step student of {c.distil.teacher}: samples with lcm in {c.distil.sample_steps} "
                  f"step{'s' * (c.distil.sample_steps != 1)} by default, guidance as input (trained on {c.distil.guidance_min:g}-{c.distil.guidance_max:g})")
        print(f"default guidance scale {model_defaults(None, c.guidance)[0]:g} "
              f"({'the package default' if c.guidance is None else 'its config'})")
        return
    names = args.preset or list(PRESETS)
    print(f"{'preset':<15} {'arch':<7} {'parameters':>13} {'text part':>11}  description")
    for n in names:
        cfg = get_preset(n)
        model = build_denoiser(cfg)
        text = sum(p.numel() for p in model.text.parameters())
        print(f"{n:<15} {cfg.arch:<7} {model.num_parameters():>13,} {text:>11,}  {describe(n)}")
