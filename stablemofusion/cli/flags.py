"""Command-line flags from a settings dataclass: one ``--field-name`` per field, and the dataclass back."""

from __future__ import annotations

import argparse
from dataclasses import MISSING, fields


def add_config_flags(p: argparse.ArgumentParser, cls: type, helps: dict[str, str],
                     types: dict[str, type] | None = None) -> None:
    """A flag for each field of dataclass ``cls`` named in ``helps`` (its help text), defaulting to the field's
    default: booleans are switches (--no-NAME turns off one that is on by default); a field whose default is None
    takes ``types[name]`` or an int."""
    for f in fields(cls):
        if f.name not in helps:
            continue
        default = f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]
        flag = "--" + f.name.replace("_", "-")
        if isinstance(default, bool):
            p.add_argument(flag, action=argparse.BooleanOptionalAction if default else "store_true", default=default,
                           help=helps[f.name])
        else:
            kind = (types or {}).get(f.name) or (int if default is None else type(default))
            p.add_argument(flag, type=kind, default=default, help=helps[f.name])


def config_from_args(cls: type, args: argparse.Namespace, helps: dict[str, str]):
    """The dataclass ``cls`` built from the flags :func:`add_config_flags` added (other fields keep defaults)."""
    return cls(**{name: getattr(args, name) for name in helps})


def apply_threads(threads: int | None) -> None:
    """Set torch's CPU threads from a ``--threads`` value (None: leave them); a one-line error below 1."""
    if threads is None:
        return
    if threads < 1:
        from ..core.errors import SMFError

        raise SMFError(f"--threads must be at least 1, got {threads}")
    import torch

    torch.set_num_threads(threads)


def add_teacher_flag(p: argparse.ArgumentParser) -> None:
    """``--teacher``: the model's teacher instead of the distilled student (commands that take ``--checkpoint``)."""
    from ..core.limits import STEPS

    p.add_argument("--teacher", action="store_true",
                   help=f"sample with the model's {STEPS}-step teacher instead of its distilled student (the teacher "
                        "the student's folder names; the shipped default model has one)")


def add_overwrite_flag(p: argparse.ArgumentParser) -> None:
    """``--overwrite``: for commands whose output file is named on the command line."""
    p.add_argument("--overwrite", action="store_true", help="replace the output file if it exists (default: refuse)")


def check_new_output(path, overwrite: bool) -> None:
    """SMFError if ``path`` exists and ``overwrite`` is off: an output named by the user is never replaced silently."""
    from ..core.errors import SMFError

    if not overwrite and path.exists():
        raise SMFError(f"{path} exists; give another output name, or --overwrite to replace it")
