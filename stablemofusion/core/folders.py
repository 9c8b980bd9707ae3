"""Model folders, read without torch: which folder a call means (the shipped model, a run's checkpoint, a student's
teacher), the text-side files that go with a model, and where its portable graphs are. One place for every
backend, the adapter checks and the command line."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

from .errors import SMFError
from ..text.names import GRAPHS_DIR

CONFIG = "config.json"  # a model folder's config
CHECKPOINT_DIR = "checkpoint"  # inside a training run folder, beside log.csv and text-cache/
MANIFEST = "graphs.json"  # a graphs folder's manifest (smf export --onnx)
# the shipped model's teacher is a distribution of its own (packaging/teacher), installed into the same folders
TEACHER_INSTALL = "pip install 'stablemofusion[teacher]'"


def default_model_path() -> Path | None:
    """The default model shipped inside the package, if any (a distilled student; its teacher in ``teacher/``)."""
    path = Path(str(resources.files("stablemofusion") / "assets" / "default_model"))
    return path if (path / CONFIG).is_file() else None


def resolve(path: str | Path) -> Path:
    """A checkpoint folder, or a training run folder holding one in ``checkpoint/``."""
    path = Path(path)
    if not (path / CONFIG).is_file() and (path / CHECKPOINT_DIR / CONFIG).is_file():
        return path / CHECKPOINT_DIR
    return path


def read_config_json(path: str | Path) -> dict:
    """The raw config (a dict) of a checkpoint, run or exported folder; SMFError when there is none or it is not
    a JSON object."""
    path = resolve(path)
    if not (path / CONFIG).is_file():
        raise SMFError(f"not a checkpoint folder (no {CONFIG}): {path}")
    try:
        config = json.loads((path / CONFIG).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SMFError(f"{path / CONFIG}: invalid JSON ({e})") from None
    if not isinstance(config, dict):
        raise SMFError(f"{path / CONFIG}: not a checkpoint config (not a JSON object)")
    return config


def is_student(path: str | Path) -> bool:
    """Whether the model in ``path`` is a distilled student (its config names what it was distilled from)."""
    return bool(read_config_json(path).get("distil"))


def teacher_folder(path: str | Path) -> Path:
    """The folder of the teacher that the distilled student in ``path`` names (``distil.teacher``: a relative
    name is relative to the student's folder, as in a release that ships its teacher in ``teacher/``).
    SMFError for a model that is not a student, or whose teacher is not there."""
    path = resolve(path)
    distil = read_config_json(path).get("distil")
    named = distil.get("teacher") if isinstance(distil, dict) else None
    if not isinstance(named, str) or not named:
        raise SMFError(f"{path} is not a distilled student: it has no teacher")
    named = Path(named)
    folder = resolve(named if named.is_absolute() else path / named)
    if not (folder / CONFIG).is_file():
        raise SMFError(f"the teacher of {path} is not there: {folder} (the shipped model's teacher is installed with "
                       f"{TEACHER_INSTALL})")
    return folder


def model_folder(path: str | Path | None = None, *, teacher: bool = False) -> Path:
    """The one place that says which model folder a call means: ``path`` (``None``: the shipped default model),
    or with ``teacher`` the teacher that model was distilled from (SMFError for a model without one)."""
    if path is None:
        path = default_model_path()
        if path is None:
            raise SMFError("no default model is shipped in this version; pass a checkpoint folder")
    return teacher_folder(path) if teacher else Path(path)


def companion_file(path: str | Path, name: str) -> Path | None:
    """The file ``name`` that goes with the model in ``path`` (the text side: length estimator, known actions):
    the model folder's own; else, for a teacher shipped inside its student's folder (the parent folder is a
    student whose ``distil.teacher`` is this folder), the student's. None when neither has it."""
    path = resolve(path)
    if (path / name).is_file():
        return path / name
    parent = path.resolve().parent
    if not (parent / CONFIG).is_file() or not (parent / name).is_file():
        return None
    try:
        named = teacher_folder(parent)
    except SMFError:  # the parent is no student, or names a teacher that is not there
        return None
    return parent / name if named.resolve() == path.resolve() else None


def companion_files(path: str | Path, names) -> dict[str, Path]:
    """:func:`companion_file` for each of ``names``: those found (name -> file)."""
    found = {name: companion_file(path, name) for name in names}
    return {name: f for name, f in found.items() if f is not None}


def graphs_of(path: str | Path) -> tuple[Path, dict] | None:
    """The portable graphs that hold the weights of the model folder ``path`` (``smf export --onnx`` records where
    each weight lies: ``weights`` in its manifest entry): (the folder of its graphs, its manifest entry), or None.
    A model's graphs are in its ``onnx/``; a teacher shipped inside its student's folder has its graphs in the
    student's ``onnx/`` under the teacher's folder name."""
    path = resolve(path)
    for folder, name in ((path / GRAPHS_DIR, "model"), (path.parent / GRAPHS_DIR, "teacher")):
        try:
            manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError, UnicodeDecodeError):
            continue
        entry = manifest.get(name) if isinstance(manifest, dict) else None
        if not isinstance(entry, dict) or not isinstance(entry.get("weights"), dict):
            continue
        if name == "teacher":  # only the teacher its student names, in the folder the graphs name
            if entry.get("folder") != path.name or not (path.parent / CONFIG).is_file():
                continue
            try:
                if teacher_folder(path.parent).resolve() != path.resolve():
                    continue
            except SMFError:
                continue
            folder = folder / entry["folder"]
        return folder, entry
    return None


__all__ = ["CHECKPOINT_DIR", "CONFIG", "MANIFEST", "TEACHER_INSTALL", "companion_file", "companion_files",
           "default_model_path", "graphs_of", "is_student", "model_folder", "read_config_json", "resolve",
           "teacher_folder"]
