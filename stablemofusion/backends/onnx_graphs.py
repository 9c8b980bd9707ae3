"""The portable graphs of a model (``smf export --onnx``; :mod:`stablemofusion.backends.onnx_export` says what each
takes and gives) loaded into ONNX Runtime, with the tokenizer: no torch.

:class:`PortableModel` is one model (the student, or its teacher): its text side and one denoising step as
numpy functions, its sampler tables and settings. :class:`PortableGraphs` is the folder: the text encoder, the
length and out-of-domain models and the known actions, shared by the model and its teacher.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from ..core.folders import MANIFEST, TEACHER_INSTALL  # noqa: F401  (public here too)
from ..core.errors import SMFError

FORMAT, VERSION = "stablemofusion-onnx", 1
TABLE_FIELDS = ("t", "c_in", "a", "b", "c", "d", "level_x0", "level_eps")
MAX_MANIFEST_BYTES = 4 * 2**20


def _session(path: Path, threads: int | None):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    return ort.InferenceSession(str(path), sess_options=opts, providers=["CPUExecutionProvider"])


@dataclass(frozen=True)
class Table:
    """A sampler's per-step coefficients (K,) (float32, as the torch engines hold them): see
    :mod:`stablemofusion.diffusion.solvers`."""

    t: np.ndarray
    c_in: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    level_x0: np.ndarray
    level_eps: np.ndarray
    init_sigma: float
    stochastic: bool

    @property
    def steps(self) -> int:
        return len(self.t)


class PortableModel:
    """One model's graphs: :meth:`condition` (text side) and :meth:`denoise` (one step), its tables and
    settings (the manifest's entry: fps, lengths, guidance, sampler, steps, ...)."""

    def __init__(self, folder: Path, entry: dict, threads: int | None = None):
        self.folder, self.entry, self.threads = folder, entry, threads
        files = entry["files"]
        self.mean = np.load(folder / files["mean"]).astype(np.float32)
        self.std = np.load(folder / files["std"]).astype(np.float32)
        self.student = bool(entry["student"])
        self.fps, self.min_frames, self.max_frames = float(entry["fps"]), int(entry["min_frames"]), int(entry["max_frames"])
        self.pad_multiple, self.dim = int(entry["pad_multiple"]), int(entry["motion_dim"])
        self.guidance, self.sampler, self.steps = float(entry["guidance"]), entry["sampler"], int(entry["steps"])
        self.max_steps = int(entry["max_steps"])
        self._tables: dict[tuple[str, int], Table] = {}

    @cached_property
    def _condition(self):
        return _session(self.folder / self.entry["files"]["condition"], self.threads)

    @cached_property
    def _denoise(self):
        return _session(self.folder / self.entry["files"]["denoise"], self.threads)

    @cached_property
    def _solver_arrays(self):
        with np.load(self.folder / self.entry["files"]["solvers"]) as z:
            return {k: z[k] for k in z.files}

    @property
    def samplers(self) -> list[str]:
        return list(self.entry["solvers"])

    def table(self, sampler: str, steps: int) -> Table:
        """The coefficient table of ``sampler`` at ``steps`` steps (SMFError for one the model lacks)."""
        key = (sampler, int(steps))
        if key not in self._tables:
            meta = self.entry["solvers"].get(sampler, {}).get(str(int(steps)))
            if meta is None:
                known = ", ".join(self.samplers)
                raise SMFError(f"this model samples with {known} at 1 to {self.max_steps} steps, not {sampler!r} at "
                               f"{steps}")
            arrays = {f: self._solver_arrays[f"{sampler}/{int(steps)}/{f}"].astype(np.float32) for f in TABLE_FIELDS}
            self._tables[key] = Table(**arrays, init_sigma=float(meta["init_sigma"]),
                                      stochastic=bool(meta["stochastic"]))
        return self._tables[key]

    def condition(self, tokens: np.ndarray, mask: np.ndarray, *, guidance: float | None = None,
                  drop: bool = False) -> dict[str, np.ndarray]:
        """The text condition of frozen ``tokens`` (B, L, C), ``mask`` (B, L) bool: a student's at ``guidance``,
        a teacher's with the text kept or (``drop``) dropped. Returns the denoise graph's text inputs."""
        B = len(tokens)
        if self.student:
            control = {"guidance": np.full(B, self.guidance if guidance is None else guidance, np.float32)}
        else:
            control = {"drop": np.full(B, bool(drop))}
        out = self._condition.run(None, {"tokens": tokens.astype(np.float32), "mask": mask, **control})
        cond = {"features": out[0], "text_mask": mask, "keep": np.full(B, not drop)}
        if self.entry.get("sentence", True):
            cond["sentence"] = out[1]
        return cond

    def denoise(self, x: np.ndarray, t: np.ndarray, cond: dict[str, np.ndarray], motion_mask: np.ndarray) -> np.ndarray:
        """x0 (B, T, D) of one step: ``x`` (B, T, D) normalised model input, ``t`` (B,) timesteps; T is padded to
        the model's ``pad_multiple`` here (the model is masked: padding changes nothing)."""
        B, T, D = x.shape
        pad = (-T) % self.pad_multiple
        if pad:
            x = np.concatenate([x, np.zeros((B, pad, D), x.dtype)], 1)
            motion_mask = np.concatenate([motion_mask, np.zeros((B, pad), bool)], 1)
        (x0,) = self._denoise.run(None, {"x": x.astype(np.float32), "t": np.asarray(t, np.float32), **cond,
                                         "motion_mask": motion_mask})
        return x0[:, :T]


class PortableGraphs:
    """A folder of portable graphs (``graphs.json``): the model, its teacher, the text encoder and tokenizer, the
    length and out-of-domain models, the known actions."""

    def __init__(self, folder: str | Path, threads: int | None = None):
        self.folder, self.threads = Path(folder), threads
        path = self.folder / MANIFEST
        if not path.is_file():
            raise SMFError(f"{self.folder} holds no portable graphs ({MANIFEST}); make them with `smf export --onnx`")
        if path.stat().st_size > MAX_MANIFEST_BYTES:
            raise SMFError(f"{path} is too large to be a manifest")
        try:
            m = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise SMFError(f"{path}: not a graphs manifest ({e})") from None
        if m.get("format") != FORMAT or m.get("version") != VERSION:
            raise SMFError(f"{path}: not a graphs manifest of version {VERSION} (format {m.get('format')!r}, version "
                           f"{m.get('version')!r})")
        from ..core.noise import NOISE_VERSION

        if m.get("noise_version") != NOISE_VERSION:
            raise SMFError(f"{path}: made for noise version {m.get('noise_version')}, this runtime draws version "
                           f"{NOISE_VERSION}: export the graphs again")
        self.manifest = m
        self.model = PortableModel(self.folder, m["model"], threads)
        # a teacher named by the manifest whose files are not installed (the shipped model's without its extra)
        teacher = self.folder / m["teacher"]["folder"] if "teacher" in m else None
        self.teacher_missing = teacher is not None and not (teacher / m["teacher"]["files"]["mean"]).is_file()
        self.teacher = None if teacher is None or self.teacher_missing else PortableModel(teacher, m["teacher"], threads)
        self.max_tokens = int(m["text_encoder"]["max_tokens"])

    @cached_property
    def tokenizer(self):
        from tokenizers import Tokenizer

        tok = Tokenizer.from_file(str(self.folder / self.manifest["text_encoder"]["tokenizer"]))
        tok.enable_truncation(max_length=self.max_tokens)
        tok.enable_padding(pad_id=0, pad_token="[PAD]")
        return tok

    @cached_property
    def _text(self):
        return _session(self.folder / self.manifest["text_encoder"]["file"], self.threads)

    @cached_property
    def _length(self):
        return _session(self.folder / self.manifest["length"]["file"], self.threads) if "length" in self.manifest \
            else None

    @cached_property
    def _ood(self):
        a = self.manifest.get("actions") or {}
        return _session(self.folder / a["detector"], self.threads) if "detector" in a else None

    def encode(self, texts: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Captions -> frozen tokens (B, L, C) float32 (zero on padding), mask (B, L) bool, unit sentence
        embeddings (B, C); L the longest caption's token count."""
        enc = self.tokenizer.encode_batch([str(t) for t in texts])
        ids = np.asarray([e.ids for e in enc], dtype=np.int64)
        am = np.asarray([e.attention_mask for e in enc], dtype=np.int64)
        tokens, sentence = self._text.run(None, {"input_ids": ids, "attention_mask": am})
        return tokens, am.astype(bool), sentence

    @property
    def has_length_model(self) -> bool:
        return "length" in self.manifest

    def predict_frames(self, tokens: np.ndarray, mask: np.ndarray, levels: np.ndarray | None = None) -> np.ndarray | None:
        """(B,) the length model's frames, each its distribution's quantile at ``levels`` (B,) (None: the median),
        or None for a folder without one. A graph exported before the levels gives the median."""
        if self._length is None:
            return None
        feed = {"tokens": tokens, "mask": mask}
        if "level" in {i.name for i in self._length.get_inputs()}:
            feed["level"] = np.full(len(tokens), 0.5, np.float32) if levels is None else np.asarray(levels, np.float32)
        return self._length.run(None, feed)[0]

    def known_actions(self, text_cache):
        """The model's :class:`~stablemofusion.text.known.KnownActions` (None without), its examples' embeddings
        and detector from this folder, prompts encoded through ``text_cache``."""
        from ..text.known import KnownActions

        a = self.manifest.get("actions")
        if a is None:
            return None
        known = KnownActions(a["actions"], a["threshold"], text_cache, top=int(a["top"]),
                             detector=self if self._ood is not None else None,
                             embeddings=np.load(self.folder / a["embeddings"]))
        if not a.get("taught"):
            return known
        clips = [c for captions in (a.get("taught_clips") or {}).values() for c in captions]
        return known.with_taught([a["taught"]], [clips])  # graphs of an adapted model

    def scores(self, sentence: np.ndarray) -> np.ndarray:
        """(B,) the out-of-domain detector's in-domain scores of unit sentence embeddings (B, C)."""
        return self._ood.run(None, {"sentence": np.asarray(sentence, np.float32)})[0]


__all__ = ["PortableGraphs", "PortableModel", "Table"]
