"""`smf generate "TEXT" [--seconds S] --out DIR [--format npy,bvh,glb] ...`: text to motion files."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..core.limits import MAX_PROMPT_CHARS

MAX_PATH_FILE_BYTES = 256 * 1024  # the most a --path file may hold
MAX_PROMPTS_FILE_BYTES = 64 * 2**20  # the most a --prompts file may hold (about 200,000 long prompts)


def add_parser(sub, name: str) -> None:
    from ..core.limits import BATCH_SIZE
    from .character import add_character_arguments
    from .options import add_sampling_arguments
    from .robot import add_robot_arguments

    p = sub.add_parser(name,
                       description="Generate one motion per prompt and write its files (by default joints and features "
                                   ".npy, BVH and glTF .glb; --format adds JSON or a rendered gif or mp4).")
    p.add_argument("text", nargs="?", default=None, help="the prompt (or use --prompts FILE)")
    p.add_argument("--prompts", type=Path, default=None, help="file with one prompt per line")
    p.add_argument("--timeline", default=None,
                   help="one continuous motion from segments 'PROMPT:SECONDS; PROMPT:SECONDS; ...' (any total length)")
    p.add_argument("--seconds", type=float, default=None,
                   help="length of each motion (default: predicted from the text by the model's length estimator; "
                        "4 s for a model without one); not with --timeline, whose segments give their own")
    p.add_argument("--path", type=Path, default=None, metavar="FILE.json",
                   help="a root path to follow: JSON [[x, z], ...] waypoints in metres (Y up), or {\"points\": [...], "
                        "\"times\": [seconds, ...]}; the length is the path's unless --seconds is given (docs/paths.md)")
    p.add_argument("--batch-size", type=int, default=BATCH_SIZE, help="prompts generated together")
    add_sampling_arguments(p)
    add_character_arguments(p, reads_motion=False)
    add_robot_arguments(p)
    p.set_defaults(func=run)


def read_prompts(args) -> list[str]:
    """The prompts of the command line (a text, --prompts FILE or --timeline), checked."""
    from ..core.errors import SMFError
    from ..core.limits import check_seconds

    if sum(x is not None for x in (args.text, args.prompts, args.timeline)) != 1:
        raise SMFError("give one of: a prompt text, --prompts FILE, --timeline 'PROMPT:SECONDS; ...'")
    if args.timeline is not None and args.seconds is not None:
        raise SMFError("--seconds does not apply to --timeline: give each segment its seconds ('PROMPT:SECONDS; ...')")
    check_seconds(args.seconds, "--seconds")
    if args.prompts is not None:
        return read_prompts_file(args.prompts)
    if args.timeline is not None:
        from ..core.timeline_plan import check_timeline, parse_timeline

        return [p for p, _ in check_timeline(parse_timeline(args.timeline))]  # refused before the model loads
    if not args.text.strip():
        raise SMFError("the prompt is empty")
    return [args.text]


def read_prompts_file(path: Path) -> list[str]:
    """The prompts of a file, one a line (blank lines skipped), read bounded and checked."""
    from ..core.errors import SMFError

    if not path.is_file():
        raise SMFError(f"no such file: {path}")
    if path.stat().st_size > MAX_PROMPTS_FILE_BYTES:
        raise SMFError(f"{path}: a prompts file is at most {MAX_PROMPTS_FILE_BYTES // 2**20} MB "
                       f"(one prompt of at most {MAX_PROMPT_CHARS} characters a line)")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as e:
        raise SMFError(f"{path}: not UTF-8 text (byte {e.start}); save the prompts file as UTF-8") from None
    prompts = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not prompts:
        raise SMFError(f"{path} holds no prompts")
    return prompts


def read_path(path: Path | None):
    """The waypoints of ``--path FILE.json`` (read bounded, checked), or None."""
    if path is None:
        return None
    import json

    from ..core.errors import SMFError
    from ..core.path_plan import Waypoints

    if not path.is_file():
        raise SMFError(f"no such file: {path}")
    if path.stat().st_size > MAX_PATH_FILE_BYTES:
        raise SMFError(f"{path}: a path file is at most {MAX_PATH_FILE_BYTES // 1024} KiB")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SMFError(f"{path}: not a JSON path ({e})") from None
    except RecursionError:
        raise SMFError(f"{path}: not a JSON path (nested too deeply)") from None
    return Waypoints.read(data)



def run(args: argparse.Namespace) -> None:
    from .options import check_sampling

    check_sampling(args)  # before the heavy imports below: a bad flag is answered at once
    from ..core.output import parse_formats, write_results
    from .character import load_rig
    from .options import choose_engine, load_pipeline, output_meta, sampling_kwargs, user_warnings
    from .robot import robot_formats, write_robot_files

    choose_engine(args)
    formats = parse_formats(args.format)
    rig = load_rig(args)  # checked before the model loads
    robot = robot_formats(args)
    prompts = read_prompts(args)
    path = read_path(args.path)
    if path is not None and args.timeline is not None:
        from ..core.errors import SMFError

        raise SMFError("--path does not apply to --timeline: give the path to a prompt")
    kwargs = sampling_kwargs(args)
    pipe = load_pipeline(args)
    meta = output_meta(args, pipe)
    if args.timeline is not None:
        from ..core.timeline_plan import parse_timeline

        with user_warnings():
            results = [pipe.timeline(parse_timeline(args.timeline), progress=None, **kwargs)]
        stems = write_results(results, args.out, formats, meta, overwrite=args.overwrite, rig=rig)
        for r, stem in zip(results, stems if robot else []):
            write_robot_files(args, r.joints, r.fps, r.contacts, stem, robot, meta)
        return
    # one batch at a time, each written before the next is made: memory stays that of one batch, files appear as it
    # goes (batch k uses seed + k, as one call of all the prompts does)
    from tqdm import tqdm

    n = len(prompts)
    seed = kwargs.pop("seed")
    bar = tqdm(total=n, unit="motion", desc="generate", disable=n <= args.batch_size, file=sys.stderr)
    for k, start in enumerate(range(0, n, args.batch_size)):
        batch = prompts[start:start + args.batch_size]
        with user_warnings():
            results = pipe(batch, seconds=args.seconds, batch_size=args.batch_size, progress=1 < n <= args.batch_size,
                           path=path, seed=None if seed is None else seed + k, **kwargs)
        for r in results:
            if r.sequence:
                parts = "; ".join(f"{p!r} {s:.1f} s" for p, s in r.sequence)
                print(f"smf: note: {r.prompt!r} asks for one thing after another: made as a timeline of {parts}",
                      file=sys.stderr)
        stems = write_results(results, args.out, formats, meta, overwrite=args.overwrite, rig=rig, first=start)
        for r, stem in zip(results, stems if robot else []):
            write_robot_files(args, r.joints, r.fps, r.contacts, stem, robot, meta)
        bar.update(len(batch))
    bar.close()
