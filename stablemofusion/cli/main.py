"""The `smf` command: one small module per subcommand, each with ``add_parser`` and ``run``."""

from __future__ import annotations

import argparse
import importlib
import sys

from .. import __version__
from ..errors import SMFError

# subcommand name -> module under stablemofusion.cli
COMMANDS = {
    "render": "render",
    "convert": "convert",
    "prepare": "prepare",
    "train": "train",
    "distil": "distil",
    "curve": "curve",
    "info": "info",
    "generate": "generate",
    "edit": "edit",
    "bench": "bench",
    "footskate": "footskate",
    "train-evaluator": "train_evaluator",
    "train-classifier": "train_classifier",
    "train-length": "train_length",
    "evaluate": "evaluate",
    "export": "export",
    "ablate": "ablate",
    "serve": "serve",
    "addon": "addon",
}


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose usage errors are one line (exit code 2)."""

    def error(self, message: str):  # noqa: D102
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="smf", description="StableMoFusion: text to human motion.")
    parser.add_argument("--version", action="version", version=f"smf {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module in COMMANDS.items():
        importlib.import_module(f"{__package__}.{module}").add_parser(sub, name)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point: bad input prints one line 'smf: error: ...' and returns exit code 2."""
    parser = build_parser()
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
    return 0


if __name__ == "__main__":
    sys.exit(main())
