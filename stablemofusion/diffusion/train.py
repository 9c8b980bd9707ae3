"""Diffusion training: x0 prediction with masked MSE, AdamW, step LR decay, grad clipping, EMA, CFG dropout.

One obvious path: corpus -> batches (deterministic in the step number) -> frozen text tokens (disk cache)
-> noise (DDPM schedule) -> denoiser -> loss -> optimiser. Runs through accelerate (CPU, one GPU, or
``accelerate launch`` on many). Every random draw of step ``s`` is seeded from (seed, s), so a run resumed
from a checkpoint reproduces the uninterrupted run exactly on CPU.
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ..data.batches import get_batch
from ..data.dataset import MotionTextDataset
from ..errors import SMFError
from ..models.base import build_denoiser
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


def train(data: str | Path, out: str | Path, cfg: TrainConfig, *, resume: bool = False, stop_after: int | None = None,
          progress: bool = True, text_cache: str | Path | None = None) -> list[float]:
    """Train a denoiser on the corpus at ``data``; checkpoints go to ``out``. Returns this run's step losses.

    ``stop_after`` ends the run after that many total steps, as if killed right after a checkpoint.
    """
    from accelerate import Accelerator
    from diffusers.training_utils import EMAModel

    from ..text.cache import TextEmbeddingCache
    from ..text.frozen import load_text_encoder

    out = Path(out)
    accelerator = Accelerator(mixed_precision=cfg.mixed_precision, cpu=not torch.cuda.is_available())
    ds = MotionTextDataset(data, "train", seed=cfg.seed, max_frames=cfg.max_frames, min_frames=cfg.min_frames,
                           feat_bias=cfg.feat_bias)
    encoder = load_text_encoder(cfg.text_encoder).to(accelerator.device)
    cache = TextEmbeddingCache(text_cache or (out / "text-cache"), encoder)
    model_cfg = get_preset(cfg.preset, motion_dim=int(ds.mean.shape[0]), text_dim=encoder.dim)
    torch.manual_seed(cfg.seed)  # initial weights
    model = build_denoiser(model_cfg)
    if cfg.init_from and not resume:
        _init_weights(model, cfg.init_from)
    # the fused CUDA kernel on a GPU (one launch for all parameters); the reference loop on a CPU
    optimizer = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay,
                                  fused=accelerator.device.type == "cuda")
    lr_sched = torch.optim.lr_scheduler.StepLR(optimizer, step_size=cfg.lr_decay_every, gamma=cfg.lr_decay)
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
        lr_sched.load_state_dict(state["lr_scheduler"])
        ema.load_state_dict(state["ema"])
        start = int(state["step"])
        if saved.train is None or (saved.train.lr, saved.train.lr_decay, saved.train.lr_decay_every,
                                   saved.train.weight_decay, saved.train.ema_decay) != (
                cfg.lr, cfg.lr_decay, cfg.lr_decay_every, cfg.weight_decay, cfg.ema_decay):
            _apply_optimisation_settings(optimizer, lr_sched, ema, cfg, start)
    model, optimizer = accelerator.prepare(model, optimizer)
    forward = torch.compile(model) if cfg.compile else model  # `model` keeps the parameters and is saved
    noise_sched = make_train_scheduler(cfg.schedule)
    T = cfg.schedule.num_train_timesteps
    synonyms = _synonyms(data) if cfg.text_augment > 0 else None
    log_path = out / "log.csv"
    out.mkdir(parents=True, exist_ok=True)
    if not resume or not log_path.exists():
        log_path.write_text("step,loss,lr,seconds\n")
    end = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    losses: list[float] = []
    bar = tqdm(range(start, end), initial=start, total=end, desc="train", unit="step", disable=not progress or
               not accelerator.is_main_process)
    t0 = time.perf_counter()
    rank, world = accelerator.process_index, accelerator.num_processes
    with open(log_path, "a", newline="") as log_file:
        log = csv.writer(log_file)
        for step in bar:
            batch = get_batch(ds, step, cfg.batch_size * world, cfg.seed, cfg.bucket)
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
            optimizer.step()
            lr_sched.step()
            optimizer.zero_grad(set_to_none=True)
            ema.step(accelerator.unwrap_model(model).parameters())
            value = accelerator.gather(loss.detach()[None]).mean().item()
            if not math.isfinite(value):
                raise SMFError(f"training diverged at step {step}: loss is {value}")
            losses.append(value)
            elapsed = time.perf_counter() - t0
            if accelerator.is_main_process:
                log.writerow([step + 1, f"{value:.6f}", f"{lr_sched.get_last_lr()[0]:.3e}", f"{elapsed:.2f}"])
                bar.set_postfix(loss=f"{value:.4f}", lr=f"{lr_sched.get_last_lr()[0]:.1e}")
            if (step + 1) % cfg.checkpoint_every == 0 or step + 1 == end:
                log_file.flush()
                cache.flush()
                if accelerator.is_main_process:
                    _save(out, accelerator.unwrap_model(model), ema, optimizer, lr_sched, step + 1, config, ds)
                accelerator.wait_for_everyone()
    cache.close()
    return losses


def _synonyms(data: str | Path) -> dict[str, tuple[str, ...]]:
    """Synonym groups for caption augmentation: the style words of the corpus's lexicon (its stats.json names
    it), or none for a corpus without one."""
    import json

    from ..data.augment import synonym_groups
    from ..data.lexicon import STYLE_KINDS, load_lexicon

    stats = Path(data) / "stats.json"
    name = json.loads(stats.read_text()).get("lexicon") if stats.is_file() else None
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


def _apply_optimisation_settings(optimizer, lr_sched, ema, cfg: TrainConfig, step: int) -> None:
    """Make a resumed run use this run's learning-rate schedule, weight decay and EMA decay (the saved states
    carry the old ones). Called only when they changed, so an unchanged run resumes bit for bit."""
    lr_sched.base_lrs = [cfg.lr] * len(optimizer.param_groups)
    lr_sched.step_size, lr_sched.gamma = cfg.lr_decay_every, cfg.lr_decay
    for group in optimizer.param_groups:
        group["initial_lr"] = cfg.lr
        group["lr"] = cfg.lr * cfg.lr_decay ** (step // cfg.lr_decay_every)
        group["weight_decay"] = cfg.weight_decay
    lr_sched._last_lr = [g["lr"] for g in optimizer.param_groups]
    ema.decay = cfg.ema_decay


def _init_weights(model: torch.nn.Module, source: str) -> None:
    """Load every weight of ``source`` into ``model``; parameters the model adds (e.g. a zero-initialised
    sentence conditioning map) keep their initial values. Every source weight must fit the model."""
    from ..diffusion.checkpoint import load_weights

    state = load_weights(source)
    own = model.state_dict()
    misfit = [k for k, v in state.items() if k not in own or own[k].shape != v.shape]
    if misfit:
        raise SMFError(f"--init-from {source}: {len(misfit)} of its weights do not fit this model "
                       f"(e.g. {misfit[0]}); fine-tuning needs the same architecture")
    model.load_state_dict({k: v.to(own[k].dtype) for k, v in state.items()}, strict=False)


def _save(out: Path, model, ema, optimizer, lr_sched, step: int, config: CheckpointConfig,
          ds: MotionTextDataset) -> None:
    ema_model_state = _ema_state(model, ema)
    training_state = {"optimizer": optimizer.state_dict(), "lr_scheduler": lr_sched.state_dict(),
                      "ema": ema.state_dict(), "step": step, "torch_rng": torch.get_rng_state(),
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


__all__ = ["TrainConfig", "train", "masked_mse"]
