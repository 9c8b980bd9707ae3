"""`smf adapt --data DIR --out ADAPTER.safetensors --licence TEXT [--base MODEL] [--joint-map NAME|FILE] ...`."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..adapters.train import AdaptConfig
from .flags import add_config_flags, apply_threads, config_from_args

_FLAGS = {  # AdaptConfig field -> help
    "rank": "rank of the low-rank updates", "alpha": "their scale is alpha / rank",
    "text_layers": "adapt the text transformer's layers as well as the denoiser's (--no-text-layers: the "
                   "denoiser's only)",
    "teacher_steps": "steps of the teacher's adaptation (diffusion loss on the clips)",
    "student_steps": "steps of the student's adaptation (regression on the adapted teacher)",
    "batch_size": "motions per step", "teacher_lr": "AdamW learning rate of the teacher's updates",
    "student_lr": "AdamW learning rate of the student's updates",
    "replay": "share of each batch replaying what the base model already does (keeps its other actions)",
    "replay_prompts": "captions of the base's known actions replayed", "pool": "student targets per side",
    "contrast": "samples replayed of each of your captions said in the base model's words (its answer to them: the "
                "adapter learns which of your words name your move); 0: none",
    "lexicon": "caption lexicon of the base's corpus, whose captions are replayed ('' for the model's known-action "
               "examples)",
    "paraphrases": "other ways to say each of your captions, taught with your clips: its verb phrase replaced by the "
                   "lexicon's phrasings of the moves it describes with your caption's verb (none where it has no "
                   "such move); 0: none",
    "contrast_auto": "replay contrast captions only when the base model takes 90%% of your captions for moves it knows "
                     "(--no-contrast-auto: always)",
    "target_guidance": "guidance of the adapted teacher's samples the student learns (default: the student's own)",
    "target_rescale": "guidance rescale of those samples, a share in [0, 1] (0: plain guidance)",
    "cond_drop": "share of the teacher's items trained without text", "grad_clip": "gradient norm clip",
    "seed": "random seed", "checkpoint_every": "steps between resumable checkpoints",
}


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name, description="Teach a model your moves: a folder of BVH clips (any rig, through a joint "
                                         "map) and their captions become a small adapter file, loaded with "
                                         "`--adapter` by generate, edit and serve. Resumable with --resume.")
    p.add_argument("--data", type=Path, required=True, help="folder of .bvh clips (searched recursively)")
    p.add_argument("--out", type=Path, required=True, help="the adapter file to write (.safetensors)")
    p.add_argument("--licence", required=True,
                   help="the licence of your clips, carried in the adapter (e.g. 'CC BY 4.0', 'proprietary')")
    p.add_argument("--base", type=Path, default=None, help="the model to adapt (default: the shipped model)")
    p.add_argument("--joint-map", default="bandai-namco",
                   help="built-in joint map name (bandai-namco, mixamo, humanml3d) or a JSON file")
    p.add_argument("--captions", type=Path, default=None,
                   help="CSV with header 'file,caption' (default: DATA/captions.csv)")
    p.add_argument("--caption", default=None, help="one caption for every clip")
    p.add_argument("--captions-from-names", action="store_true",
                   help="captions from the file names ('kick_high_02.bvh' -> 'a person kick high')")
    p.add_argument("--name", default=None, help="the adapter's name and its action's label (default: --out's stem)")
    p.add_argument("--unit", default="auto", choices=["auto", "m", "cm", "mm", "inch"],
                   help="length unit of the BVH files")
    p.add_argument("--work", type=Path, default=None, help="resumable work folder (default: OUT.work)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted run from its work folder")
    p.add_argument("--report", type=Path, default=None,
                   help="folder for the report (default: OUT.report): captions, figures, a strip per caption")
    p.add_argument("--no-report", action="store_true", help="write no report")
    p.add_argument("--overwrite", action="store_true", help="replace an existing adapter file")
    p.add_argument("--threads", type=int, default=None, help="CPU threads for torch (default: torch's choice)")
    p.add_argument("--no-progress", action="store_true")
    add_config_flags(p, AdaptConfig, _FLAGS, types={"target_guidance": float})
    p.add_argument("--stop-after", type=int, nargs=2, default=None, help=argparse.SUPPRESS)  # simulate a kill (tests)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import sys
    import time

    from ..core.errors import SMFError

    cfg = config_from_args(AdaptConfig, args, _FLAGS).check()
    if args.out.exists() and not args.overwrite:
        raise SMFError(f"{args.out} exists; pass --overwrite to replace it")
    if args.out.suffix != ".safetensors":
        raise SMFError(f"--out must end in .safetensors, got {args.out.name}")
    if not args.licence.strip():
        raise SMFError("--licence must say under which terms your clips may be used")
    apply_threads(args.threads)
    t0 = time.perf_counter()
    import warnings

    from ..adapters.clips import ClipSkippedWarning, read_clips
    from ..adapters.train import adapt
    from ..core.folders import model_folder
    from ..diffusion.checkpoint import read_config

    base = model_folder(args.base)
    config = read_config(base)
    with warnings.catch_warnings(record=True) as caught:  # each clip skipped: one line on stderr
        warnings.simplefilter("always", ClipSkippedWarning)
        clips, source = read_clips(args.data, args.joint_map, captions=args.captions, caption=args.caption,
                                   from_names=args.captions_from_names, min_frames=config.min_frames, unit=args.unit,
                                   skeleton=config.skeleton, progress=not args.no_progress)
    for w in caught:
        print(f"smf: warning: {w.message}", file=sys.stderr)
    seconds = sum(c.frames for c in clips) / config.fps
    print(f"smf adapt: {len(clips)} clips ({seconds:.0f} s of motion), captions from {source}", file=sys.stderr)
    adapter = adapt(args.base, clips, args.out, cfg, name=args.name or args.out.stem, licence=args.licence.strip(),
                    work=args.work, resume=args.resume, progress=not args.no_progress,
                    stop_after=tuple(args.stop_after) if args.stop_after else None, source=source)
    if adapter is None:
        print(f"stopped; resume with --resume (work folder {args.work or str(args.out) + '.work'})")
        return
    size = args.out.stat().st_size / 2**20
    print(f"wrote {args.out} ({size:.1f} MB) in {time.perf_counter() - t0:.0f} s; use it with "
          f"`smf generate --adapter {args.out} \"...\"`")
    if not args.no_report:
        from ..adapters.report import write_report

        report = write_report(adapter, args.base, args.report or Path(str(args.out) + ".report"))
        print(f"report: {report}")
