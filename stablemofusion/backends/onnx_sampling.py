"""The sampling call of the portable runtime, in numpy: the same steps as the torch path's
(:func:`stablemofusion.backends.torch_sampling.sample` with a coefficient table, :func:`~stablemofusion.diffusion.
sampling.run_solver`) on the same portable noise, so both give the same motion."""

from __future__ import annotations

from typing import Callable

import numpy as np

from ..core.noise import batch_noise, draws
from .onnx_graphs import PortableModel, Table

Denoiser = Callable[[np.ndarray, int], np.ndarray]  # (model input x (B, T, D), step k) -> x0 (B, T, D)


def run_table(denoiser: Denoiser, table: Table, x: np.ndarray, step_noise: np.ndarray | None,
              x0_hook: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """The loop of a coefficient table: ``x`` the initial noise scaled by ``table.init_sigma``, ``step_noise``
    (K, B, T, D) for stochastic tables, ``x0_hook`` applied to every prediction (e.g. a known part imposed).
    Returns the final sample."""
    prev = np.zeros_like(x)
    for k in range(table.steps):
        x0 = denoiser(x * table.c_in[k], k)
        if x0_hook is not None:
            x0 = x0_hook(x0)
        nxt = table.a[k] * x + table.b[k] * x0 + table.c[k] * prev
        if table.stochastic:
            nxt = nxt + table.d[k] * step_noise[k]
        x, prev = nxt, x0
    return x


def guided_denoiser(model: PortableModel, tokens: np.ndarray, mask: np.ndarray, lengths: list[int], T: int,
                    table: Table, guidance: float) -> Denoiser:
    """The model under the text condition: a student takes ``guidance`` as input; a teacher with guidance other
    than 1 runs the conditional and unconditional passes in one batch (``u + guidance * (c - u)``)."""
    B = len(lengths)
    motion_mask = np.arange(T)[None] < np.asarray(lengths)[:, None]
    if model.student or guidance == 1.0:
        cond = model.condition(tokens, mask, guidance=guidance)
        return lambda x, k: model.denoise(x, np.full(B, table.t[k], np.float32), cond, motion_mask)
    c, u = model.condition(tokens, mask), model.condition(tokens, mask, drop=True)
    pair = {key: np.concatenate([c[key], u[key]]) for key in c}
    mask2 = np.concatenate([motion_mask, motion_mask])
    scale = np.float32(guidance)

    def denoise(x: np.ndarray, k: int) -> np.ndarray:
        out = model.denoise(np.concatenate([x, x]), np.full(2 * B, table.t[k], np.float32), pair, mask2)
        cond_x0, uncond_x0 = out[:B], out[B:]
        return uncond_x0 + scale * (cond_x0 - uncond_x0)

    return denoise


def sample(model: PortableModel, tokens: np.ndarray, mask: np.ndarray, lengths: list[int], seed: int | list[int], *,
           guidance: float, sampler: str, steps: int,
           x0_hook: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """The model's raw features (B, max(lengths), D) in dataset units (float32), before the final stage: item k
    draws its noise from ``seed`` (stream k) or ``seed[k]`` (:func:`stablemofusion.core.noise.batch_noise`).
    ``x0_hook``: applied to every prediction (normalised), e.g. an edit's known part
    (:func:`stablemofusion.core.edit_plan.x0_constraint`)."""
    table = model.table(sampler, steps)
    T = max(lengths)
    x = batch_noise(seed, lengths, model.dim, draw=0) * np.float32(table.init_sigma)
    step_noise = draws(seed, lengths, model.dim, range(1, 1 + table.steps)) if table.stochastic else None
    x = run_table(guided_denoiser(model, tokens, mask, lengths, T, table, guidance), table, x, step_noise, x0_hook)
    return x * model.std + model.mean


__all__ = ["run_table", "guided_denoiser", "sample"]
