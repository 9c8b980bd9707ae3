"""A 22-joint vGRF model distilled from UnderPressure on our corpus (the paper's step).

The student reads our joints directly (metres, Y up, 20 fps) and is trained to match the UnderPressure
teacher fed the retargeted, 100-fps version of the same motion. It is saved as ``NAME.safetensors`` plus
``NAME.json`` (architecture, training figures and the licence note: derived from UnderPressure, so
non-commercial research use only).
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..core.errors import SMFError
from ..core.io import atomic_path, write_text
from .underpressure import LICENCE_NOTE, UnderPressureNet, vgrf_from_joints22


@dataclass(frozen=True)
class StudentConfig:
    hidden: int = 96
    kernel: int = 5
    layers: int = 3
    fps: float = 20.0


class VgrfStudent(nn.Module):
    """(B, T, 22, 3) joints (m, Y up, 20 fps) -> (B, T, 2, 16) vGRF (body weight, foot 0 = left).

    Input per frame: joints relative to the root's ground projection (66) and the root's horizontal
    velocity in m/s (2), so the model does not depend on where the motion stands.
    """

    def __init__(self, config: StudentConfig = StudentConfig()):
        super().__init__()
        self.config = config
        chans = [68] + [config.hidden] * config.layers
        self.convs = nn.ModuleList(nn.Conv1d(a, b, config.kernel, padding=config.kernel // 2,
                                             padding_mode="replicate") for a, b in zip(chans[:-1], chans[1:]))
        self.head = nn.Linear(config.hidden, 32)
        with torch.no_grad():  # start near the standing average (1/32 body weight per cell), not saturated
            self.head.weight.mul_(0.1)
            self.head.bias.fill_(float(np.log(np.expm1(1.0 / 32))))

    def forward(self, joints: torch.Tensor) -> torch.Tensor:
        B, T = joints.shape[:2]
        ground = joints[:, :, :1] * joints.new_tensor([1.0, 0.0, 1.0])
        rel = (joints - ground).reshape(B, T, 66)
        root = joints[:, :, 0, [0, 2]]
        vel = torch.cat([root[:, 1:2] - root[:, :1], root[:, 1:] - root[:, :-1]], 1) * self.config.fps
        h = torch.cat([rel, vel], -1).transpose(1, 2)
        for conv in self.convs:
            h = nn.functional.elu(conv(h))
        return nn.functional.softplus(self.head(h.transpose(1, 2))).reshape(B, T, 2, 16)


def save_vgrf_model(model: VgrfStudent, path: str | Path, info: dict | None = None) -> None:
    """Write ``path`` (.safetensors) and the JSON config beside it (same stem)."""
    from safetensors.torch import save

    path = Path(path).with_suffix(".safetensors")
    with atomic_path(path) as tmp:
        tmp.write_bytes(save({k: v.detach().float().contiguous() for k, v in model.state_dict().items()}))
    meta = {"kind": "stablemofusion-vgrf-student", "config": asdict(model.config), "licence": LICENCE_NOTE,
            "output": "vGRF (T, 2 feet [left, right], 16 insole cells), fraction of body weight",
            **(info or {})}
    write_text(path.with_suffix(".json"), json.dumps(meta, indent=2) + "\n")


def load_vgrf_model(path: str | Path) -> VgrfStudent:
    """Load a distilled model (.safetensors with its .json). Non-commercial: derived from UnderPressure."""
    from safetensors.torch import load_file

    path = Path(path)
    if path.suffix != ".safetensors":
        path = path.with_suffix(".safetensors")
    meta_path = path.with_suffix(".json")
    if not path.is_file() or not meta_path.is_file():
        raise SMFError(f"vGRF model not found: {path} (and its .json)")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        model = VgrfStudent(StudentConfig(**meta["config"]))
        model.load_state_dict(load_file(str(path)))
    except Exception as e:  # noqa: BLE001
        raise SMFError(f"{path}: not a distilled vGRF model ({e.__class__.__name__})") from None
    return model.eval()


def shipped_vgrf_model_path() -> Path | None:
    """The distilled model shipped in the package (assets/vgrf), if any."""
    from importlib import resources

    p = Path(str(resources.files("stablemofusion") / "assets" / "vgrf" / "vgrf22.safetensors"))
    return p if p.is_file() else None


def teacher_labels(teacher: UnderPressureNet, motions: list[np.ndarray], fps: float = 20.0) -> list[np.ndarray]:
    """UnderPressure vGRF (T, 2, 16) at ``fps`` for each of our motions (T, 22, 3)."""
    return [vgrf_from_joints22(teacher, m, fps).astype(np.float32) for m in motions]


def _random_yaw(x: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    a = torch.rand(x.shape[0], generator=gen) * 2 * np.pi
    c, s = torch.cos(a)[:, None, None], torch.sin(a)[:, None, None]
    out = x.clone()
    out[..., 0] = c * x[..., 0] + s * x[..., 2]
    out[..., 2] = -s * x[..., 0] + c * x[..., 2]
    return out


def distil(teacher: UnderPressureNet, train: list[np.ndarray], val: list[np.ndarray], *, steps: int = 3000,
           batch: int = 32, crop: int = 64, lr: float = 1e-3, seed: int = 0, config: StudentConfig = StudentConfig(),
           log=print) -> tuple[VgrfStudent, dict]:
    """Train a student on motions (T, 22, 3) at 20 fps to match the teacher; returns (model, figures)."""
    t0 = time.perf_counter()
    train = [m for m in train if len(m) >= 8]
    if not train:
        raise SMFError("no training motions (need at least 8 frames each)")
    y_train, y_val = teacher_labels(teacher, train, config.fps), teacher_labels(teacher, val, config.fps)
    label_s = time.perf_counter() - t0
    gen = torch.Generator().manual_seed(seed)
    torch.manual_seed(seed)
    model = VgrfStudent(config)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps, pct_start=0.1)
    weights = np.array([len(m) for m in train], dtype=np.float64)
    weights /= weights.sum()
    rng = np.random.default_rng(seed)
    for step in range(steps):
        xs, ys = [], []
        for i in rng.choice(len(train), size=batch, p=weights):
            m, y = train[i], y_train[i]
            n = min(crop, len(m))
            a = rng.integers(0, len(m) - n + 1)
            pad = crop - n  # short motions: hold the last frame
            xs.append(np.concatenate([m[a:a + n], np.repeat(m[a + n - 1:a + n], pad, 0)]))
            ys.append(np.concatenate([y[a:a + n], np.repeat(y[a + n - 1:a + n], pad, 0)]))
        x = _random_yaw(torch.as_tensor(np.stack(xs), dtype=torch.float32), gen)
        pred, y = model(x), torch.as_tensor(np.stack(ys))
        loss = nn.functional.mse_loss(pred, y) + nn.functional.mse_loss(pred.sum(-1), y.sum(-1)) / 16
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if log and (step % 500 == 0 or step == steps - 1):
            log(f"step {step}: loss {loss.item():.5f}")
    model.eval()
    figures = {"train_motions": len(train), "val_motions": len(val), "steps": steps,
               "label_seconds": round(label_s, 1), "seconds": round(time.perf_counter() - t0, 1),
               **evaluate_student(model, val, y_val)}
    return model, figures


@torch.no_grad()
def evaluate_student(model: nn.Module, motions: list[np.ndarray], labels: list[np.ndarray]) -> dict:
    """Per-foot total vGRF RMSE (body weight) and correlation of the student against teacher labels."""
    if not motions:
        return {}
    p = np.concatenate([model(torch.as_tensor(m, dtype=torch.float32)[None])[0].sum(-1).numpy() for m in motions])
    t = np.concatenate([y.sum(-1) for y in labels])
    cell = np.concatenate([(model(torch.as_tensor(m, dtype=torch.float32)[None])[0].numpy() - y).ravel()
                           for m, y in zip(motions, labels)])
    return {"val_foot_rmse": float(np.sqrt(((p - t) ** 2).mean())),
            "val_foot_corr": float(np.corrcoef(p.ravel(), t.ravel())[0, 1]),
            "val_cell_rmse": float(np.sqrt((cell ** 2).mean()))}


def load_corpus_joints(data: str | Path, split: str, limit: int | None = None) -> list[np.ndarray]:
    """Joints (T, 22, 3) of a HumanML3D-layout folder's split (``new_joints/<id>.npy`` listed in ``split``.txt)."""
    data = Path(data)
    ids_file = data / f"{split}.txt"
    if not ids_file.is_file():
        raise SMFError(f"no split file {ids_file}")
    ids = [s for s in ids_file.read_text(encoding="utf-8").split() if s]
    if limit is not None:
        ids = ids[:limit]
    out = []
    for i in ids:
        p = data / "new_joints" / f"{i}.npy"
        if p.is_file():
            out.append(np.load(p).astype(np.float64))
    if not out:
        raise SMFError(f"no motions found under {data / 'new_joints'} for split {split}")
    return out
