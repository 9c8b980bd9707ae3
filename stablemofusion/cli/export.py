"""`smf export --checkpoint RUN --out DIR [--card MODEL_CARD.md]`: a small release folder (EMA weights, fp16)."""

from __future__ import annotations

import argparse
from pathlib import Path

# Calibrated with benchmarks/ood_threshold.py on the lexicon's held-out phrasings (in domain) and
# benchmarks/ood_calibration.txt (out of domain); not on the free-form dev set.
OOD_THRESHOLD = 0.56


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name, help="write a release folder (EMA weights in fp16, config, Mean/Std, model card)",
                       description="Export a checkpoint for shipping: EMA weights only, float16 by default.")
    p.add_argument("--checkpoint", type=Path, required=True, help="checkpoint or training run folder")
    p.add_argument("--out", type=Path, required=True, help="release folder to write (replaced atomically)")
    p.add_argument("--card", type=Path, default=None, help="model card (markdown) copied in as MODEL_CARD.md")
    p.add_argument("--dtype", default="float16", choices=("float16", "bfloat16", "float32"))
    p.add_argument("--lexicon", default=None,
                   help="corpus lexicon (e.g. bandai) whose actions the model knows: writes actions.json, so prompts "
                        "far from them get an out-of-domain warning")
    p.add_argument("--ood-threshold", type=float, default=OOD_THRESHOLD,
                   help=f"similarity below which a prompt is out of domain (default {OOD_THRESHOLD})")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import torch

    from ..diffusion.checkpoint import export_checkpoint
    from ..errors import SMFError

    extra = {}
    if args.card is not None:
        if not args.card.is_file():
            raise SMFError(f"no such model card: {args.card}")
        extra["MODEL_CARD.md"] = args.card.read_text(encoding="utf-8")
    if args.lexicon is not None:
        import json

        from ..data.lexicon import known_actions, load_lexicon
        from ..text.known import ACTIONS_FILE

        extra[ACTIONS_FILE] = json.dumps(known_actions(load_lexicon(args.lexicon), args.ood_threshold), indent=1) + "\n"
    out = export_checkpoint(args.checkpoint, args.out, dtype=getattr(torch, args.dtype), extra_files=extra)
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"exported {args.checkpoint} -> {out} ({size / 1e6:.1f} MB)")
