"""The inference engine: the denoising loop of a precomputed solver (:mod:`.solvers`) at static shapes.

Engines, fastest last (``eager`` is the reference and works with every sampler):

- ``eager``: the diffusers scheduler loop (:func:`.sampling.run_diffusers`);
- ``fast``: the coefficient-table loop (:func:`.sampling.run_solver`) around the eager model;
- ``compiled``: the same loop around ``torch.compile`` of the model's motion part (inductor; CPU or GPU);
  one compilation per shape bucket, cached by torch across runs where it can;
- ``graph`` (CUDA only): the whole loop (every step, guidance included) around the eager model, captured as
  one CUDA graph per (sampler, steps, guidance, batch bucket, length bucket, text bucket) and replayed: the
  launches go, the warm-up is one capture (no compilation);
- ``compiled-graph`` (CUDA only): the same graph around the compiled model (fused kernels too; compiles first);
- ``aot``: the ``compiled`` loop around ``model.denoise`` exported and compiled ahead of time by AOTInductor
  (:mod:`.aot`): one package for all shapes, built once per machine and model (cache folder), then loaded in
  about 2 s by each new process instead of compiled.

Static shapes: lengths padded up to multiples of :data:`FRAME_BUCKET` (frames past an item's length are
masked; only for models whose output on valid frames does not depend on padding), batches up to the next of
:data:`BATCH_BUCKETS` (filler items, dropped after), text up to multiples of :data:`TEXT_BUCKET` tokens.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from dataclasses import dataclass, field

import torch

from ..core.errors import SMFError
from ..core.limits import ENGINES
from ..models.base import TextCondition
from .sampling import Step, guided, run_solver
from .solvers import SolverTable

GRAPH_ENGINES = ("graph", "compiled-graph")
COMPILED_ENGINES = ("compiled", "compiled-graph", "aot")  # run through SolverEngine (padded shapes)
FRAME_BUCKET = 16
TEXT_BUCKET = 16
BATCH_BUCKETS = (1, 2, 4, 8, 16, 32)
MAX_GRAPHS = 32  # captured graphs kept per engine (least recently used dropped, with their memory)
RECOMPILE_LIMIT = 256  # torch.compile's shapes per function (torch's default, 8, is far fewer than the buckets)


def default_engine(device: torch.device, sampler_fast: bool) -> str:
    """The fastest engine that works without a long warm-up: ``graph`` on CUDA (one capture per shape),
    ``fast`` on CPU (compiling costs tens of seconds per shape, so ``compiled`` and ``compiled-graph`` are
    opt-in, for servers), ``eager`` for samplers without a precomputed form."""
    if not sampler_fast:
        return "eager"
    return "graph" if device.type == "cuda" else "fast"


def check_engine(name: str, device: torch.device) -> None:
    if name not in ENGINES and name != "auto":
        raise SMFError(f"engine must be auto or one of {', '.join(ENGINES)}, got {name!r}")
    if name in GRAPH_ENGINES and device.type != "cuda":
        raise SMFError(f"engine {name!r} needs a CUDA device (CUDA graphs); use 'fast' or 'compiled' on the CPU")


def bucket(n: int, step: int) -> int:
    """``n`` rounded up to a multiple of ``step``."""
    return -(-n // step) * step


def batch_bucket(n: int) -> int:
    """The smallest batch bucket holding ``n`` items (``n`` itself past the largest)."""
    return next((b for b in BATCH_BUCKETS if b >= n), n)


@dataclass
class EngineStats:
    """Warm-up cost of the engine's caches: seconds spent compiling or capturing, per shape key."""

    warmup_seconds: dict[tuple, float] = field(default_factory=dict)

    @property
    def total(self) -> float:
        return sum(self.warmup_seconds.values())


class SolverEngine:
    """Runs the coefficient-table loop for one model with the ``fast``, ``compiled`` or ``graph`` engine.

    :meth:`run` takes the text condition of B prompts (and of the dropped text), the initial noise and the
    step noise; pads to the shape buckets (compiled and graph engines), runs, and returns x (B, T, D)."""

    def __init__(self, model, engine: str):
        self.model, self.engine = model, engine
        self.stats = EngineStats()
        self._compiled = None
        self._graphs: OrderedDict[tuple, _Captured] = OrderedDict()

    def _denoise_fn(self):
        if self.engine not in COMPILED_ENGINES:
            return self.model
        if self._compiled is None:
            if self.engine == "aot":
                from .aot import AOTDenoise

                self._compiled = AOTDenoise(self.model)
                how = "built" if self._compiled.built else "loaded"
                self.stats.warmup_seconds[("aot", how)] = self._compiled.seconds
            else:
                self._compiled = _CompiledDenoise(self.model)
        return self._compiled

    def run(self, cond: TextCondition, uncond: TextCondition | None, motion_mask: torch.Tensor, scale: float,
            table: SolverTable, x: torch.Tensor, step_noise: torch.Tensor | None) -> torch.Tensor:
        B, T, _ = x.shape
        if self.engine == "fast":
            return run_solver(guided(self.model, cond, uncond, motion_mask, scale), table, x, step_noise)
        Tb = self.model.frame_bucket(T, FRAME_BUCKET)
        if self.engine == "aot":
            Tb = max(bucket(T, FRAME_BUCKET), 2 * FRAME_BUCKET)  # the package's frame dim: 16 * k, k >= 2
        Bb = B if self.engine == "aot" else batch_bucket(B)  # the package's batch dim is dynamic
        Lb = bucket(cond.features.shape[1], TEXT_BUCKET)
        cond_p, uncond_p = _pad_cond(cond, Bb, Lb), None if uncond is None else _pad_cond(uncond, Bb, Lb)
        mask_p = _pad_items(_pad(motion_mask, 1, Tb, False), Bb)
        x_p = _pad(_pad(x, 1, Tb, 0.0), 0, Bb, 0.0)
        n_p = None if step_noise is None else _pad(_pad(step_noise, 2, Tb, 0.0), 1, Bb, 0.0)
        key = (table.name, table.steps, uncond is None, Bb, Tb, Lb, x.dtype)  # the guidance scale is an input
        if self.engine in ("compiled", "aot"):
            t0 = time.perf_counter()
            out = run_solver(guided(self._denoise_fn(), cond_p, uncond_p, mask_p, scale), table, x_p, n_p)
            if self.engine == "compiled" and key not in self.stats.warmup_seconds:  # first call: compilation
                self.stats.warmup_seconds[key] = time.perf_counter() - t0
            return out[:B, :T]
        graph = self._graphs.get(key)
        if graph is None:
            if len(self._graphs) >= MAX_GRAPHS:
                self._graphs.popitem(last=False)
            t0 = time.perf_counter()
            graph = self._graphs[key] = _Captured(self._denoise_fn(), cond_p, uncond_p, mask_p, scale, table, x_p, n_p)
            self.stats.warmup_seconds[key] = time.perf_counter() - t0
        self._graphs.move_to_end(key)
        return graph.replay(cond_p, uncond_p, mask_p, scale, x_p, n_p)[:B, :T]


class _CompiledDenoise:
    """``model.denoise`` compiled with inductor (static shapes), callable like the model's ``denoise``."""

    def __init__(self, model):
        import torch._dynamo

        self.model = model
        for name in ("recompile_limit", "cache_size_limit"):  # the option's name changed across torch versions
            if hasattr(torch._dynamo.config, name):
                setattr(torch._dynamo.config, name, max(getattr(torch._dynamo.config, name), RECOMPILE_LIMIT))
        self.fn = torch.compile(model.denoise, dynamic=False)

    def denoise(self, *args):
        return self.fn(*args)


class _Captured:
    """One CUDA graph of the whole solver loop over static input buffers (the guidance scale among them)."""

    def __init__(self, model, cond, uncond, mask, scale, table, x, noise):
        self.cond, self.uncond = _clone_cond(cond), None if uncond is None else _clone_cond(uncond)
        self.mask, self.x = mask.clone(), x.clone()
        self.noise = None if noise is None else noise.clone()
        self.scale = torch.tensor(float(scale), device=x.device, dtype=x.dtype)
        self.table = table  # the graph reads its coefficient tensors: keep them alive
        fn = (lambda: run_solver(guided(model, self.cond, self.uncond, self.mask, self.scale), table, self.x,
                                 self.noise))
        stream = torch.cuda.Stream()
        stream.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(stream):  # warm-up (lazy inits, compilation) outside the capture
            for _ in range(2):
                fn()
        torch.cuda.current_stream().wait_stream(stream)
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph):
            self.out = fn()

    def replay(self, cond, uncond, mask, scale, x, noise) -> torch.Tensor:
        _copy_cond(self.cond, cond)
        self.scale.fill_(float(scale))
        if uncond is not None:
            _copy_cond(self.uncond, uncond)
        self.mask.copy_(mask)
        self.x.copy_(x)
        if noise is not None:
            self.noise.copy_(noise)
        self.graph.replay()
        return self.out.clone()


def _fields(c: TextCondition) -> tuple:
    return c.features, c.mask, c.keep, c.sentence


def _clone_cond(c: TextCondition) -> TextCondition:
    return TextCondition(*(None if v is None else v.clone() for v in _fields(c)))


def _copy_cond(dst: TextCondition, src: TextCondition) -> None:
    for d, s in zip(_fields(dst), _fields(src)):
        if d is not None:
            d.copy_(s)


def _pad(v: torch.Tensor, dim: int, size: int, fill: float | bool) -> torch.Tensor:
    """``v`` padded with ``fill`` along ``dim`` up to ``size`` entries."""
    n = v.shape[dim]
    if n >= size:
        return v
    shape = list(v.shape)
    shape[dim] = size - n
    return torch.cat([v, torch.full(shape, fill, dtype=v.dtype, device=v.device)], dim)


def _pad_items(v: torch.Tensor | None, size: int) -> torch.Tensor | None:
    """``v`` padded along dim 0 up to ``size`` items with copies of its first (filler items)."""
    if v is None or v.shape[0] >= size:
        return v
    return torch.cat([v, v[:1].expand(size - v.shape[0], *v.shape[1:])])


def _pad_cond(c: TextCondition, B: int, L: int) -> TextCondition:
    """A text condition padded to B items (copies of the first) and L tokens (masked zeros)."""
    feats, mask = _pad(c.features, 1, L, 0.0), _pad(c.mask, 1, L, False)
    return TextCondition(*(_pad_items(v, B) for v in (feats, mask, c.keep, c.sentence)))


__all__ = ["ENGINES", "SolverEngine", "default_engine", "check_engine", "Step"]
