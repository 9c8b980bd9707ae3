"""The sampling loop as small pieces (k-diffusion style).

- a *denoiser* is a callable ``(x_t, step) -> x0``: x_t (B, T, D) the model input of step ``step``, x0 the
  clean-motion prediction (B, T, D); :func:`model_denoiser` makes one from a model and its text condition;
- guidance is a wrapper that builds a denoiser (:func:`guided`): :func:`cfg_batched` (conditional and unconditional passes in
  one batch) or :func:`cfg_two_pass`;
- x0 hooks (footskate cleanup in the loop, editing constraints) wrap a denoiser: :func:`with_x0_hook`;
- the loops: :func:`run_diffusers` (any diffusers scheduler of the registry, the reference) and
  :func:`run_solver` (a precomputed coefficient table, :mod:`.solvers`: static shapes, no host syncs).
- :class:`Noise` draws the initial and per-step noise of a call from one seed or one seed per item.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import torch

from ..core.errors import SMFError
from ..core.limits import fresh_seed
from ..models.base import TextCondition
from ..core.noise import draw_key, draws
from .schedulers import SamplerSpec, model_output_for
from .solvers import SolverTable


@dataclass(frozen=True)
class Step:
    """Where a denoiser call is in the loop: step ``index`` of ``count``, model timesteps ``t`` (B,)."""

    index: int
    count: int
    t: torch.Tensor


class DenoiserFn(Protocol):
    def __call__(self, x: torch.Tensor, step: Step) -> torch.Tensor: ...


X0Hook = Callable[[torch.Tensor, Step], torch.Tensor]  # (x0 (B, T, D), step) -> x0
XHook = Callable[[torch.Tensor, Step], torch.Tensor]  # (x after step `step`, step) -> x


def model_denoiser(model, cond: TextCondition, motion_mask: torch.Tensor | None) -> DenoiserFn:
    """The model's x0 prediction under a fixed text condition (batch B)."""
    return lambda x, step: model.denoise(x, step.t.to(x.dtype), cond, motion_mask)


def cfg_batched(model, cond: TextCondition, uncond: TextCondition, motion_mask: torch.Tensor | None,
                scale: float | torch.Tensor, rescale: float = 0.0) -> DenoiserFn:
    """Classifier-free guidance ``u + scale * (c - u)`` with both passes in one forward of batch 2B; the
    pair's condition and mask are built once here, not at every step. ``scale`` may be a 0-d tensor (a
    CUDA graph's input); ``rescale``: :func:`rescale_guidance`'s share (0: plain guidance)."""
    pair = TextCondition(torch.cat([cond.features, uncond.features]), torch.cat([cond.mask, uncond.mask]),
                         _cat_opt(cond.keep, uncond.keep, cond.features), _cat_opt(cond.sentence, uncond.sentence))
    mask2 = None if motion_mask is None else torch.cat([motion_mask, motion_mask])

    def denoise(x: torch.Tensor, step: Step) -> torch.Tensor:
        t = step.t.to(x.dtype)
        c, u = model.denoise(torch.cat([x, x]), torch.cat([t, t]), pair, mask2).chunk(2)
        return _combine(c, u, scale, motion_mask, rescale)

    return denoise


def _combine(c: torch.Tensor, u: torch.Tensor, scale, motion_mask: torch.Tensor | None, rescale: float) -> torch.Tensor:
    """``u + scale * (c - u)`` of the conditional and unconditional predictions, rescaled by a share ``rescale``."""
    out = u + scale * (c - u)
    return rescale_guidance(out, c, motion_mask, rescale) if rescale else out


def rescale_guidance(guided_x0: torch.Tensor, cond_x0: torch.Tensor, motion_mask: torch.Tensor | None,
                     share: float) -> torch.Tensor:
    """Guidance rescale (Lin et al., 2024): the guided prediction (B, T, D) scaled per item to the standard
    deviation of the conditional one ``cond_x0`` (over its valid frames, ``motion_mask`` (B, T), and features),
    mixed with the unscaled one by ``share`` in [0, 1]. A high scale keeps what it picks out of the condition but
    not the exaggeration (an adapter's guided running was far too fast: docs/adapters.md)."""
    w = torch.ones(guided_x0.shape[:2], dtype=guided_x0.dtype, device=guided_x0.device) if motion_mask is None \
        else motion_mask.to(guided_x0.dtype)
    w = w[..., None].expand_as(guided_x0)
    n = w.sum(dim=(1, 2), keepdim=True).clamp_min(1.0)

    def sd(v: torch.Tensor) -> torch.Tensor:
        mean = (v * w).sum(dim=(1, 2), keepdim=True) / n
        return (((v - mean) ** 2 * w).sum(dim=(1, 2), keepdim=True) / n).sqrt()

    scaled = guided_x0 * (sd(cond_x0) / sd(guided_x0).clamp_min(1e-8))
    return share * scaled + (1.0 - share) * guided_x0


def guided(model, cond: TextCondition, uncond: TextCondition | None, motion_mask: torch.Tensor | None,
           scale: float | torch.Tensor, batched: bool = True, rescale: float = 0.0) -> DenoiserFn:
    """The denoiser of a call: the model under the text condition, with classifier-free guidance in x0 space
    (``u + scale * (c - u)``, both passes in one batch, or two; ``rescale``: :func:`rescale_guidance`'s share)
    unless ``uncond`` is None (no guidance)."""
    if uncond is None:
        return model_denoiser(model, cond, motion_mask)
    if batched:
        return cfg_batched(model, cond, uncond, motion_mask, scale, rescale)
    return cfg_two_pass(model_denoiser(model, cond, motion_mask), model_denoiser(model, uncond, motion_mask), scale,
                        motion_mask, rescale)


def cfg_two_pass(cond: DenoiserFn, uncond: DenoiserFn, scale: float, motion_mask: torch.Tensor | None = None,
                 rescale: float = 0.0) -> DenoiserFn:
    """Classifier-free guidance as two separate passes (less memory, twice the launches)."""

    def denoise(x: torch.Tensor, step: Step) -> torch.Tensor:
        return _combine(cond(x, step), uncond(x, step), scale, motion_mask, rescale)

    return denoise


def with_x0_hook(denoiser: DenoiserFn, hook: X0Hook) -> DenoiserFn:
    """A denoiser whose prediction passes through ``hook(x0, step)`` (e.g. a cleanup or a constraint)."""
    return lambda x, step: hook(denoiser(x, step), step)


def replace_x0(known: torch.Tensor, mask: torch.Tensor,
               project: Callable[[torch.Tensor], torch.Tensor] | None = None) -> X0Hook:
    """An x0 hook imposing a known part: x0 takes ``known`` (B, T, D) where ``mask`` (B, T, D) is True (then
    ``project``, e.g. a root-path constraint that is not a fixed set of entries, if given)."""

    def hook(x0: torch.Tensor, step: Step) -> torch.Tensor:
        x0 = torch.where(mask, known.to(x0.dtype), x0)
        return x0 if project is None else project(x0)

    return hook


def impute_xt(known: torch.Tensor, mask: torch.Tensor, eps: torch.Tensor, table: SolverTable) -> XHook:
    """An x hook imposing a known part in x_t (imputation): after step k the known entries are ``known``
    noised to that step's level with the fixed noise ``eps`` (B, T, D); after the last step they are exact."""

    def hook(x: torch.Tensor, step: Step) -> torch.Tensor:
        k = step.index
        noised = table.level_x0[k] * known + table.level_eps[k] * eps
        return torch.where(mask, noised.to(x.dtype), x)

    return hook


def _cat_opt(a: torch.Tensor | None, b: torch.Tensor | None, like: torch.Tensor | None = None) -> torch.Tensor | None:
    """Concatenate two optional per-item tensors; a missing ``keep`` means all True."""
    if a is None and b is None:
        return None
    if like is not None:
        n = like.shape[0]
        a = torch.ones(n, dtype=torch.bool, device=like.device) if a is None else a
        b = torch.ones(n, dtype=torch.bool, device=like.device) if b is None else b
    return torch.cat([a, b])


class Noise:
    """The noise of one sampling call: (B, T, D) standard normal draws of the portable noise
    (:mod:`stablemofusion.core.noise`, the same numbers on every runtime, made on the call's device), zeros past each
    item's length.

    ``seed`` an int: item k draws from stream k of it. A list (one per item): item k from stream 0 of its own
    seed, so an item's result does not depend on the others it is batched with (and equals generating it
    alone). None: a fresh seed. Each :meth:`draw` takes the next draw index (the initial noise is draw 0)."""

    def __init__(self, seed: int | list[int] | None, lengths: list[int], dim: int, device: torch.device):
        self.lengths, self.dim, self.device = list(lengths), int(dim), torch.device(device)
        self.frames = max(self.lengths)
        self.per_item = isinstance(seed, (list, tuple))
        if self.per_item and len(seed) != len(self.lengths):
            raise SMFError(f"give one seed per prompt: {len(seed)} seeds for {len(self.lengths)} prompts")
        self.seed = [int(s) for s in seed] if self.per_item else (fresh_seed() if seed is None else int(seed))
        self.next_draw = 0

    def draw(self, count: int | None = None) -> torch.Tensor:
        """``count`` draws stacked (count, B, T, D), or one (B, T, D) when ``count`` is None; float32 on
        the device."""
        n = 1 if count is None else count
        # made on the device as numpy makes them (float64 inside: a device without it, such as Apple's, gets them
        # made on the CPU)
        where = self.device if self.device.type in ("cpu", "cuda") else torch.device("cpu")
        out = draws(self.seed, self.lengths, self.dim, range(self.next_draw, self.next_draw + n),
                    like=torch.empty(0, device=where)).to(self.device)
        self.next_draw += n
        return out[0] if count is None else out

    def generator(self) -> torch.Generator | list[torch.Generator]:
        """A generator for schedulers that draw their own step noise (no ``variance_noise``): seeded from the
        key of the call's next draw (these samplers are torch-only)."""
        self.next_draw += 1
        make = lambda s, stream: torch.Generator(device=self.device).manual_seed(  # noqa: E731
            draw_key(s, stream, self.next_draw - 1))
        if self.per_item:
            return [make(s, 0) for s in self.seed]
        return make(self.seed, 0)


def run_diffusers(denoiser: DenoiserFn, scheduler, spec: SamplerSpec, noise: Noise, dtype: torch.dtype,
                  batch: int) -> torch.Tensor:
    """The reference loop over a diffusers scheduler (``set_timesteps`` already called): returns the final
    sample (B, T, D) in ``dtype`` on the noise's device."""
    x = (noise.draw() * scheduler.init_noise_sigma).to(dtype)
    count = len(scheduler.timesteps)
    steps_noise = noise.draw(count) if spec.step_noise else None
    for k, t in enumerate(scheduler.timesteps):
        step = Step(k, count, t.expand(batch).to(x.device))
        x0 = denoiser(scheduler.scale_model_input(x, t), step)
        out = model_output_for(scheduler, x0, x, t)
        if spec.step_noise:
            x = scheduler.step(out, t, x, variance_noise=steps_noise[k].to(x.dtype)).prev_sample
        elif spec.stochastic:
            x = scheduler.step(out, t, x, generator=noise.generator()).prev_sample
        else:
            x = scheduler.step(out, t, x).prev_sample
    return x


def run_solver(denoiser: DenoiserFn, table: SolverTable, x: torch.Tensor, step_noise: torch.Tensor | None,
               x_hook: XHook | None = None) -> torch.Tensor:
    """The loop of a precomputed coefficient table: ``x`` (B, T, D) the initial noise already scaled by
    ``table.init_sigma``, ``step_noise`` (K, B, T, D) for stochastic tables; ``x_hook`` applied to the sample
    after each step (e.g. :func:`impute_xt`). Only tensor arithmetic on the table's device: capturable as one
    CUDA graph. Returns the final sample (B, T, D)."""
    K, B = table.steps, x.shape[0]
    prev = torch.zeros_like(x)
    for k in range(K):
        step = Step(k, K, table.t[k].expand(B))
        x0 = denoiser(x * table.c_in[k], step)
        nxt = table.a[k] * x + table.b[k] * x0 + table.c[k] * prev
        if table.stochastic:
            nxt = nxt + table.d[k] * step_noise[k]
        x, prev = nxt, x0
        if x_hook is not None:
            x = x_hook(x, step)
    return x
