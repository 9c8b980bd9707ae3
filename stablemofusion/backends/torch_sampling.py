"""The torch backend's sampling: the engine chosen once per call (:func:`resolve_engine`), and one call shared by
every task (:func:`sample`): text condition, noise, the denoiser (guidance, x0 hooks), the loop of the engine, back
to dataset units. Constraints come as generic hooks:

- ``x0_hook(x0, step) -> x0`` on the model's prediction (normalised, model dtype and device);
- ``xt_hook(eps, table) -> XHook``: builds the hook applied to x_t after each step from the call's initial
  noise ``eps`` and solver table (imputation needs both).
"""

from __future__ import annotations

import warnings
from typing import Callable

import torch
from tqdm import tqdm

from ..diffusion.engine import COMPILED_ENGINES, GRAPH_ENGINES, check_engine, default_engine
from ..diffusion.schedulers import make_sampler, sampler_spec
from ..diffusion.sampling import (Noise, Step, X0Hook, XHook, guided, impute_xt, replace_x0, run_diffusers, run_solver,
                                  with_x0_hook)
from ..diffusion.solvers import SolverTable
from ..core.edit_plan import EditPlan
from ..core.errors import SMFError
from ..footskate import FootskateOptions
from ..footskate.cleanup import cleanup_features
from ..core.final import EngineWarning
from ..core.settings import Settings

XtHookFactory = Callable[[torch.Tensor, SolverTable], XHook]
HOOK_ENGINES = ("eager", "fast")  # the engines whose loop runs step by step on the host: they apply x0 / x_t hooks


@torch.no_grad()
def sample(c, prompts: list[str], lengths: list[int], settings: Settings,
           seed: int | list[int] | None, *, x0_hook: X0Hook | None = None, xt_hook: XtHookFactory | None = None,
           batched_cfg: bool = True, progress: bool = False) -> torch.Tensor:
    """The model's raw features (B, max(lengths), D) in dataset units (CPU, float32), before the final stage.
    ``seed``: one for the batch, or one per item (then an item does not depend on the others batched with
    it). In footskate 'loop' mode the last predicted x0 are cleaned (rigid body) inside the loop.
    ``progress``: a tqdm bar over the steps (loops that run step by step on the host: not CUDA graphs)."""
    if not settings.resolved:
        raise ValueError("sample() takes settings resolved for the model: TorchBackend.settings(...)")
    engine = settings.engine
    if (x0_hook is not None or xt_hook is not None or settings.footskate == "loop") and engine not in HOOK_ENGINES:
        raise ValueError(f"hooks need one of the engines {HOOK_ENGINES}, got {engine!r}: resolve with hooks=True")
    B, T, D = len(prompts), max(lengths), int(c.mean.shape[0])
    noise = Noise(seed, lengths, D, c.device)
    mask = (torch.arange(T)[None] < torch.tensor(lengths)[:, None]).to(c.device)
    # a student, or guidance 1: uncond None, one forward a step
    cond, uncond = c.text_condition(prompts, settings.guidance_scale, uncond=settings.guided)
    if engine in COMPILED_ENGINES + GRAPH_ENGINES and batched_cfg:
        table = c.solver(settings.sampler, settings.steps)
        x = noise.draw() * table.init_sigma
        step_noise = noise.draw(settings.steps).to(c.dtype) if table.stochastic else None
        x = c.solver_engine(engine).run(cond, uncond, mask, settings.guidance_scale, table, x.to(c.dtype), step_noise)
        return c.denormalise(x)
    denoiser = guided(c.model, cond, uncond, mask, settings.guidance_scale, batched_cfg)
    if settings.footskate == "loop":
        denoiser = with_x0_hook(denoiser, footskate_hook(c, lengths, settings.footskate_options))
    if x0_hook is not None:
        denoiser = with_x0_hook(denoiser, x0_hook)
    if progress:
        denoiser = with_x0_hook(denoiser, progress_hook(settings.steps))
    if engine == "eager":
        sched = make_sampler(settings.sampler, c.schedule)
        sched.set_timesteps(settings.steps, device=c.device)
        return c.denormalise(run_diffusers(denoiser, sched, sampler_spec(settings.sampler), noise, c.dtype, B))
    table = c.solver(settings.sampler, settings.steps)
    eps = noise.draw().to(c.dtype)
    step_noise = noise.draw(settings.steps).to(c.dtype) if table.stochastic else None
    x_hook = None if xt_hook is None else xt_hook(eps, table)
    return c.denormalise(run_solver(denoiser, table, eps * table.init_sigma, step_noise, x_hook))


def resolve_engine(name: str, device: torch.device, sampler: str, *, hooks: bool = False) -> str:
    """The engine a call runs with, decided once: ``name`` ('auto' = the fastest that works here) for the
    sampler. Calls with x0 / x_t hooks (edits, timelines, live streams, footskate 'loop') run with one of
    HOOK_ENGINES: 'auto' picks 'fast'; another engine asked for by name runs them with 'fast' and says so
    (:class:`EngineWarning`)."""
    check_engine(name, device)
    fast = sampler_spec(sampler).fast
    requested = name
    if name == "auto":
        name = default_engine(device, fast)
    elif name != "eager" and not fast:
        raise SMFError(f"sampler {sampler!r} runs only with the eager engine (no precomputed form)")
    if hooks and name not in HOOK_ENGINES:
        if requested != "auto":
            warnings.warn(f"engine {requested!r} cannot run edits, timelines, live streams or footskate 'loop' "
                          "(hooks change every step); this call runs with 'fast'", EngineWarning, stacklevel=4)
        return "fast"
    return name


def edit_hooks(plan: EditPlan, mean, std, batch: int, device, dtype, impose: str = "x0"):
    """The sampling hooks imposing ``plan`` on a batch (:mod:`stablemofusion.backends.torch_sampling`), built once on
    the torch side: (x0 hook or None, x_t hook factory or None). ``mean``/``std`` (D,) float32 the model's
    normalisation; ``impose`` 'x0' (replace the prediction's known entries and project its root) or 'xt'
    (impute the noisy sample; the root constraints still on x0)."""
    on = plan.on(device)
    mean64, std64 = mean.double().to(device), std.double().to(device)
    mean32, std32 = mean.to(device), std.to(device)

    def normalise(f: torch.Tensor) -> torch.Tensor:
        return ((f.float() - mean32) / std32).to(device, dtype)

    known = normalise(on.known).expand(batch, -1, -1)
    kmask = on.mask.expand(batch, -1, -1)
    def constrain(x0: torch.Tensor) -> torch.Tensor:  # root constraints: not a fixed set of entries
        feats = x0.double() * std64 + mean64
        return normalise(torch.stack([on.project(f) for f in feats]))

    project = None if plan.land is None and plan.path is None else constrain
    if impose == "x0":
        return replace_x0(known, kmask, project), None
    x0_hook = None if project is None else (lambda x0, step: project(x0))
    return x0_hook, lambda eps, table: impute_xt(known, kmask, eps, table)


def progress_hook(steps: int) -> X0Hook:
    """An x0 hook that only advances a tqdm bar of ``steps`` steps."""
    bar = tqdm(total=steps, desc="denoise", unit="step")

    def hook(x0: torch.Tensor, step: Step) -> torch.Tensor:
        bar.update(1)
        if step.index + 1 == step.count:
            bar.close()
        return x0

    return hook


def footskate_hook(c, lengths: list[int], options) -> X0Hook:
    """The in-loop footskate cleanup (on the rigid body) as an x0 hook, on the steps ``options.in_loop``
    selects: each item's first ``lengths[i]`` frames."""
    options = options or FootskateOptions()

    def hook(x0: torch.Tensor, step: Step) -> torch.Tensor:
        if not options.in_loop(step.index, step.count):
            return x0
        feats = c.denormalise(x0)
        clean = feats.clone()
        for i, n in enumerate(lengths):
            f, _ = cleanup_features(feats[i, :n].detach().cpu().double().numpy(), options.config,
                                    vgrf_model=options.vgrf_model, fps=c.fps, rigid=c.rigid)
            clean[i, :n] = torch.from_numpy(f).to(clean.device, clean.dtype)
        return ((clean - c.mean) / c.std).to(x0.device, x0.dtype)

    return hook
