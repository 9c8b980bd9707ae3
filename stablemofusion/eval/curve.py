"""A training run's learning curve: its self-evaluations (``eval.jsonl``) and loss (``log.csv``) as a figure."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from ..core.errors import SMFError

MAX_LOG_BYTES = 512 * 1024 * 1024  # a log.csv of a very long run is still read whole; beyond this it is refused
LOSS_WINDOW = 200  # steps of the loss's moving average
PROBE_SERIES = (("probe_all_content_acc", "content, all"), ("probe_dataset-1_content_acc", "content, dataset 1"),
                ("probe_dataset-2_content_acc", "content, dataset 2"), ("probe_all_style_acc", "style, all"))


def read_run(run: str | Path) -> tuple[list[dict], dict[str, np.ndarray]]:
    """(evaluations in step order, log columns as arrays) of a run folder; one-line errors for what is missing."""
    run = Path(run)
    log_path, eval_path = run / "log.csv", run / "eval.jsonl"
    if not log_path.is_file():
        raise SMFError(f"{run}: no log.csv (not a training run folder)")
    for path in (log_path, eval_path):
        if path.is_file() and path.stat().st_size > MAX_LOG_BYTES:
            raise SMFError(f"{path}: larger than {MAX_LOG_BYTES // 2**20} MB")
    with open(log_path, newline="") as f:
        rows = list(csv.DictReader(f))
    log = {k: np.array([float(r[k]) for r in rows if r.get(k)]) for k in ("step", "loss", "seconds")}
    evals = []
    if eval_path.is_file():
        for n, line in enumerate(eval_path.read_text().splitlines(), 1):
            if line.strip():
                try:
                    evals.append(json.loads(line))
                except json.JSONDecodeError:
                    raise SMFError(f"{eval_path}:{n}: not valid JSON") from None
    by_step = {e["step"]: e for e in evals}  # a resumed run may have evaluated a step twice: keep the last
    return [by_step[s] for s in sorted(by_step)], log


def draw_curve(evals: list[dict], log: dict[str, np.ndarray], out: str | Path, title: str) -> None:
    """Probe accuracy and validation FID against steps (top) and training hours (bottom); loss on the right."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..core.io import atomic_path

    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    steps = np.array([e["step"] for e in evals])
    hours = np.array([e.get("train_seconds", np.nan) for e in evals]) / 3600
    for row, (x, label) in enumerate(((steps, "step"), (hours, "training wall time (h)"))):
        ax = axes[row, 0]
        for key, name in PROBE_SERIES:
            y = [e.get(key, np.nan) for e in evals]
            if np.isfinite(y).any():
                ax.plot(x, y, "o-", ms=3, label=name)
        ax.set(xlabel=label, ylabel="held-out probe accuracy", ylim=(0, 1))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        ax = axes[row, 1]
        fid = [e.get("val_fid", np.nan) for e in evals]
        if np.isfinite(fid).any():
            ax.plot(x, fid, "o-", ms=3, color="C3")
        ax.set(xlabel=label, ylabel="validation FID (fixed subset)")
        ax.grid(alpha=0.3)
    for row, (x, label) in enumerate(((log["step"], "step"), (log["seconds"] / 3600, "training wall time (h)"))):
        ax = axes[row, 2]
        if len(log["loss"]):
            k = min(LOSS_WINDOW, len(log["loss"]))
            smooth = np.convolve(log["loss"], np.ones(k) / k, mode="valid")
            ax.plot(x[k - 1:], smooth, color="C7")
        ax.set(xlabel=label, ylabel=f"loss ({LOSS_WINDOW}-step mean)")
        ax.grid(alpha=0.3)
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(out, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


COMPARE_SERIES = (("probe_all_content_acc", "probe content, all"), ("probe_dataset-1_content_acc", "probe content, dataset 1"),
                  ("probe_dataset-2_content_acc", "probe content, dataset 2"), ("val_fid", "validation FID (fixed subset)"))


def draw_comparison(runs: dict[str, list[dict]], out: str | Path, title: str) -> None:
    """Several runs' evaluations (name -> evaluations) overlaid: each of :data:`COMPARE_SERIES` against steps
    (top) and training hours (bottom), one line per run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..core.io import atomic_path

    fig, axes = plt.subplots(2, len(COMPARE_SERIES), figsize=(5 * len(COMPARE_SERIES), 8))
    for n, (name, evals) in enumerate(runs.items()):
        steps = np.array([e["step"] for e in evals])
        hours = np.array([e.get("train_seconds", np.nan) for e in evals]) / 3600
        for row, x in enumerate((steps, hours)):
            for col, (key, _) in enumerate(COMPARE_SERIES):
                y = np.array([e.get(key, np.nan) for e in evals], dtype=float)
                if np.isfinite(y).any():
                    axes[row, col].plot(x, y, "o-", ms=3, color=f"C{n}", label=name)
    for row, label in enumerate(("step", "training wall time (h)")):
        for col, (key, ylabel) in enumerate(COMPARE_SERIES):
            ax = axes[row, col]
            ax.set(xlabel=label, ylabel=ylabel, **({} if key == "val_fid" else {"ylim": (0, 1)}))
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(out, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def comparison_table(runs: dict[str, list[dict]]) -> str:
    """A markdown table of every run's evaluations: step, training hours and :data:`COMPARE_SERIES`."""
    head = "| run | step | training h | " + " | ".join(name for _, name in COMPARE_SERIES) + " |"
    lines = [head, "|" + "---|" * (3 + len(COMPARE_SERIES))]
    for name, evals in runs.items():
        for e in evals:
            hours = e.get("train_seconds")
            cells = [name, str(e["step"]), "-" if hours is None else f"{hours / 3600:.2f}"]
            cells += [f"{e[k]:.3f}" if isinstance(e.get(k), (int, float)) else "-" for k, _ in COMPARE_SERIES]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


__all__ = ["comparison_table", "draw_comparison", "draw_curve", "read_run"]
