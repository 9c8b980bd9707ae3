"""Diffusion training: x0 prediction with masked MSE, AdamW, step LR decay, grad clipping, EMA, CFG dropout.

One obvious path: corpus -> batches (deterministic in the step number) -> frozen text tokens (disk cache)
-> noise (DDPM schedule) -> denoiser -> loss -> optimiser. Runs through accelerate (CPU, one GPU, or
``accelerate launch`` on many). Every random draw of step ``s`` is seeded from (seed, s), so a run resumed
from a checkpoint reproduces the uninterrupted run exactly on CPU.
"""

from __future__ import annotations

import csv
import json
import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ..data.batches import TIME_WARP_CONTENTS, get_batch
from ..data.dataset import MotionTextDataset
from ..core.errors import SMFError
from ..models.registry import build_denoiser
from ..models.presets import get_preset
from .checkpoint import CHECKPOINT_DIR, MODEL, load_training_state, read_config, save_checkpoint
from .config import CheckpointConfig, TrainConfig
from .schedule import make_train_scheduler


def _mix(*ints: int) -> int:
    """A 63-bit seed from integers (stable across runs and machines)."""
    return int(np.random.SeedSequence(list(ints)).generate_state(1, dtype=np.uint64)[0] >> 1)


def masked_mse(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean squared error over valid frames: pred/target (B, T, D), mask (B, T) bool."""
    m = mask[..., None].to(pred.dtype)
    return ((pred - target) ** 2 * m).sum() / (m.sum() * pred.shape[-1]).clamp_min(1.0)


LOG_HEADER = "step,loss,lr,seconds,samples_per_s"  # seconds: training wall time since the run began, resumes included
BALANCE_CAP = 16  # most copies of one item per epoch under label balancing
SCHEDULES = ("step", "cosine", "wsd")


def learning_rate(cfg: TrainConfig, step: int) -> float:
    """The learning rate of (0-based) step ``step``: linear warm-up over ``cfg.warmup`` steps, then ``step``:
    ``lr * lr_decay ** (step // lr_decay_every)``; ``cosine``: from lr down to min_lr at ``cfg.steps``;
    ``wsd`` (warm-up, stable, decay): lr until the last ``cfg.decay_steps`` steps, then cosine to min_lr."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    if cfg.lr_schedule == "step":
        return cfg.lr * cfg.lr_decay ** (step // cfg.lr_decay_every)
    start = cfg.warmup if cfg.lr_schedule == "cosine" else cfg.steps - cfg.decay_steps
    if step < start:
        return cfg.lr
    frac = min((step - start) / max(cfg.steps - start, 1), 1.0)
    return cfg.min_lr + (cfg.lr - cfg.min_lr) * 0.5 * (1.0 + math.cos(math.pi * frac))


def check_train_config(cfg: TrainConfig) -> None:
    """One-line errors for settings no run can use."""
    if cfg.steps < 1 or cfg.batch_size < 1:
        raise SMFError("--steps and --batch-size must be at least 1")
    if cfg.mixed_precision not in ("no", "fp16", "bf16"):
        raise SMFError(f"--mixed-precision must be no, fp16 or bf16, not {cfg.mixed_precision!r}")
    if cfg.lr_schedule not in SCHEDULES:
        raise SMFError(f"--lr-schedule must be one of {', '.join(SCHEDULES)}, not {cfg.lr_schedule!r}")
    if cfg.warmup < 0 or cfg.decay_steps < 0 or cfg.min_lr < 0 or cfg.balance < 0:
        raise SMFError("--warmup, --decay-steps, --min-lr and --balance must not be negative")
    if not 0.0 <= cfg.short_crops <= 1.0:
        raise SMFError(f"--short-crops is a probability in [0, 1], got {cfg.short_crops}")
    if not 0.0 <= cfg.time_warp <= 1.0:
        raise SMFError(f"--time-warp is a probability in [0, 1], got {cfg.time_warp}")
    if cfg.time_warp_contents not in TIME_WARP_CONTENTS:
        raise SMFError(f"--time-warp-contents must be one of {', '.join(TIME_WARP_CONTENTS)}, got "
                       f"{cfg.time_warp_contents!r}")


def label_balance(data: str | Path, ds: MotionTextDataset, power: float) -> tuple[int, ...] | None:
    """Per-item repeats that even out (dataset, content) label frequencies (None when ``power`` is 0)."""
    if power <= 0:
        return None
    from ..data.batches import label_repeats
    from ..data.labels import corpus_labels

    labels = corpus_labels(data)
    groups = [(labels[ds.ids[e.index]].dataset, labels[ds.ids[e.index]].content) for e in ds.entries]
    return label_repeats(groups, power, BALANCE_CAP)


def warpable_items(data: str | Path, ds: MotionTextDataset, contents: str) -> tuple[bool, ...] | None:
    """Which items time warp may slow: all (None) or, for "tempo-free", those whose content label the corpus's
    lexicon lists as ``tempo_free`` (needs clips.csv and a lexicon named in stats.json)."""
    if contents == "all":
        return None
    from ..data.labels import corpus_labels
    from ..data.lexicon import load_lexicon

    name = _lexicon_name(data)
    if not name:
        raise SMFError(f"{data}: --time-warp-contents {contents} needs a corpus whose stats.json names its lexicon")
    free, labels = load_lexicon(name).tempo_free, corpus_labels(data)
    return tuple(labels[ds.ids[e.index]].content in free for e in ds.entries)


def train(data: str | Path, out: str | Path, cfg: TrainConfig, *, resume: bool = False, stop_after: int | None = None,
          progress: bool = True, text_cache: str | Path | None = None, eval_every: int = 0,
          on_eval: Callable[[Path, int], dict] | None = None) -> list[float]:
    """Train a denoiser on the corpus at ``data``; checkpoints go to ``out``. Returns this run's step losses.

    ``stop_after`` ends the run after that many total steps, as if killed right after a checkpoint. With
    ``eval_every`` and ``on_eval``, every ``eval_every`` steps a checkpoint is saved and ``on_eval(out, step)``
    measures it; its figures go to ``out/eval.jsonl`` with the step and the training wall time.
    """
    check_train_config(cfg)
    from accelerate import Accelerator
    from diffusers.training_utils import EMAModel

    from ..text.cache import TextEmbeddingCache
    from ..text.frozen import load_text_encoder

    out = Path(out)
    accelerator = Accelerator(mixed_precision=cfg.mixed_precision, cpu=not torch.cuda.is_available())
    ds = MotionTextDataset(data, "train", seed=cfg.seed, max_frames=cfg.max_frames, min_frames=cfg.min_frames,
                           feat_bias=cfg.feat_bias, short_crops=cfg.short_crops)
    encoder = load_text_encoder(cfg.text_encoder).to(accelerator.device)
    cache = TextEmbeddingCache(text_cache or (out / "text-cache"), encoder)
    model_cfg = get_preset(cfg.preset, motion_dim=int(ds.mean.shape[0]), text_dim=encoder.dim)
    torch.manual_seed(cfg.seed)  # initial weights
    model = build_denoiser(model_cfg)
    if cfg.init_from and not resume:
        _init_weights(model, cfg.init_from)
    # the fused kernel (one pass over all parameters) on a GPU and on the CPU: on this 2-core CPU 6 ms per step
    # for the 5.5M-parameter small-sentence model against 21 ms for the reference loop (docs/models.md)
    optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay, fused=True)
    ema = EMAModel(model.parameters(), decay=cfg.ema_decay)
    start = 0
    config = CheckpointConfig.for_skeleton(model_cfg, ds.skeleton.name, schedule=cfg.schedule,
                                           text_encoder=encoder.name, min_frames=ds.min_frames,
                                           max_frames=ds.max_frames, train=cfg)
    if resume:
        state = load_training_state(out / CHECKPOINT_DIR)
        saved = read_config(out / CHECKPOINT_DIR)
        differ = config.resume_mismatch(saved)
        if differ:
            raise SMFError(f"cannot resume {out}: this run differs from the saved one in {', '.join(differ)} "
                           "(a resumed run may change its steps and optimisation settings, not the model)")
        from safetensors.torch import load_file

        model.load_state_dict(load_file(out / CHECKPOINT_DIR / MODEL))
        optimizer.load_state_dict(state["optimizer"])
        ema.load_state_dict(state["ema"])
        start = int(state["step"])
        for group in optimizer.param_groups:  # this run's settings apply from the resumed step
            group["weight_decay"] = cfg.weight_decay
        ema.decay = cfg.ema_decay
    repeats = label_balance(data, ds, cfg.balance)
    warpable = warpable_items(data, ds, cfg.time_warp_contents) if cfg.time_warp > 0 else None
    # every training caption through the frozen language model once, up front: steps then only read the cache
    cache.precompute(c.caption for e in ds.entries for c in e.captions)
    cache.flush()
    model, optimizer = accelerator.prepare(model, optimizer)
    forward = torch.compile(model) if cfg.compile else model  # `model` keeps the parameters and is saved
    noise_sched = make_train_scheduler(cfg.schedule)
    T = cfg.schedule.num_train_timesteps
    synonyms = _synonyms(data) if cfg.text_augment > 0 else None
    log_path, seconds_before = open_log(out, resume, start)
    end = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    losses: list[float] = []
    bar = tqdm(range(start, end), initial=start, total=end, desc="train", unit="step", disable=not progress or
               not accelerator.is_main_process)
    t0 = t_step = time.perf_counter()
    rank, world = accelerator.process_index, accelerator.num_processes
    with open(log_path, "a", newline="") as log_file:
        log = csv.writer(log_file)
        for step in bar:
            batch = get_batch(ds, step, cfg.batch_size * world, cfg.seed, cfg.bucket, repeats, cfg.time_warp,
                              warpable)
            sl = slice(rank * cfg.batch_size, (rank + 1) * cfg.batch_size)
            x0 = batch["motion"][sl].to(accelerator.device)
            mask = batch["mask"][sl].to(accelerator.device)
            captions = batch["caption"][sl]
            if cfg.text_augment > 0:
                tokens, tmask = _augmented_text(captions, cache, encoder, cfg, synonyms, _mix(cfg.seed, step, rank, 2),
                                                accelerator.device)
            else:
                tokens, tmask = cache.get_or_compute(captions, device=accelerator.device)
            g = torch.Generator().manual_seed(_mix(cfg.seed, step, rank))
            t = torch.randint(0, T, (x0.shape[0],), generator=g).to(accelerator.device)
            noise = torch.randn(x0.shape, generator=g).to(accelerator.device)
            drop = (torch.rand(x0.shape[0], generator=g) < cfg.cond_drop).to(accelerator.device)
            torch.manual_seed(_mix(cfg.seed, step, rank, 1))  # dropout inside the model
            x_t = noise_sched.add_noise(x0, noise, t)
            model.train()
            with accelerator.autocast():
                pred = forward(x_t, t, tokens, tmask, drop, mask)
            loss = masked_mse(pred.float(), x0, mask)
            accelerator.backward(loss)
            if accelerator.sync_gradients:
                accelerator.clip_grad_norm_(model.parameters(), cfg.grad_clip)
            lr = learning_rate(cfg, step)
            for group in optimizer.param_groups:
                group["lr"] = lr
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)
            ema.step(accelerator.unwrap_model(model).parameters())
            value = accelerator.gather(loss.detach()[None]).mean().item()
            if not math.isfinite(value):
                raise SMFError(f"training diverged at step {step}: loss is {value}")
            losses.append(value)
            now = time.perf_counter()
            rate = cfg.batch_size * world / max(now - t_step, 1e-9)
            t_step = now
            if accelerator.is_main_process:
                log.writerow([step + 1, f"{value:.6f}", f"{lr:.3e}", f"{seconds_before + now - t0:.2f}", f"{rate:.1f}"])
                bar.set_postfix(loss=f"{value:.4f}", lr=f"{lr:.1e}", samples_s=f"{rate:.0f}")
            evaluate_now = on_eval is not None and eval_every > 0 and (step + 1) % eval_every == 0
            if (step + 1) % cfg.checkpoint_every == 0 or step + 1 == end or evaluate_now:
                log_file.flush()
                cache.flush()
                if accelerator.is_main_process:
                    _save(out, accelerator.unwrap_model(model), ema, optimizer, step + 1, config, ds)
                    if evaluate_now:
                        t_eval = time.perf_counter()
                        _log_eval(out, step + 1, seconds_before + t_eval - t0, on_eval(out, step + 1))
                        t0 += time.perf_counter() - t_eval  # evaluation is not training time
                        t_step = time.perf_counter()
                accelerator.wait_for_everyone()
    cache.close()
    return losses


def open_log(out: Path, resume: bool, start: int) -> tuple[Path, float]:
    """``out/log.csv``, started afresh unless resuming, and the training seconds it records up to ``start``."""
    log_path = out / "log.csv"
    out.mkdir(parents=True, exist_ok=True)
    if not resume or not log_path.exists():
        log_path.write_text(LOG_HEADER + "\n")
    return log_path, _logged_seconds(log_path, start)


def _logged_seconds(log_path: Path, step: int) -> float:
    """Training wall time the log records up to ``step`` (0 for a new run or a log without the column)."""
    rows = log_path.read_text().splitlines()
    if step == 0 or len(rows) < 2:
        return 0.0
    head = rows[0].split(",")
    for row in reversed(rows[1:]):
        cols = row.split(",")
        if "seconds" in head and len(cols) == len(head) and int(cols[0]) <= step:
            return float(cols[head.index("seconds")])
    return 0.0


def _log_eval(out: Path, step: int, seconds: float, figures: dict) -> None:
    """Append one evaluation to ``out/eval.jsonl`` (one JSON object per line)."""
    with open(out / "eval.jsonl", "a", encoding="utf-8") as f:
        f.write(json.dumps({"step": step, "train_seconds": round(seconds, 1), **figures}) + "\n")


def _lexicon_name(data: str | Path) -> str | None:
    """The lexicon a corpus's stats.json names (None without one)."""
    stats = Path(data) / "stats.json"
    return json.loads(stats.read_text()).get("lexicon") if stats.is_file() else None


def _synonyms(data: str | Path) -> dict[str, tuple[str, ...]]:
    """Synonym groups for caption augmentation: the style words of the corpus's lexicon (its stats.json names
    it), or none for a corpus without one."""
    from ..data.augment import synonym_groups
    from ..data.lexicon import STYLE_KINDS, load_lexicon

    name = _lexicon_name(data)
    if not name:
        return {}
    lex = load_lexicon(name)
    return synonym_groups(sw.kind(k).train for sw in lex.styles.values() for k in STYLE_KINDS if k != "personas")


def _augmented_text(captions: list[str], cache, encoder, cfg: TrainConfig, synonyms, seed: int, device):
    """Frozen tokens of a batch where each caption is perturbed with probability ``cfg.text_augment``:
    unchanged captions come from the cache, perturbed ones are encoded afresh (they are not cached)."""
    import random

    from ..data.augment import augment_caption
    from ..text.cache import pad_rows

    rng = random.Random(seed)
    texts = [augment_caption(c, rng, synonyms) if rng.random() < cfg.text_augment else c for c in captions]
    fresh = [i for i, (a, b) in enumerate(zip(texts, captions)) if a != b]
    tokens, mask = cache.get_or_compute(captions, device=device)
    if not fresh:
        return tokens, mask
    rows = [tokens[i, :int(mask[i].sum())] for i in range(len(captions))]
    with torch.no_grad():
        new_tokens, new_mask = encoder.encode([texts[i] for i in fresh])
    for j, i in enumerate(fresh):
        rows[i] = new_tokens[j, :int(new_mask[j].sum())]
    return pad_rows(rows, tokens.shape[-1], device)


def _init_weights(model: torch.nn.Module, source: str) -> None:
    """Load every weight of ``source`` into ``model``; parameters the model adds (e.g. a zero-initialised
    sentence conditioning map) keep their initial values. Every source weight must fit the model."""
    from .checkpoint import load_weights

    state = load_weights(source)
    own = model.state_dict()
    misfit = [k for k, v in state.items() if k not in own or own[k].shape != v.shape]
    if misfit:
        raise SMFError(f"--init-from {source}: {len(misfit)} of its weights do not fit this model "
                       f"(e.g. {misfit[0]}); fine-tuning needs the same architecture")
    model.load_state_dict({k: v.to(own[k].dtype) for k, v in state.items()}, strict=False)


def _save(out: Path, model, ema, optimizer, step: int, config: CheckpointConfig, ds: MotionTextDataset) -> None:
    ema_model_state = _ema_state(model, ema)
    training_state = {"optimizer": optimizer.state_dict(), "ema": ema.state_dict(), "step": step, "torch_rng": torch.get_rng_state(),
                      "numpy_rng": np.random.get_state()}
    save_checkpoint(out / CHECKPOINT_DIR, model=model, config=replace(config, step=step), mean=ds.mean, std=ds.std,
                    ema_state=ema_model_state, training_state=training_state)


def _ema_state(model, ema) -> dict[str, torch.Tensor]:
    """The model's state dict with the EMA shadow weights in place of its parameters."""
    state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    names = [n for n, _ in model.named_parameters()]
    for name, shadow in zip(names, ema.shadow_params):
        state[name] = shadow.detach().clone()
    return state


__all__ = ["TrainConfig", "check_train_config", "learning_rate", "masked_mse", "open_log", "train"]
