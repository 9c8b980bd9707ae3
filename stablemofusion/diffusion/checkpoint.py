"""Checkpoint folders: model + EMA weights (safetensors), config JSON, Mean/Std, optional training state.

A folder alone rebuilds its pipeline: ``config.json`` is a :class:`CheckpointConfig` (model, schedule, text
encoder, skeleton, frame rate and length range, training settings); ``Mean.npy``/``Std.npy`` the normalisation (Std already divided by the feature bias).
Folders are written to a temporary sibling and renamed into place, so a crash never leaves a half folder.

A distilled student names its teacher (``distil.teacher``, :func:`teacher_folder`); a release may ship the teacher
inside the student's folder (``teacher/``, :func:`export_checkpoint`), where it uses the student's text-side files
(:func:`companion_file`).
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from ..core.errors import SMFError
from ..models.base import Denoiser
from ..models.registry import build_denoiser
from ..core.folders import (CHECKPOINT_DIR, CONFIG, companion_file, companion_files, graphs_of,  # noqa: F401
                            read_config_json, resolve, teacher_folder)
from .config import CheckpointConfig, ExportInfo, check_guidance

MODEL = "model.safetensors"
EMA = "ema.safetensors"
STATE = "training_state.pt"
TEACHER_DIR = "teacher"  # inside a released student's folder: the teacher it was distilled from (smf export)


@dataclass
class Checkpoint:
    """A loaded checkpoint: the denoiser (EMA weights unless asked otherwise) and its metadata."""

    model: Denoiser
    config: CheckpointConfig
    mean: np.ndarray
    std: np.ndarray
    path: Path


def _contiguous(sd: dict[str, torch.Tensor], dtype: torch.dtype | None = None) -> dict[str, torch.Tensor]:
    return {k: (v.to(dtype) if dtype is not None and v.is_floating_point() else v).detach().cpu().contiguous()
            for k, v in sd.items()}


def save_checkpoint(path: str | Path, *, model: Denoiser, config: CheckpointConfig, mean: np.ndarray, std: np.ndarray,
                    ema_state: dict[str, torch.Tensor] | None = None, training_state: dict | None = None,
                    dtype: torch.dtype | None = None, extra_files: dict[str, str] | None = None) -> Path:
    """Write a checkpoint folder atomically (replacing ``path`` if it exists); ``extra_files``: name -> text."""
    from ..core.io import atomic_dir

    with atomic_dir(path) as tmp:
        _write_checkpoint(tmp, model=model, config=config, mean=mean, std=std, ema_state=ema_state,
                          training_state=training_state, dtype=dtype, extra_files=extra_files)
    return Path(path)


def _write_checkpoint(folder: Path, *, model: Denoiser, config: CheckpointConfig, mean: np.ndarray, std: np.ndarray,
                      ema_state: dict[str, torch.Tensor] | None = None, training_state: dict | None = None,
                      dtype: torch.dtype | None = None, extra_files: dict[str, str] | None = None) -> None:
    """The files of a checkpoint in ``folder`` (created; the caller makes the whole folder atomic)."""
    folder.mkdir(parents=True, exist_ok=True)
    save_file(_contiguous(model.state_dict(), dtype), folder / MODEL)
    if ema_state is not None:
        save_file(_contiguous(ema_state, dtype), folder / EMA)
    (folder / CONFIG).write_text(json.dumps(config.to_dict(), indent=2) + "\n")
    np.save(folder / "Mean.npy", np.asarray(mean, dtype=np.float32))
    np.save(folder / "Std.npy", np.asarray(std, dtype=np.float32))
    if training_state is not None:
        torch.save(training_state, folder / STATE)
    for name, text in (extra_files or {}).items():
        (folder / name).write_text(text, encoding="utf-8")


def read_config(path: str | Path) -> CheckpointConfig:
    """The config of a checkpoint, run or exported folder (its raw JSON read by
    :func:`~stablemofusion.core.folders.read_config_json`)."""
    path = resolve(path)
    return CheckpointConfig.from_dict(read_config_json(path), where=str(path / CONFIG))


def weights_from_graphs(folder: Path, entry: dict) -> dict[str, torch.Tensor]:
    """A model's weights read from its portable graphs (:func:`graphs_of`) as float32 tensors: each one the
    initialiser its manifest entry names, transposed where it says 'T', in the weight's shape."""
    import onnx
    from onnx import numpy_helper

    where = entry["weights"]
    graphs = {}
    for f in sorted({w[0] for w in where.values()}):
        if Path(f).name != f or not (folder / f).is_file():
            raise SMFError(f"{folder}: the graph {f!r} named by its weights is not there")
        graphs[f] = {i.name: i for i in onnx.load(str(folder / f)).graph.initializer}
    out = {}
    for key, (f, name, layout, shape) in where.items():
        if name not in graphs[f]:
            raise SMFError(f"{folder / f}: no initialiser {name!r} (the weight {key})")
        arr = numpy_helper.to_array(graphs[f][name]).astype(np.float32)
        arr = arr.T if layout == "T" else arr
        if arr.size != int(np.prod(shape)):
            raise SMFError(f"{folder / f}: the initialiser {name!r} does not hold the weight {key} {tuple(shape)}")
        out[key] = torch.from_numpy(np.ascontiguousarray(arr).reshape(shape))
    return out


def load_weights(path: str | Path, *, ema: bool = True) -> dict[str, torch.Tensor]:
    """The (EMA) weights of a checkpoint, run or exported folder as float32 tensors; a folder without a weights
    file (the shipped model) reads them from its portable graphs (:func:`graphs_of`), shaped by the caller."""
    path = resolve(path)
    read_config(path)
    weights = path / (EMA if ema and (path / EMA).is_file() else MODEL)
    if not weights.is_file():
        graphs = graphs_of(path)
        if graphs is None:
            raise SMFError(f"checkpoint has no weights file {weights}")
        return weights_from_graphs(*graphs)
    return {k: v.float() if v.is_floating_point() else v for k, v in load_file(weights).items()}


def load_checkpoint(path: str | Path, *, ema: bool = True, device: str | torch.device = "cpu") -> Checkpoint:
    """Rebuild the denoiser of a checkpoint folder and load its (EMA) weights, in float32, eval mode."""
    path = resolve(path)
    config = read_config(path)
    model = build_denoiser(config.model)
    weights = path / (EMA if ema and (path / EMA).is_file() else MODEL)
    state = load_weights(path, ema=ema)
    missing, unexpected = model.load_state_dict(state, strict=False)
    if missing or unexpected:
        raise SMFError(f"{weights}: weights do not fit the config (missing {missing[:3]}, unexpected {unexpected[:3]})")
    for f in ("Mean.npy", "Std.npy"):
        if not (path / f).is_file():
            raise SMFError(f"checkpoint has no {f}: {path}")
    return Checkpoint(model.to(device).eval(), config, np.load(path / "Mean.npy"), np.load(path / "Std.npy"), path)


def load_training_state(path: str | Path) -> dict:
    """The optimiser/scheduler/EMA/RNG/step state saved with a training checkpoint."""
    f = Path(path) / STATE
    if not f.is_file():
        raise SMFError(f"cannot resume: no {STATE} in {path}")
    return torch.load(f, map_location="cpu", weights_only=False)


def export_checkpoint(src: str | Path, dst: str | Path, *, dtype: torch.dtype = torch.float16,
                      extra_files: dict[str, str] | None = None, teacher: str | Path | None = None,
                      copy_files: dict[str, Path] | None = None, guidance: float | None = None) -> Path:
    """Write a release folder from a checkpoint: the EMA weights only (as ``model.safetensors`` in ``dtype``),
    config.json, Mean/Std, ``extra_files`` (name -> text, e.g. a model card) and ``copy_files`` (name -> a file
    copied in, e.g. the length estimator). No optimiser state. ``teacher``: for a distilled student, its teacher
    folder, exported the same way into ``TEACHER_DIR`` inside the release, which the student's
    ``distil.teacher`` then names (relative, so the release can move); it keeps its own default guidance.
    ``guidance``: the model's default guidance scale recorded in its config (None: the source's). One atomic
    folder."""
    from ..core.io import atomic_dir

    ck = load_checkpoint(src, ema=True)
    config = _exported(ck.config, dtype)
    if guidance is not None:
        config = replace(config, guidance=check_guidance(guidance, "the exported config"))
    shipped = None
    if teacher is not None:
        if not ck.config.student:
            raise SMFError(f"{src} is not a distilled student: only a student ships its teacher")
        shipped = load_checkpoint(teacher, ema=True)
        check_teacher(ck, shipped)
        config = replace(config, distil=replace(config.distil, teacher=TEACHER_DIR))
    elif ck.config.student and not Path(ck.config.distil.teacher).is_absolute():
        # a name relative to the source folder: the release, elsewhere, names the same teacher absolutely
        named = (ck.path / ck.config.distil.teacher).resolve()
        config = replace(config, distil=replace(config.distil, teacher=str(named)))
    for name, f in (copy_files or {}).items():
        if not Path(f).is_file():
            raise SMFError(f"no such file to copy into the release: {f}")
    with atomic_dir(dst) as tmp:
        _write_checkpoint(tmp, model=ck.model, config=config, mean=ck.mean, std=ck.std, dtype=dtype,
                          extra_files=extra_files)
        for name, f in (copy_files or {}).items():
            shutil.copyfile(f, tmp / name)
        if shipped is not None:
            _write_checkpoint(tmp / TEACHER_DIR, model=shipped.model, config=_exported(shipped.config, dtype),
                              mean=shipped.mean, std=shipped.std, dtype=dtype)
    return Path(dst)


def _exported(config: CheckpointConfig, dtype: torch.dtype) -> CheckpointConfig:
    version = config.export.version if config.export is not None else None  # a release exported again keeps its name
    return replace(config, export=ExportInfo(from_step=config.step, dtype=str(dtype).replace("torch.", ""),
                                             version=version))


def check_teacher(student: Checkpoint, teacher: Checkpoint) -> None:
    """SMFError unless ``teacher`` can be ``student``'s teacher: an ordinary model of the student's architecture
    (without the guidance input), noise schedule, text encoder, skeleton and normalisation."""
    if teacher.config.student:
        raise SMFError(f"{teacher.path} is itself a distilled student, not a teacher")
    s, t = student.config, teacher.config
    differ = [name for name, a, b in (
        ("architecture", replace(s.model, guidance=False).to_dict(), t.model.to_dict()),
        ("noise schedule", asdict(s.schedule), asdict(t.schedule)), ("text encoder", s.text_encoder, t.text_encoder),
        ("skeleton", s.skeleton, t.skeleton)) if json.dumps(a, sort_keys=True) != json.dumps(b, sort_keys=True)]
    if not (np.array_equal(student.mean, teacher.mean) and np.array_equal(student.std, teacher.std)):
        differ.append("Mean/Std")
    if differ:
        raise SMFError(f"{teacher.path} cannot be the teacher of {student.path}: {', '.join(differ)} differ")
