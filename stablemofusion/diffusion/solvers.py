"""Samplers as precomputed coefficient tables: every step is one fixed linear update, no Python scalars.

For the samplers here (DDIM, Euler, DPM-Solver++ 2M ODE and SDE, with or without Karras sigmas) step ``k``
of ``K`` is linear in the current sample, the last two x0 predictions and the step noise::

    x0_k    = D(c_in[k] * x_k, t[k])
    x_{k+1} = a[k] * x_k + b[k] * x0_k + c[k] * x0_{k-1} + d[k] * z_k

The timesteps and sigmas come from the diffusers scheduler of the same name (``set_timesteps``); the
coefficients are computed here once per (sampler, steps) in float64 and kept as device tensors, so the loop
(:func:`stablemofusion.diffusion.sampling.run_solver`) has static shapes and no host synchronisation and can
be captured as one CUDA graph. Equal to the diffusers schedulers on the same noise (tests, 1e-4).

Facts used (DPM-Solver++, Lu et al. 2022; the diffusers implementation's choices): data prediction in the
VP parametrisation x = alpha * x0 + sigma * eps with alpha = 1/sqrt(1 + s^2), sigma = s * alpha for the
scheduler's sigma s; the first step and the last step are first order (``lower_order_final``, final sigma
0); second-order steps use the midpoint form D1 = (x0_k - x0_{k-1}) / r, r = h_{k-1} / h_k.

Consistency sampling (``lcm``, LCM / consistency models): f_k = c_skip(t_k) x_k + c_out(t_k) x0_k, then
x_{k+1} = sqrt(ab_{k+1}) f_k + sqrt(1 - ab_{k+1}) z_k (ab of the next timestep; the last step returns f_k),
so a = sqrt(ab') c_skip, b = sqrt(ab') c_out, d = sqrt(1 - ab').
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..core.errors import SMFError
from .schedulers import SIGMA_DATA, make_sampler, parse_sampler
from .schedule import ScheduleConfig


@dataclass
class SolverTable:
    """Per-step coefficients (K,) of a sampler run of K steps (see the module docstring), on one device."""

    name: str  # the sampler
    t: torch.Tensor  # model timesteps (float32)
    c_in: torch.Tensor  # model input scale
    a: torch.Tensor
    b: torch.Tensor
    c: torch.Tensor
    d: torch.Tensor
    init_sigma: float  # initial noise scale
    stochastic: bool
    # the noise level of x after step k: x = level_x0[k] * x0 + level_eps[k] * eps (for imputing known parts)
    level_x0: torch.Tensor
    level_eps: torch.Tensor

    @property
    def steps(self) -> int:
        return int(self.t.shape[0])

    def to(self, device: torch.device | str, dtype: torch.dtype = torch.float32) -> "SolverTable":
        conv = (lambda v: v.to(device=device, dtype=dtype))
        return SolverTable(self.name, self.t.to(device=device, dtype=torch.float32), conv(self.c_in), conv(self.a),
                           conv(self.b), conv(self.c), conv(self.d), self.init_sigma, self.stochastic,
                           conv(self.level_x0), conv(self.level_eps))


def solver_table(name: str, steps: int, schedule: ScheduleConfig | None = None) -> SolverTable:
    """The coefficient table of sampler ``name`` (see :data:`stablemofusion.diffusion.schedulers.SAMPLERS`,
    those with ``fast``) for ``steps`` steps, on the CPU."""
    base, spec, _ = parse_sampler(name)
    if not spec.fast:
        raise SMFError(f"sampler {name!r} has no fast (precomputed) form; fast samplers: "
                       + ", ".join(n for n in _fast_names()))
    if steps < 1:
        raise SMFError(f"steps must be at least 1, got {steps}")
    if base == "lcm" and steps > sched_grid(name):
        raise SMFError(f"the lcm sampler takes at most {sched_grid(name)} steps (its skip schedule), got {steps}")
    sched = make_sampler(name, schedule)
    sched.set_timesteps(steps, device="cpu")
    t = sched.timesteps.double().numpy()
    build = {"ddim": _ddim, "euler": _euler, "dpmsolver++": _dpmpp_2m, "sde-dpmsolver++": _dpmpp_2m_sde,
             "lcm": _lcm}[base]
    (c_in, a, b, c, d), (lx, le) = build(sched, t), _levels(base, sched, t)
    f = (lambda v: torch.from_numpy(np.asarray(v, dtype=np.float64)))
    return SolverTable(name, f(t).float(), f(c_in), f(a), f(b), f(c), f(d), float(sched.init_noise_sigma), spec.stochastic,
                       f(lx), f(le))


def _levels(base: str, sched, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K,) scales of x0 and of the noise in the sample after each step, in the sampler's own space."""
    if base == "ddim":
        ac = sched.alphas_cumprod.double().numpy()
        prev = t.astype(int) - sched.config.num_train_timesteps // sched.num_inference_steps
        ab = np.where(prev >= 0, ac[np.clip(prev, 0, None)], float(sched.final_alpha_cumprod))
        return np.sqrt(ab), np.sqrt(1 - ab)
    if base == "lcm":
        root = np.sqrt(_lcm_next_alpha(sched, t))
        return root, np.sqrt(1 - root ** 2)
    s = sched.sigmas.double().numpy()[1:len(t) + 1]
    if base == "euler":  # x = x0 + s * eps
        return np.ones_like(s), s
    return 1 / np.sqrt(s ** 2 + 1), s / np.sqrt(s ** 2 + 1)


def _fast_names() -> list[str]:
    from .schedulers import sampler_names

    return [n for n in sampler_names() if parse_sampler(n)[1].fast]


def _zeros(n: int) -> np.ndarray:
    return np.zeros(n, dtype=np.float64)


def _ddim(sched, t: np.ndarray):
    """DDIM, eta 0: x' = sqrt(ab') x0 + sqrt(1 - ab') eps, eps = (x - sqrt(ab) x0) / sqrt(1 - ab)."""
    ac = sched.alphas_cumprod.double().numpy()
    final = float(sched.final_alpha_cumprod)
    stride = sched.config.num_train_timesteps // sched.num_inference_steps
    K = len(t)
    ab = ac[t.astype(int)]
    prev = t.astype(int) - stride
    ab_prev = np.where(prev >= 0, ac[np.clip(prev, 0, None)], final)
    a = np.sqrt(1 - ab_prev) / np.sqrt(1 - ab)
    b = np.sqrt(ab_prev) - a * np.sqrt(ab)
    return np.ones(K), a, b, _zeros(K), _zeros(K)


def _euler(sched, t: np.ndarray):
    """Euler on the probability-flow ODE in sigma (x = x0 + s eps): x' = x + (x - x0) / s * (s' - s); the
    model sees x / sqrt(s^2 + 1)."""
    s = sched.sigmas.double().numpy()
    K = len(t)
    ratio = (s[1:K + 1] - s[:K]) / s[:K]
    return 1 / np.sqrt(s[:K] ** 2 + 1), 1 + ratio, -ratio, _zeros(K), _zeros(K)


def sched_grid(name: str) -> int:
    """Points of a consistency sampler's skip schedule."""
    return int(parse_sampler(name)[1].options["original_inference_steps"])


def consistency_scalings(t, scaling: float) -> tuple:
    """LCM's boundary-condition scalings at timesteps ``t`` (numpy or torch): c_skip = s_d^2 / ((t scaling)^2 +
    s_d^2), c_out = t scaling / sqrt((t scaling)^2 + s_d^2); c_skip(0) = 1, so f(x, 0) = x."""
    scaled = t * scaling
    denom = scaled ** 2 + SIGMA_DATA ** 2
    return SIGMA_DATA ** 2 / denom, scaled / denom ** 0.5


def _lcm_next_alpha(sched, t: np.ndarray) -> np.ndarray:
    """alpha-bar of the timestep after each step (1 after the last: the sample is then x0 itself)."""
    ac = sched.alphas_cumprod.double().numpy()
    nxt = np.concatenate([t[1:].astype(int), [-1]])
    return np.where(nxt >= 0, ac[np.clip(nxt, 0, None)], 1.0)


def _lcm(sched, t: np.ndarray):
    """Multistep consistency sampling (see the module docstring)."""
    K = len(t)
    c_skip, c_out = consistency_scalings(t.astype(np.float64), float(sched.config.timestep_scaling))
    ab = _lcm_next_alpha(sched, t)
    return np.ones(K), np.sqrt(ab) * c_skip, np.sqrt(ab) * c_out, _zeros(K), np.sqrt(1 - ab)


def _vp(sched) -> tuple[np.ndarray, np.ndarray]:
    """alpha, sigma of the VP parametrisation at each of the scheduler's sigmas (K + 1)."""
    s = sched.sigmas.double().numpy()
    alpha = 1 / np.sqrt(s ** 2 + 1)
    return alpha, s * alpha


def _orders(K: int) -> np.ndarray:
    """Solver order of each step: 1 for the first and (final sigma 0) the last step, else 2."""
    order = np.full(K, 2)
    order[0] = 1
    order[K - 1] = 1
    return order


def _ratios(alpha: np.ndarray, sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each step k: e^{-h_k} (h_k = lambda_{k+1} - lambda_k, lambda = log(alpha / sigma)) and r_k =
    h_{k-1} / h_k (1 where undefined). Computed from ratios so a final sigma of 0 gives e^{-h} = 0."""
    K = len(alpha) - 1
    e = (sigma[1:] / alpha[1:]) / (sigma[:-1] / alpha[:-1])  # e^{-h_k}
    lam = np.log(alpha[:K]) - np.log(sigma[:K])
    h_prev = np.concatenate([[np.nan], np.diff(lam)])  # h_{k-1} = lambda_k - lambda_{k-1}
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -np.log(e)
        r = np.where(np.isfinite(h_prev) & np.isfinite(h) & (h != 0), h_prev / h, 1.0)
    return e, h, r


def _dpmpp_2m(sched, t: np.ndarray):
    """DPM-Solver++ 2M (ODE), midpoint: x' = (s'/s) x + alpha' (1 - e^{-h}) (x0 + D1 / 2)."""
    alpha, sigma = _vp(sched)
    K = len(t)
    e, _, r = _ratios(alpha, sigma)
    a = sigma[1:] / sigma[:-1]
    g = alpha[1:] * (1 - e)
    second = _orders(K) == 2
    b = np.where(second, g * (1 + 0.5 / r), g)
    c = np.where(second, -g * 0.5 / r, 0.0)
    return np.ones(K), a, b, c, _zeros(K)


def _dpmpp_2m_sde(sched, t: np.ndarray):
    """SDE-DPM-Solver++ 2M, midpoint: x' = (s'/s) e^{-h} x + alpha' (1 - e^{-2h}) (x0 + D1 / 2)
    + s' sqrt(1 - e^{-2h}) z."""
    alpha, sigma = _vp(sched)
    K = len(t)
    e, _, r = _ratios(alpha, sigma)
    a = sigma[1:] / sigma[:-1] * e
    g = alpha[1:] * (1 - e ** 2)
    second = _orders(K) == 2
    b = np.where(second, g * (1 + 0.5 / r), g)
    c = np.where(second, -g * 0.5 / r, 0.0)
    d = sigma[1:] * np.sqrt(1 - e ** 2)
    return np.ones(K), a, b, c, d
