"""Distillation of a few-step student from a trained teacher, with the guidance scale as input.

Latent-consistency-model distillation (Luo et al. 2023; MotionLCM, Dai et al. 2024) on our features: the
student is a copy of the teacher plus a zero-initialised guidance-scale embedding (``ModelConfig.guidance``),
so it starts as the teacher's conditional branch and runs one forward per step. Step ``s``:

1. a training batch exactly as ``smf train`` draws it (same data order, masks, condition drop), its frozen text
   tokens from the cache;
2. per item a guidance scale w ~ U[guidance_min, guidance_max] and a point t_{n+1} of the ``grid``-point skip
   schedule (t = 20 i - 1 for T = 1000, grid 50: the ``lcm`` sampler's); x_{t_{n+1}} = q(x_0, noise);
3. the teacher's guided DDIM step from t_{n+1} to t_n = t_{n+1} - T / grid (0 at the bottom) with x0 =
   u + w (c - u) (both passes in one batch; dropped-text items get u);
4. loss between the student's consistency function f(x_{t_{n+1}}, t_{n+1}, w) and the target network's
   f(x_{t_n}, t_n, w) (no gradient), masked to valid frames; f = c_skip x + c_out D, the LCM boundary
   scalings (f(x, 0) = x);
5. AdamW on the student, then the target network (EMA of the student, ``target_decay``) follows it.

``--method regression`` (Luhman & Luhman 2021, "knowledge distillation" of the sampler) replaces 2-4: per
item noise eps and a guidance scale w; the target is the teacher's whole deterministic sample from eps
(``teacher_sampler``, ``teacher_steps``, guidance w: one pass at w = 1); the loss is between it and the
student's ``sample_steps``-step sample from the same eps (the inference path, gradients through it). A
consistency student at one step draws something like the average of the motions its text allows (a wave
over random phases looks like a raised hand); regressing on the teacher's noise-to-motion map teaches it
which motion each noise gives. Start it from a consistency student (``init_from``).

Checkpoints hold the student (``model.safetensors``) and the target network (``ema.safetensors``: what the
pipeline loads), the optimiser and the step; every random draw of step ``s`` is seeded from (seed, s), so a
resumed run equals the uninterrupted one on a CPU.
"""

from __future__ import annotations

import copy
import csv
import math
import shutil
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ..data.batches import get_batch
from ..data.dataset import MotionTextDataset
from ..core.errors import SMFError
from .checkpoint import CHECKPOINT_DIR, CONFIG, EMA, MODEL, STATE, companion_files, load_checkpoint, \
    load_training_state, read_config, resolve, save_checkpoint
from .config import LENGTH_MULTIPLE, DistilConfig
from ..core.limits import STUDENT_SAMPLER
from .schedulers import CONSISTENCY_GRID, TIMESTEP_SCALING, parse_sampler
from .sampling import guided, model_denoiser, run_solver
from .solvers import consistency_scalings, solver_table
from .train import _mix, masked_mse, open_log

LOSSES = ("l2", "huber")
METHODS = ("consistency", "regression")
# teacher-folder files that are not the teacher's own weights/config: carried into the student's checkpoints
# (length estimator, known actions, ...), so the student's pipeline behaves like the teacher's around sampling
_OWN_FILES = {CONFIG, MODEL, EMA, STATE, "Mean.npy", "Std.npy", "MODEL_CARD.md"}
_GUIDANCE = "guidance_embed."  # parameter names of the student's guidance-scale embedding (Denoiser.guidance_embed)


def check_distil_config(cfg: DistilConfig) -> None:
    """One-line errors for settings no run can use."""
    if not cfg.teacher:
        raise SMFError("--teacher is required (a checkpoint, run or exported model folder)")
    if cfg.steps < 1 or cfg.batch_size < 1:
        raise SMFError("--steps and --batch-size must be at least 1")
    if cfg.mixed_precision not in ("no", "fp16", "bf16"):
        raise SMFError(f"--mixed-precision must be no, fp16 or bf16, not {cfg.mixed_precision!r}")
    if cfg.loss not in LOSSES:
        raise SMFError(f"--loss must be one of {', '.join(LOSSES)}, not {cfg.loss!r}")
    if not 0 <= cfg.target_decay < 1:
        raise SMFError(f"--target-decay must be in [0, 1), got {cfg.target_decay}")
    if not 0 <= cfg.guidance_min <= cfg.guidance_max:
        raise SMFError(f"need 0 <= --guidance-min <= --guidance-max, got {cfg.guidance_min}, {cfg.guidance_max}")
    if cfg.grid != CONSISTENCY_GRID:
        raise SMFError(f"--grid must be {CONSISTENCY_GRID}, the lcm sampler's skip schedule")
    if not cfg.guidance_lr_scale > 0:
        raise SMFError(f"--guidance-lr-scale must be > 0, got {cfg.guidance_lr_scale}")
    if not 1 <= cfg.sample_steps <= cfg.grid:
        raise SMFError(f"--sample-steps must be in [1, {cfg.grid}], got {cfg.sample_steps}")
    if cfg.warmup < 0 or cfg.lr <= 0 or not 0 <= cfg.cond_drop <= 1:
        raise SMFError("--warmup must not be negative, --lr must be positive and --cond-drop in [0, 1]")
    if cfg.method not in METHODS:
        raise SMFError(f"--method must be one of {', '.join(METHODS)}, not {cfg.method!r}")
    if cfg.method == "regression":
        _, spec, _ = parse_sampler(cfg.teacher_sampler)
        if spec.stochastic or not spec.fast:
            raise SMFError(f"--teacher-sampler must be deterministic with a precomputed form (e.g. dpmsolver++-karras, "
                           f"ddim), not {cfg.teacher_sampler!r}: the target must be a function of the noise")
        if cfg.teacher_steps < 1:
            raise SMFError(f"--teacher-steps must be at least 1, got {cfg.teacher_steps}")
    if not 0 <= cfg.length_mix <= 1:
        raise SMFError(f"--length-mix must be in [0, 1], got {cfg.length_mix}")
    if cfg.length_mix and cfg.method != "regression":
        raise SMFError("--length-mix needs --method regression (consistency distillation noises the clips themselves)")


def distil_lr(cfg: DistilConfig, step: int) -> float:
    """Linear warm-up over ``cfg.warmup`` steps, then constant (as LCM)."""
    return cfg.lr * min(1.0, (step + 1) / cfg.warmup) if cfg.warmup else cfg.lr


def param_groups(student: torch.nn.Module, guidance_lr_scale: float) -> list[dict]:
    """AdamW groups: the guidance embedding (``lr_scale`` = guidance_lr_scale) and everything else (1)."""
    parts: dict[bool, list] = {False: [], True: []}
    for name, p in student.named_parameters():
        parts[name.startswith(_GUIDANCE)].append(p)
    return [{"params": parts[False], "lr_scale": 1.0}, {"params": parts[True], "lr_scale": float(guidance_lr_scale)}]


def drawn_length(cfg: DistilConfig, step: int, min_frames: int, max_frames: int) -> int | None:
    """The one length (frames, a multiple of LENGTH_MULTIPLE in [min_frames, max_frames]) that step ``step``
    samples its whole batch at, or None (the clips' own lengths) on a fraction 1 - ``cfg.length_mix`` of steps;
    seeded from (seed, step)."""
    if not cfg.length_mix:
        return None
    g = torch.Generator().manual_seed(_mix(cfg.seed, step, 2))
    if float(torch.rand((), generator=g)) >= cfg.length_mix:
        return None
    lo, hi = -(-min_frames // LENGTH_MULTIPLE), max_frames // LENGTH_MULTIPLE
    return LENGTH_MULTIPLE * int(torch.randint(lo, hi + 1, (), generator=g))


def skip_grid(T: int, grid: int) -> torch.Tensor:
    """The skip schedule's timesteps, ascending: (1..grid) * (T // grid) - 1 (the lcm sampler's)."""
    return torch.arange(1, grid + 1) * (T // grid) - 1


def masked_huber(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor, c: float) -> torch.Tensor:
    """Pseudo-Huber sqrt(d^2 + c^2) - c per feature, averaged over valid frames (mask (B, T) bool)."""
    m = mask[..., None].to(pred.dtype)
    per = torch.sqrt((pred - target) ** 2 + c * c) - c
    return (per * m).sum() / (m.sum() * pred.shape[-1]).clamp_min(1.0)


def student_from_teacher(teacher, init_from: str | Path | None = None) -> torch.nn.Module:
    """A student: the teacher's architecture with the guidance input and the teacher's weights (the guidance
    embedding zero-initialised, so it starts as the teacher's conditional branch), or the (EMA) weights of the
    student folder ``init_from``."""
    from ..models.registry import build_denoiser

    model = replace(teacher.config.model, guidance=True)
    student = build_denoiser(model)
    if init_from is not None:
        start = load_checkpoint(init_from)
        if not start.config.student or start.config.model.to_dict() != model.to_dict():
            raise SMFError(f"--init-from {init_from}: not a distilled student of this teacher's architecture")
        student.load_state_dict(start.model.state_dict())
        return student
    missing, unexpected = student.load_state_dict(teacher.model.state_dict(), strict=False)
    if unexpected or any(not k.startswith(_GUIDANCE) for k in missing):
        raise SMFError(f"the teacher's weights do not fit its student (missing {missing[:3]}, "
                       f"unexpected {unexpected[:3]})")
    return student


def distil(data: str | Path, out: str | Path, cfg: DistilConfig, *, resume: bool = False,
           stop_after: int | None = None, progress: bool = True, text_cache: str | Path | None = None) -> list[float]:
    """Distil ``cfg.teacher`` into a few-step student trained on the corpus at ``data``; checkpoints go to
    ``out/checkpoint``, one row per step to ``out/log.csv``. Returns this run's step losses. ``stop_after``
    ends the run after that many total steps, as if killed right after a checkpoint."""
    check_distil_config(cfg)
    from accelerate import Accelerator

    from ..text.cache import TextEmbeddingCache
    from ..text.frozen import load_text_encoder

    out = Path(out)
    accelerator = Accelerator(mixed_precision=cfg.mixed_precision, cpu=not torch.cuda.is_available())
    device = accelerator.device
    teacher = load_checkpoint(cfg.teacher)  # EMA weights, float32, eval mode
    if teacher.config.student:
        raise SMFError(f"{cfg.teacher} is already a distilled student; distil from its teacher")
    tcfg = teacher.config
    feat_bias = tcfg.train.feat_bias if tcfg.train else 5.0
    ds = MotionTextDataset(data, "train", skeleton=tcfg.skeleton, seed=cfg.seed,
                           max_frames=cfg.max_frames or tcfg.max_frames, min_frames=cfg.min_frames or tcfg.min_frames,
                           feat_bias=feat_bias)
    # the corpus normalised as the teacher was: x_teacher = x_ds * scale + shift (identity for its own corpus)
    scale = torch.from_numpy(ds.std / teacher.std).float().to(device)
    shift = torch.from_numpy((ds.mean - teacher.mean) / teacher.std).float().to(device)
    renormalise = not (np.allclose(ds.std, teacher.std, rtol=1e-5) and np.allclose(ds.mean, teacher.mean, atol=1e-6))
    encoder = load_text_encoder(tcfg.text_encoder).to(device)
    cache = TextEmbeddingCache(text_cache or (out / "text-cache"), encoder)
    torch.manual_seed(cfg.seed)  # the guidance embedding's initial weights
    student = student_from_teacher(teacher, cfg.init_from)
    # the teacher's default guidance is not the student's (it takes the scale as input): the student starts at
    # None, or, regressed on the teacher at one scale, that scale
    fixed = cfg.method == "regression" and cfg.guidance_min == cfg.guidance_max
    config = replace(tcfg, model=replace(tcfg.model, guidance=True), step=None, export=None,
                     guidance=cfg.guidance_min if fixed else None,
                     distil=replace(cfg, teacher=str(resolve(cfg.teacher).resolve())))
    # the fused kernel on any device, as `smf train` (diffusion/train.py)
    optimizer = torch.optim.AdamW(param_groups(student, cfg.guidance_lr_scale), lr=cfg.lr,
                                  weight_decay=cfg.weight_decay, fused=True)
    start = 0
    if resume:
        state = load_training_state(out / CHECKPOINT_DIR)
        saved = read_config(out / CHECKPOINT_DIR)
        differ = config.resume_mismatch(saved)
        if differ:
            raise SMFError(f"cannot resume {out}: this run differs from the saved one in {', '.join(differ)}")
        from safetensors.torch import load_file

        student.load_state_dict(load_file(out / CHECKPOINT_DIR / MODEL))
        if len(state["optimizer"]["param_groups"]) != len(optimizer.param_groups):
            raise SMFError(f"cannot resume {out}: it was saved by an older `smf distil` (one optimizer group, before "
                           "--guidance-lr-scale); start a new run")
        optimizer.load_state_dict(state["optimizer"])
        start = int(state["step"])
        for group in optimizer.param_groups:
            group["weight_decay"] = cfg.weight_decay
    target = copy.deepcopy(student).eval().requires_grad_(False)
    if resume:
        target.load_state_dict(load_file(out / CHECKPOINT_DIR / EMA))
    teacher_model = teacher.model.to(device).eval().requires_grad_(False)
    target.to(device)
    cache.precompute(c.caption for e in ds.entries for c in e.captions)
    cache.flush()
    student, optimizer = accelerator.prepare(student, optimizer)
    T = tcfg.schedule.num_train_timesteps
    grid = skip_grid(T, cfg.grid)
    from .schedule import make_train_scheduler

    ab = make_train_scheduler(tcfg.schedule).alphas_cumprod.double()
    if cfg.method == "regression":
        teacher_table = solver_table(cfg.teacher_sampler, cfg.teacher_steps, tcfg.schedule).to(device)
        student_table = solver_table(STUDENT_SAMPLER, cfg.sample_steps, tcfg.schedule).to(device)
    log_path, seconds_before = open_log(out, resume, start)
    end = cfg.steps if stop_after is None else min(cfg.steps, stop_after)
    losses: list[float] = []
    bar = tqdm(range(start, end), initial=start, total=end, desc="distil", unit="step", disable=not progress)
    extra = teacher_extras(cfg.teacher)
    t0 = t_step = time.perf_counter()
    with open(log_path, "a", newline="") as log_file:
        log = csv.writer(log_file)
        for step in bar:
            batch = get_batch(ds, step, cfg.batch_size, cfg.seed, cfg.bucket)
            x0 = batch["motion"].to(device)
            if renormalise:
                x0 = x0 * scale + shift
            mask = batch["mask"].to(device)
            tokens, tmask = cache.get_or_compute(batch["caption"], device=device)
            B = x0.shape[0]
            g = torch.Generator().manual_seed(_mix(cfg.seed, step))
            index = torch.randint(0, cfg.grid, (B,), generator=g)
            noise = torch.randn(x0.shape, generator=g)
            drop = torch.rand(B, generator=g) < cfg.cond_drop
            w = cfg.guidance_min + (cfg.guidance_max - cfg.guidance_min) * torch.rand(B, generator=g)
            torch.manual_seed(_mix(cfg.seed, step, 1))  # dropout inside the student (--dropout)
            drop, w = drop.to(device), w.to(device)
            if cfg.method == "consistency":
                t_hi = grid[index]
                t_lo = (t_hi - T // cfg.grid).clamp_min(0)
                x_hi = _q(x0, noise.to(device), ab[t_hi].to(device))
                t_hi, t_lo = t_hi.to(device), t_lo.to(device)
                with torch.no_grad(), accelerator.autocast():
                    x_lo = _teacher_ddim(teacher_model, x_hi, t_hi, t_lo, ab.to(device), tokens, tmask, drop, mask, w)
                    target_f = _consistency(target, x_lo, t_lo, tokens, tmask, drop, mask, w).float()
                student.train(cfg.dropout)
                with accelerator.autocast():
                    pred_f = _consistency(student, x_hi, t_hi, tokens, tmask, drop, mask, w)
            else:  # the same noise through the teacher's whole sampler and the student's
                frames = drawn_length(cfg, step, ds.min_frames, ds.max_frames)
                if frames is not None:  # this step samples every caption at one drawn length
                    mask = torch.ones(B, frames, dtype=mask.dtype, device=device)
                    noise = torch.randn((B, frames, x0.shape[-1]), generator=g)
                eps = (noise * mask.cpu()[..., None]).to(device)
                step_noise = torch.randn((cfg.sample_steps,) + tuple(eps.shape), generator=g).to(device)
                with torch.no_grad(), accelerator.autocast():
                    target_f = teacher_sample(teacher_model, eps, tokens, tmask, drop, mask, w, teacher_table).float()
                student.train(cfg.dropout)
                with accelerator.autocast():
                    pred_f = student_sample(student, eps, tokens, tmask, drop, mask, w, student_table, step_noise)
            if cfg.loss == "l2":
                loss = masked_mse(pred_f.float(), target_f, mask)
            else:
                loss = masked_huber(pred_f.float(), target_f, mask, cfg.huber_c)
            accelerator.backward(loss)
            accelerator.clip_grad_norm_(student.parameters(), cfg.grad_clip)
            lr = distil_lr(cfg, step)
            for group in optimizer.param_groups:
                group["lr"] = lr * group["lr_scale"]
            optimizer.step()
            optimizer.zero_grad(set_to_none=True)
            with torch.no_grad():  # the target network follows the student
                own = accelerator.unwrap_model(student).state_dict()
                for k, v in target.state_dict().items():
                    if v.is_floating_point():
                        v.lerp_(own[k].detach(), 1.0 - cfg.target_decay)
            value = loss.item()
            if not math.isfinite(value):
                raise SMFError(f"distillation diverged at step {step}: loss is {value}")
            losses.append(value)
            now = time.perf_counter()
            rate = B / max(now - t_step, 1e-9)
            t_step = now
            log.writerow([step + 1, f"{value:.6f}", f"{lr:.3e}", f"{seconds_before + now - t0:.2f}", f"{rate:.1f}"])
            bar.set_postfix(loss=f"{value:.4f}", samples_s=f"{rate:.0f}")
            if (step + 1) % cfg.checkpoint_every == 0 or step + 1 == end:
                log_file.flush()
                cache.flush()
                state = {"optimizer": optimizer.state_dict(), "step": step + 1}
                save_checkpoint(out / CHECKPOINT_DIR, model=accelerator.unwrap_model(student),
                                config=replace(config, step=step + 1), mean=teacher.mean, std=teacher.std,
                                ema_state=target.state_dict(), training_state=state)
                for name, f in extra.items():
                    shutil.copy2(f, out / CHECKPOINT_DIR / name)
    cache.close()
    return losses


def teacher_extras(teacher: str | Path) -> dict[str, Path]:
    """The files of the teacher's folder that are not its own weights and config (name -> file), carried into the
    student's checkpoints; for a teacher shipped inside its student's folder, the text side is the student's
    (:func:`~.checkpoint.companion_file`)."""
    from ..text import TEXT_SIDE_FILES

    folder = resolve(teacher)
    own = {p.name: p for p in sorted(folder.iterdir()) if p.is_file() and p.name not in _OWN_FILES}
    return {**companion_files(folder, TEXT_SIDE_FILES), **own}


def _q(x0: torch.Tensor, noise: torch.Tensor, ab: torch.Tensor) -> torch.Tensor:
    """The forward process at alpha-bar ``ab`` (B,): sqrt(ab) x0 + sqrt(1 - ab) noise."""
    a = ab.to(x0.dtype)[:, None, None]
    return a.sqrt() * x0 + (1 - a).sqrt() * noise


def _teacher_ddim(teacher, x, t_hi, t_lo, ab, tokens, tmask, drop, mask, w) -> torch.Tensor:
    """One DDIM (eta 0) step of the teacher under classifier-free guidance at scale ``w`` (B,), from t_hi
    to t_lo: x0 = u + w (c - u), eps = (x - sqrt(ab) x0) / sqrt(1 - ab), x' = sqrt(ab') x0 + sqrt(1 - ab') eps."""
    B = x.shape[0]
    both = torch.cat([drop, torch.ones_like(drop)])
    t2 = torch.cat([t_hi, t_hi]).to(x.dtype)
    pair = teacher(torch.cat([x, x]), t2, torch.cat([tokens, tokens]), torch.cat([tmask, tmask]), both,
                   torch.cat([mask, mask])).float()
    c, u = pair[:B], pair[B:]
    x0 = u + w[:, None, None] * (c - u)
    a_hi, a_lo = ab[t_hi].float()[:, None, None], ab[t_lo].float()[:, None, None]
    eps = (x.float() - a_hi.sqrt() * x0) / (1 - a_hi).sqrt()
    return a_lo.sqrt() * x0 + (1 - a_lo).sqrt() * eps


def teacher_sample(teacher, eps, tokens, tmask, drop, mask, w, table, rescale: float = 0.0) -> torch.Tensor:
    """The teacher's sample (B, T, D) from noise ``eps`` by the sampler of ``table``, under classifier-free
    guidance at scale ``w`` (B,) (``rescale``: the guidance rescale's share): one pass where every w is 1."""
    cond = teacher.condition(tokens, tmask, drop)
    uncond = None if bool((w == 1).all()) else teacher.condition(tokens, tmask, torch.ones_like(drop))
    denoiser = guided(teacher, cond, uncond, mask, w[:, None, None].to(eps.dtype), rescale=rescale)
    return run_solver(denoiser, table, eps * table.init_sigma, None)


def student_sample(student, eps, tokens, tmask, drop, mask, w, table, step_noise) -> torch.Tensor:
    """The student's sample (B, T, D) from noise ``eps`` at guidance input ``w`` (B,), as the pipeline draws it
    (``table``: the student's sampler and steps; ``step_noise`` (K, B, T, D) its re-noising), with gradients."""
    cond = student.condition(tokens, tmask, drop, w)
    return run_solver(model_denoiser(student, cond, mask), table, eps * table.init_sigma, step_noise)


def _consistency(model, x, t, tokens, tmask, drop, mask, w) -> torch.Tensor:
    """f(x, t, w) = c_skip(t) x + c_out(t) D(x, t, w): the consistency function in the x0 parametrisation."""
    c_skip, c_out = consistency_scalings(t.double(), TIMESTEP_SCALING)
    d = model(x, t.to(x.dtype), tokens, tmask, drop, mask, guidance=w)
    return c_skip.to(d.dtype)[:, None, None] * x.to(d.dtype) + c_out.to(d.dtype)[:, None, None] * d


__all__ = ["DistilConfig", "METHODS", "check_distil_config", "distil", "distil_lr", "masked_huber", "skip_grid",
           "student_sample", "teacher_sample",
           "student_from_teacher"]
