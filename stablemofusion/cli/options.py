"""The flags `smf generate` and `smf edit` share (sampling, footskate, engine, output), with their defaults
from :mod:`stablemofusion.core.settings`, and the pipeline settings and writers built from them."""

from __future__ import annotations

import argparse
import contextlib
from pathlib import Path


def add_sampling_arguments(p: argparse.ArgumentParser) -> None:
    """--out, --format, --overwrite, --guidance, --steps, --sampler, --seed, --checkpoint, --teacher, --device,
    --engine and the footskate flags."""
    from ..core.limits import (DEFAULT_FORMATS, ENGINES, FOOTSKATE, FOOTSKATE_MODES, GUIDANCE, OUTPUT_FORMATS,
                          PORTABLE_ENGINE, SAMPLER, STEPS, STUDENT_EDIT_STEPS, STUDENT_SAMPLER)
    from .flags import add_teacher_flag

    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--format", default=DEFAULT_FORMATS, help=f"comma list of {','.join(OUTPUT_FORMATS)}")
    p.add_argument("--overwrite", action="store_true",
                   help="replace files of the same name (default: a free name, NAME-2, NAME-3, ...)")
    p.add_argument("--guidance", type=float, default=None,
                   help=f"classifier-free guidance scale (default: the model's: the scale its config names, else "
                        f"{GUIDANCE}; `smf info` shows it)")
    p.add_argument("--steps", type=int, default=None,
                   help=f"sampling steps (default: the model's: {STEPS}, a distilled student its own count; editing "
                        f"with a student at least {STUDENT_EDIT_STEPS})")
    p.add_argument("--sampler", default=None,
                   help=f"sampler name (default: the model's: {SAMPLER}, a distilled student {STUDENT_SAMPLER})")
    p.add_argument("--seed", type=int, default=None,
                   help="random seed (default: a fresh one, printed with each motion so that it can be made again)")
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or run folder (default: shipped model)")
    add_teacher_flag(p)
    add_adapter_flag(p)
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads for torch (default: OMP_NUM_THREADS if set, else the idle cores: the cores less "
                        "the 1-minute load average, at least 1)")
    p.add_argument("--engine", default="auto", choices=("auto",) + ENGINES + (PORTABLE_ENGINE,),
                   help="denoising engine (default auto: CUDA graphs on a GPU, the precomputed solver loop on a CPU; "
                        f"{PORTABLE_ENGINE}: the portable graphs on ONNX Runtime, docs/runtime.md; docs/inference.md)")
    p.add_argument("--footskate", default=FOOTSKATE, choices=FOOTSKATE_MODES,
                   help="footskate cleanup: off, post (after sampling) or loop (inside the last denoising steps); "
                        "post by default: the raw motion skates about 3 times as much as real motion "
                        "(docs/footskate.md)")
    add_contact_arguments(p)


def add_adapter_flag(p: argparse.ArgumentParser) -> None:
    """--adapter FILE (repeatable): adapters made by `smf adapt`, merged into the model at load."""
    p.add_argument("--adapter", type=Path, action="append", default=None,
                   help="an adapter file from `smf adapt` (your moves); repeat it to load several")


def add_contact_arguments(p: argparse.ArgumentParser) -> None:
    """--contacts, --vgrf-model, --underpressure: how the footskate cleanup finds contacts."""
    p.add_argument("--contacts", default="kinematic", choices=("kinematic", "vgrf"),
                   help="contact route for the cleanup (vgrf needs --vgrf-model or --underpressure)")
    p.add_argument("--vgrf-model", type=Path, default=None,
                   help="distilled 22-joint vGRF model (.safetensors): adds the vGRF loss (non-commercial)")
    p.add_argument("--underpressure", type=Path, default=None,
                   help="UnderPressure pretrained.tar used directly as vGRF model (non-commercial, slower)")


def footskate_options_from_args(args):
    """FootskateOptions from the flags of :func:`add_contact_arguments`."""
    from ..footskate import CleanupConfig, FootskateOptions
    from .footskate import vgrf_model_from_args

    model = None
    if args.vgrf_model is not None or args.underpressure is not None or args.contacts == "vgrf":
        model = vgrf_model_from_args(args.vgrf_model, args.underpressure, required=True)
    return FootskateOptions(config=CleanupConfig(contacts=args.contacts), vgrf_model=model)


def choose_engine(args, *, portable: bool = True, what: str = "this") -> None:
    """``--engine auto`` without PyTorch installed: the ONNX backend (``--engine onnx``) where the command runs on it
    (``portable``), else a one-line error naming the extra (``what`` needs PyTorch); a torch engine asked for by
    name without it: the same kind of error (:func:`~stablemofusion.backends.backend_for`)."""
    from ..backends import backend_for
    from ..core.errors import SMFError
    from ..core.limits import PORTABLE_ENGINE

    if backend_for(None, args.engine) == "torch" or args.engine != "auto":
        return
    if not portable:
        raise SMFError(f"{what} needs PyTorch, which this install lacks: pip install 'stablemofusion[train]' (the "
                       f"ONNX backend, --engine {PORTABLE_ENGINE}, makes text to motion and timelines)")
    args.engine = PORTABLE_ENGINE


def check_sampling(args) -> None:
    """The flags of :func:`add_sampling_arguments` against the limits, before anything heavy is imported."""
    from ..core.limits import check_footskate, check_guidance, check_seed, check_steps

    check_guidance(args.guidance)
    check_steps(args.steps)
    check_seed(args.seed)
    check_footskate(args.footskate)


def sampling_kwargs(args) -> dict:
    """The pipeline keywords of :func:`add_sampling_arguments`' flags (checked first: :func:`check_sampling`)."""
    options = footskate_options_from_args(args) if args.footskate != "off" else None
    return dict(guidance_scale=args.guidance, steps=args.steps, sampler=args.sampler, seed=args.seed,
                footskate=args.footskate, footskate_options=options, engine=args.engine)


def idle_threads() -> int:
    """The cores this process may run on less the 1-minute load average (other processes' running threads),
    at least 1: torch threads that do not fight a busy core (on this project's 2-core CPU with one core busy,
    `smf generate` took 19.5 s with two threads and 6.3 s with one; idle, 5.7 s either way)."""
    import os

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    try:
        busy = os.getloadavg()[0]
    except OSError:  # no load average on this platform
        busy = 0.0
    return max(1, min(cores, int(cores - busy + 0.5)))


def set_threads(args) -> None:
    """torch's CPU threads from ``--threads``, else OMP_NUM_THREADS when set, else :func:`idle_threads`."""
    import os

    import torch

    from .flags import apply_threads

    if args.threads is not None or "OMP_NUM_THREADS" in os.environ:
        apply_threads(args.threads)
    else:
        torch.set_num_threads(min(torch.get_num_threads(), idle_threads()))


def check_adapter_flags(args, *, teacher_part: bool = False) -> None:
    """The --adapter files checked against the model without PyTorch (:mod:`stablemofusion.adapters.check`), so that
    a crafted file is refused in one line before anything heavy loads: against ``--teacher``'s folder with
    ``--teacher``, and with ``teacher_part`` (export of a student) also their teacher part against its teacher. A
    folder that is not there is left to the loader, which names it."""
    if not getattr(args, "adapter", None):
        return
    from importlib import resources

    from ..adapters.check import check_adapter_files, teacher_of

    folder = Path(args.checkpoint) if args.checkpoint is not None else \
        Path(str(resources.files("stablemofusion") / "assets" / "default_model"))
    if getattr(args, "teacher", False):
        folder = teacher_of(folder)
    if folder is None or not ((folder / "config.json").is_file() or (folder / "checkpoint" / "config.json").is_file()):
        return
    check_adapter_files(args.adapter, folder)
    teacher = teacher_of(folder) if teacher_part else None
    if teacher is not None:
        check_adapter_files(args.adapter, teacher, "teacher")


def load_pipeline(args):
    """The pipeline of ``--checkpoint``/``--teacher`` on the backend ``--engine`` means
    (:func:`~stablemofusion.backends.backend_for`), saying on stderr what it loads (imports and loading take a few
    seconds on a first run). Adapter files are checked before PyTorch is imported."""
    import os

    from ..backends import backend_for
    from ..pipelines.motion_pipeline import MotionPipeline

    torch_backend = backend_for(None, args.engine) == "torch"
    if torch_backend:
        check_adapter_flags(args)  # before PyTorch is imported, and before the status line
    what = f"the model in {args.checkpoint}" if args.checkpoint is not None else "the shipped model"
    status = LoadingStatus(f"smf: loading {what}{' (its teacher)' if args.teacher else ''} and its text encoder ...")
    adapters = getattr(args, "adapter", None)
    if torch_backend:
        from ..adapters.file import checked_adapters
        from ..core.folders import model_folder

        set_threads(args)
        threads, options = None, {"device": args.device}
        if adapters:  # refused before the model loads
            adapters = checked_adapters(adapters, model_folder(args.checkpoint, teacher=args.teacher))
    else:  # one thread unless asked: ONNX Runtime's threads cost more than they give on small machines (docs/runtime.md)
        threads = args.threads or (int(os.environ["OMP_NUM_THREADS"]) if os.environ.get("OMP_NUM_THREADS", "").isdigit()
                                   else 1)
        options = {}
    pipe = MotionPipeline.from_pretrained(args.checkpoint, engine=args.engine, teacher=args.teacher, threads=threads,
                                          adapter=adapters, **options)
    if torch_backend:
        pipe.text_cache.encoder.load()  # now, under the status line, not inside the first generation
    status.done()
    return pipe


class LoadingStatus:
    """A status line on a terminal's stderr while something loads, erased when done (nothing when stderr is a
    file or a pipe: there stderr holds only warnings and errors, one line each)."""

    def __init__(self, text: str):
        import sys

        self.stream = sys.stderr
        self.shown = self.stream.isatty()
        if self.shown:
            self.stream.write(text)
            self.stream.flush()

    def done(self) -> None:
        if self.shown:
            self.stream.write("\r\033[K")
            self.stream.flush()


def output_meta(args, pipe, *, edit: bool = False) -> dict:
    """What the JSON output records of how a motion was made (the guidance, steps and sampler ``pipe`` resolves the
    flags to, on either backend; ``edit``: for an edit)."""
    from ..core.output import made_by
    from ..core.settings import Settings

    s = pipe.settings(Settings(guidance_scale=args.guidance, steps=args.steps, sampler=args.sampler), edit=edit)
    b = pipe.backend
    return {**made_by(b.version), "sampler": s.sampler, "steps": s.steps, "guidance": s.guidance_scale,
            "student": b.student, "adapters": list(b.adapters)}


@contextlib.contextmanager
def user_warnings():
    """Within it, the pipeline's warnings meant for users (engine, length, out of domain) are gathered and printed
    after on stderr, one line each, ``smf: warning: ...`` (stdout keeps the results alone)."""
    import sys
    import warnings

    from ..core.final import (EngineWarning, LengthClampedWarning, NotEnglishWarning, OutOfDomainWarning,
                              TaughtCaptionWarning, WeakActionWarning)

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    shown = (EngineWarning, LengthClampedWarning, NotEnglishWarning, OutOfDomainWarning, TaughtCaptionWarning,
             WeakActionWarning)
    for w in dict.fromkeys(str(c.message) for c in caught if issubclass(c.category, shown)):
        print(f"smf: warning: {w}", file=sys.stderr)
