"""The ONNX backend: a model's exported graphs (``smf export --onnx``) on ONNX Runtime and numpy, no torch. Its
sampling is the torch backend's table loop on the same portable noise, so both give the same motion
(docs/runtime.md)."""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from ..core.edit_plan import x0_constraint
from ..core.errors import SMFError
from ..core.reliability import graphs_reliability
from ..core.limits import FOOTSKATE, PORTABLE_ENGINE, PORTABLE_FOOTSKATE, STUDENT_EDIT_STEPS
from ..motion.rigid import DEFAULT_FIT, RigidMotion
from ..motion.skeleton import get_skeleton
from ..core.final import finish_many
from ..core.settings import Settings
from ..text.known import domains_of
from ..text.names import GRAPHS_DIR
from .base import Known
from .onnx_graphs import TEACHER_INSTALL, PortableGraphs
from .onnx_sampling import sample


def default_graphs_path() -> Path | None:
    """The portable graphs of the model shipped inside the package, if any."""
    path = Path(str(resources.files("stablemofusion") / "assets" / "default_model" / GRAPHS_DIR))
    return path if (path / "graphs.json").is_file() else None


def graphs_folder(path: str | Path | None = None) -> Path:
    """The graphs folder ``path`` means: itself, or the ``onnx/`` folder of a model folder; None: the shipped
    model's."""
    if path is None:
        path = default_graphs_path()
        if path is None:
            raise SMFError("this install ships no portable graphs of the default model")
    path = Path(path)
    if not (path / "graphs.json").is_file() and (path / GRAPHS_DIR / "graphs.json").is_file():
        path = path / GRAPHS_DIR
    return path


class OnnxBackend:
    """The :class:`~stablemofusion.backends.base.Backend` of a model's portable graphs (``teacher``: its teacher's);
    prompts encoded once each (an LRU cache of ``text_cache_size``)."""

    name = "onnx"
    footskate_modes = PORTABLE_FOOTSKATE  # 'loop' runs inside the torch sampler
    adapters: tuple[str, ...] = ()  # an adapted model's graphs hold its adapters merged in

    def __init__(self, graphs: PortableGraphs, *, teacher: bool = False, text_cache_size: int = 1024):
        model = graphs.teacher if teacher else graphs.model
        if model is None:
            raise SMFError(f"the teacher is not installed: {TEACHER_INSTALL}" if graphs.teacher_missing
                           else "these graphs hold no teacher")
        self.graphs, self.model = graphs, model
        self.skeleton = get_skeleton(model.entry["skeleton"])
        self.fps, self.min_frames, self.max_frames, self.dim = model.fps, model.min_frames, model.max_frames, model.dim
        self.mean, self.std = np.asarray(model.mean, np.float32), np.asarray(model.std, np.float32)
        self.rigid = DEFAULT_FIT
        self.student = bool(model.student)
        self.version = graphs.manifest.get("model_version")  # the model's version (a release's name)
        self.reliability = graphs_reliability(graphs.folder)  # how well it draws each known action
        self._cache: OrderedDict[str, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._cache_size = text_cache_size

    @classmethod
    def from_pretrained(cls, path: str | Path | None = None, *, teacher: bool = False,
                        threads: int | None = None) -> "OnnxBackend":
        """The graphs folder ``path`` (or a model folder holding one in ``onnx/``); None: the shipped model's."""
        return cls(PortableGraphs(graphs_folder(path), threads), teacher=teacher)

    # ---------------------------------------------------------------- text
    @cached_property
    def known_actions(self):
        """The model's known actions and out-of-domain detector (None without)."""
        return self.graphs.known_actions(_TextCache(self))

    @property
    def has_length_model(self) -> bool:
        return self.graphs.has_length_model

    def encode(self, prompts: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Frozen tokens (B, L, C), mask (B, L), sentence embeddings (B, C), each prompt encoded once (LRU)."""
        todo = [p for p in dict.fromkeys(prompts) if p not in self._cache]
        if todo:
            tokens, mask, sentence = self.graphs.encode(todo)
            for p, t, m, s in zip(todo, tokens, mask, sentence):
                self._cache[p] = (t[:int(m.sum())], s)
        rows = []
        for p in prompts:
            self._cache.move_to_end(p)
            rows.append(self._cache[p])
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        L = max(len(r[0]) for r in rows)
        tokens = np.zeros((len(rows), L, rows[0][0].shape[-1]), np.float32)
        mask = np.zeros((len(rows), L), bool)
        for i, (t, _) in enumerate(rows):
            tokens[i, :len(t)], mask[i, :len(t)] = t, True
        return tokens, mask, np.stack([s for _, s in rows])

    def predict_seconds(self, prompts: str | list[str], levels: list[float] | None = None) -> list[float]:
        """The length each prompt's motion is expected to have (seconds), from the length model: its distribution's
        quantile at each of ``levels`` (None: the median); one text is one prompt (not one per character)."""
        prompts = [prompts] if isinstance(prompts, str) else list(prompts)
        tokens, mask, _ = self.encode(prompts)
        frames = self.graphs.predict_frames(tokens, mask, levels)
        if frames is None:
            raise SMFError("this model has no length model; give the length")
        return [int(f) / self.fps for f in np.clip(frames, self.min_frames, self.max_frames)]

    def domains(self, prompts: list[str]) -> list:
        """Each prompt's closest known action (None without known actions), warning once per out-of-domain
        prompt."""
        return domains_of(self.known_actions, prompts)

    # ---------------------------------------------------------------- sampling
    def settings(self, settings: Settings | None = None, *, edit: bool = False, hooks: bool = False) -> Settings:
        """``settings`` resolved for the graphs' model: its guidance, sampler and steps where None (a student's
        edit at least STUDENT_EDIT_STEPS), footskate 'post' or 'off', the engine 'onnx'."""
        m, s = self.model, (settings or Settings()).check()
        if s.engine not in (None, "auto", PORTABLE_ENGINE):
            raise SMFError(f"the ONNX backend runs the engine {PORTABLE_ENGINE!r}, not {s.engine!r}")
        own = max(m.steps, STUDENT_EDIT_STEPS) if edit and m.student else m.steps
        steps = own if s.steps is None else int(s.steps)
        if m.student and steps > m.max_steps:
            raise SMFError(f"steps must be at most {m.max_steps} for this model (a distilled student: more steps drift "
                           f"into motions no human makes), got {steps}")
        footskate = FOOTSKATE if s.footskate is None else s.footskate
        if footskate not in PORTABLE_FOOTSKATE:
            raise SMFError("footskate 'loop' runs inside the torch sampler; use 'post' or 'off' here")
        sampler = s.sampler or m.sampler
        m.table(sampler, steps)  # SMFError for a sampler or step count the graphs lack
        return replace(s, guidance_scale=m.guidance if s.guidance_scale is None else float(s.guidance_scale),
                       steps=steps, sampler=sampler, footskate=footskate, engine=PORTABLE_ENGINE)

    def check_continues(self, settings: Settings, what: str) -> None:
        """Every sampler of the graphs is a coefficient table: each keeps a known part."""

    def raw_features(self, prompts: list[str], lengths: list[int], settings: Settings, seed: int | list[int], *,
               known: Known | None = None, progress: bool = False) -> np.ndarray:
        """Raw features (B, max(lengths), D) float32 in dataset units (``progress`` unused: a call takes
        milliseconds)."""
        tokens, mask, _ = self.encode(prompts)
        return sample(self.model, tokens, mask, lengths, seed, guidance=settings.guidance_scale,
                      sampler=settings.sampler, steps=settings.steps, x0_hook=self._x0_hook(known))

    def _x0_hook(self, known: Known | None):
        """The numpy x0 hook imposing ``known`` on every prediction (normalised)."""
        if known is None:
            return None
        if known.impose != "x0":
            raise SMFError(f"impose {known.impose!r} runs on the torch backend (pip install 'stablemofusion[train]'); "
                           "the ONNX backend imposes on x0")
        if known.plan is not None:
            return x0_constraint(known.plan, self.mean, self.std)
        values = (known.values.astype(np.float32) - self.mean) / self.std

        def impose(x0: np.ndarray) -> np.ndarray:
            return np.where(known.mask, values, x0)

        return impose

    def finish_many(self, features: list[np.ndarray], footskate: str = "off",
                    footskate_options=None) -> list[tuple[np.ndarray, RigidMotion | None]]:
        return finish_many(features, self.skeleton, self.fps, self.rigid, footskate, footskate_options)


class _TextCache:
    """The text-cache protocol of :class:`~stablemofusion.text.known.KnownActions` over a backend's encoder."""

    def __init__(self, backend: OnnxBackend):
        self.backend = backend
        self.encoder = SimpleNamespace(name=backend.graphs.manifest["text_encoder"]["name"])

    def get_or_compute(self, texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
        tokens, mask, _ = self.backend.encode(list(texts))
        return tokens, mask


__all__ = ["OnnxBackend", "default_graphs_path", "graphs_folder"]
