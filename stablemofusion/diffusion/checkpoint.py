"""Checkpoint folders: model + EMA weights (safetensors), config JSON, Mean/Std, optional training state.

A folder alone rebuilds its pipeline: ``config.json`` is a :class:`CheckpointConfig` (model, schedule, text
encoder, skeleton, frame rate and length range, training settings); ``Mean.npy``/``Std.npy`` the normalisation (Std already divided by the feature bias).
Folders are written to a temporary sibling and renamed into place, so a crash never leaves a half folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file

from ..errors import SMFError
from ..models.base import Denoiser, build_denoiser
from .config import CheckpointConfig, ExportInfo

CONFIG = "config.json"
MODEL = "model.safetensors"
EMA = "ema.safetensors"
STATE = "training_state.pt"
CHECKPOINT_DIR = "checkpoint"  # inside a training run folder, beside log.csv and text-cache/


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
    from ..io import atomic_dir

    with atomic_dir(path) as tmp:
        save_file(_contiguous(model.state_dict(), dtype), tmp / MODEL)
        if ema_state is not None:
            save_file(_contiguous(ema_state, dtype), tmp / EMA)
        (tmp / CONFIG).write_text(json.dumps(config.to_dict(), indent=2) + "\n")
        np.save(tmp / "Mean.npy", np.asarray(mean, dtype=np.float32))
        np.save(tmp / "Std.npy", np.asarray(std, dtype=np.float32))
        if training_state is not None:
            torch.save(training_state, tmp / STATE)
        for name, text in (extra_files or {}).items():
            (tmp / name).write_text(text, encoding="utf-8")
    return Path(path)


def resolve(path: str | Path) -> Path:
    """A checkpoint folder, or a training run folder holding one in ``checkpoint/``."""
    path = Path(path)
    if not (path / CONFIG).is_file() and (path / CHECKPOINT_DIR / CONFIG).is_file():
        return path / CHECKPOINT_DIR
    return path


def read_config(path: str | Path) -> CheckpointConfig:
    """The config of a checkpoint, run or exported folder."""
    path = resolve(path)
    if not (path / CONFIG).is_file():
        raise SMFError(f"not a checkpoint folder (no {CONFIG}): {path}")
    try:
        config = json.loads((path / CONFIG).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SMFError(f"{path / CONFIG}: invalid JSON ({e})") from None
    return CheckpointConfig.from_dict(config, where=str(path / CONFIG))


def load_weights(path: str | Path, *, ema: bool = True) -> dict[str, torch.Tensor]:
    """The (EMA) weights of a checkpoint, run or exported folder as float32 tensors."""
    path = resolve(path)
    read_config(path)
    weights = path / (EMA if ema and (path / EMA).is_file() else MODEL)
    if not weights.is_file():
        raise SMFError(f"checkpoint has no weights file {weights}")
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
                      extra_files: dict[str, str] | None = None) -> Path:
    """Write a release folder from a checkpoint: the EMA weights only (as ``model.safetensors`` in ``dtype``),
    config.json, Mean/Std and ``extra_files`` (name -> text, e.g. a model card). No optimiser state."""
    ck = load_checkpoint(src, ema=True)
    config = replace(ck.config, export=ExportInfo(from_step=ck.config.step, dtype=str(dtype).replace("torch.", "")))
    return save_checkpoint(dst, model=ck.model, config=config, mean=ck.mean, std=ck.std, dtype=dtype,
                           extra_files=extra_files)
