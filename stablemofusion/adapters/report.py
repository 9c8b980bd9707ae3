"""The report ``smf adapt`` writes beside an adapter: what was taught and what the model now draws for it.

``report.md`` lists the clips and captions, the training figures, and per taught caption (up to
REPORT_CAPTIONS) the base model's and the adapted model's motion for it (same seed and length): the root's
speed and distance, the in-domain decision, and a frame strip (``strip-NN.png``: base above, adapted below).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.io import write_text
from .file import Adapter

REPORT_CAPTIONS = 6
STRIP_FRAMES = 6


def _speed(joints: np.ndarray, fps: float) -> tuple[float, float]:
    """(mean horizontal root speed m/s, straight-line distance m) of joints (T, J, 3)."""
    xz = joints[:, 0, [0, 2]]
    step = np.linalg.norm(np.diff(xz, axis=0), axis=1)
    return float(step.mean() * fps), float(np.linalg.norm(xz[-1] - xz[0]))


def write_report(adapter: Adapter, base: str | Path | None, out: str | Path, seed: int = 0) -> Path:
    """Write ``out/report.md`` and its strips for ``adapter`` on model ``base``."""
    import warnings

    from ..pipelines.motion_pipeline import MotionPipeline
    from ..render import render_strip

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    info, t = adapter.info, adapter.info.training
    base_pipe = MotionPipeline.from_pretrained(base, backend="torch")
    pipes = {"base": base_pipe, "adapted": base_pipe.with_adapters([adapter])}
    captions = [c for caps in info.actions.values() for c in caps][:REPORT_CAPTIONS]
    lines = [f"# Adapter {info.name!r}", "",
             f"- Clips: {t.get('clips')} ({t.get('motion_seconds')} s of motion), captions from {t.get('captions_from')}.",
             f"- Licence stated for the clips: {info.licence}.",
             f"- Training: {t.get('seconds')} s; teacher loss {t.get('teacher_loss')} (first, last), student loss "
             f"{t.get('student_loss')}; {t.get('replay_prompts')} replayed prompts of the base model.",
             f"- Low-rank updates: rank {info.lora.rank}, alpha {info.lora.alpha}.", "",
             f"Each taught caption (seed {seed}, the length the model predicts): the base model, then the adapted one.",
             "", "| caption | base: speed m/s, distance m, in domain | adapted: speed m/s, distance m, in domain | strip |",
             "|---|---|---|---|"]
    for k, caption in enumerate(captions):
        rows, cells = [], []
        for label, pipe in pipes.items():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = pipe(caption, seed=seed)[0]
            speed, dist = _speed(r.joints, r.fps)
            inside = "-" if r.domain is None else ("yes" if not r.domain.out_of_domain else "no")
            cells.append(f"{speed:.2f}, {dist:.2f}, {inside}")
            rows.append((label, r.joints))
        n = min(len(j) for _, j in rows)
        strip = out / f"strip-{k:02d}.png"
        render_strip(rows, [int(i) for i in np.linspace(0, n - 1, STRIP_FRAMES)], strip, size=160)
        lines.append(f"| {caption} | {cells[0]} | {cells[1]} | ![]({strip.name}) |")
    path = out / "report.md"
    write_text(path, "\n".join(lines) + "\n")
    return path


__all__ = ["write_report"]
