"""A training run's self-evaluation: prompt following on a held-out probe and FID on a fixed validation subset.

``smf train --eval-every N --probe FILE --classifier CL --evaluator EV`` calls :meth:`TrainingMonitor.__call__`
on the run's checkpoint every N steps (its EMA weights and default sampler; guidance ``--eval-guidance``, else the
model's default); the figures, with the guidance they were measured at, go into
the run's ``eval.jsonl`` and `smf curve` draws them. Probe: one motion per prompt at a fixed length, judged by
the motion classifier (never the free-form dev set, which stays a test set). FID: our evaluator on the first
``fid_items`` items of one fixed draw of the validation split, one replication.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..core.errors import SMFError

PROBE_SECONDS = 4.0  # every probe prompt at one length: the accuracy then measures the action, not the length


@dataclass(frozen=True)
class MonitorConfig:
    probe: Path  # labelled prompt file (JSON lines, eval/prompts.py)
    classifier: Path  # `smf train-classifier` folder
    evaluator: Path | None = None  # `smf train-evaluator` folder (FID); None = probe only
    fid_items: int = 256  # validation items for FID (whole R-precision batches)
    batch_size: int = 32  # R-precision batch (the protocol's 32)
    split: str = "val"
    seed: int = 0
    guidance: float | None = None  # classifier-free guidance scale of the probe and FID samples; None: the model's


class TrainingMonitor:
    """Loads the probe, classifier and evaluator once; each call measures one checkpoint of a run."""

    def __init__(self, data: str | Path, cfg: MonitorConfig):
        from .classifier import corpus_labels, load_classifier
        from .prompts import check_known, load_prompts

        for what, path in (("probe file", cfg.probe), ("classifier", cfg.classifier)):
            if not Path(path).exists():
                raise SMFError(f"no such {what}: {path}")
        if cfg.evaluator is not None and not Path(cfg.evaluator).is_dir():
            raise SMFError(f"no such evaluator folder: {cfg.evaluator}")
        if cfg.fid_items < cfg.batch_size:
            raise SMFError(f"--fid-items must be at least one batch ({cfg.batch_size}), got {cfg.fid_items}")
        self.data, self.cfg = Path(data), cfg
        self.classifier = load_classifier(cfg.classifier)
        self.labels = corpus_labels(data)
        self.items = [it for it in load_prompts(cfg.probe) if not it.ood]
        check_known(self.items, self.classifier)
        self.evaluator = None
        if cfg.evaluator is not None:
            from .evaluator import load_evaluator

            self.evaluator, _ = load_evaluator(cfg.evaluator)

    def __call__(self, run: Path, step: int) -> dict:
        """Figures of the checkpoint in ``run``: probe content/style accuracy overall and per dataset, and
        FID / top-3 on the validation subset."""
        from ..pipelines.motion_pipeline import MotionPipeline
        from ..core.settings import Settings
        from .prompts import prompt_accuracy

        pipe = MotionPipeline.from_pretrained(run, backend="torch")
        guidance = pipe.settings(Settings(guidance_scale=self.cfg.guidance)).guidance_scale
        acc = prompt_accuracy(pipe, self.classifier, self.items, self.labels, samples=1, seconds=PROBE_SECONDS,
                              seed=self.cfg.seed, guidance_scale=guidance)
        out = {"guidance": guidance}
        out.update({f"probe_{k}_{m}": round(v[m], 4) for k, v in acc.items()
                    if isinstance(v, dict) and "content_acc" in v for m in ("content_acc", "style_acc")})
        if self.evaluator is not None:
            out.update(self._fid(pipe, guidance))
        return out

    def _fid(self, pipe, guidance: float) -> dict:
        from .protocol import EmbeddingModel, EvalConfig, evaluate

        cfg = EvalConfig(replications=1, mm_captions=0, max_items=self.cfg.fid_items, split=self.cfg.split,
                         seed=self.cfg.seed, batch_size=self.cfg.batch_size, guidance_scale=guidance)
        res = evaluate(pipe, EmbeddingModel(self.evaluator, pipe.text_cache), self.data, cfg, progress=False)
        gen = res["rows"]["Generated"]
        return {"val_fid": round(float(gen["fid"][0]), 4), "val_top3": round(float(gen["top3"][0]), 4)}


__all__ = ["MonitorConfig", "PROBE_SECONDS", "TrainingMonitor"]
