"""Out-of-domain check: how close a prompt is to the actions a model was trained on.

A model folder may hold ``actions.json``: ``{"threshold": float, "actions": {label: [example sentences]},
"detector": {"file": "ood.safetensors"}}`` (written by ``smf export --lexicon NAME``), and beside it
``actions.safetensors``: the example sentences' embeddings, so that a process's first check does not encode
every example (used only when its sentences and text encoder match); a model folder with portable graphs
(``onnx/``, the shipped model) keeps them once, in the graphs' ``actions.npy``, read when the graphs name the same
actions and text encoder. A prompt's similarity
to an action is the largest cosine similarity between its sentence embedding (the frozen encoder's
mean-pooled, normalised token states, :func:`~stablemofusion.text.frozen.sentence_embedding`) and those of
the action's examples: the ``closest`` actions. The check's ``similarity`` is the detector's calibrated
in-domain score (:mod:`.domain`: a classifier on the sentence embedding, trained on every training caption
against foreign captions); an older file without ``detector`` uses the closest action's similarity. Below
``threshold`` the prompt is out of domain: the pipeline still generates, and warns naming the closest actions
it knows.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import SMFError
from ..motion.arrays import to_numpy
from ..core.final import OutOfDomainWarning
from ..core.folders import MANIFEST
from .names import ACTIONS_FILE, DETECTOR_FILE, EMBEDDINGS_FILE, GRAPHS_DIR
from .sentence import sentence_embedding
MAX_EMBEDDINGS_BYTES = 64 * 2**20  # a larger embeddings file is not read (the examples are encoded instead)
# a prompt this similar (cosine of sentence embeddings) to a caption an adapter was taught is in domain
# (benchmarks/adapt_check.py measures it on held-out prompts of the taught action and on foreign ones)
TAUGHT_SIMILARITY = 0.6
# a prompt whose closest action is one an adapter taught, by this much (cosine) over the next closest action, is
# answered with the nearest of the captions of that action's own clips: an adapter draws its move surely for them, and
# seldom for other words (chosen on the development prompts of benchmarks/adapt: docs/adapters.md)
TAUGHT_MARGIN = 0.1


@dataclass(frozen=True)
class DomainCheck:
    """``similarity``: the in-domain score (the detector's, or the closest action's cosine similarity for an
    actions file without a detector); ``closest``: the (label, cosine similarity) of the closest actions, best
    first; ``answer``: the caption of an adapter's clip the prompt is answered with (``TAUGHT_MARGIN``), else None."""

    similarity: float
    closest: tuple[tuple[str, float], ...]
    out_of_domain: bool
    answer: str | None = None

    def to_dict(self, prompt: str) -> dict:
        """JSON fields for a result: similarity, closest actions, and a one-line warning when out of domain."""
        out = {"similarity": round(self.similarity, 4), "out_of_domain": self.out_of_domain,
               "closest_actions": [[label, round(sim, 4)] for label, sim in self.closest]}
        if self.out_of_domain:
            out["warning"] = self.message(prompt)
        if self.answer is not None:
            out["answered_as"] = self.answer
        return out

    def answer_message(self, prompt: str) -> str:
        """One warning line: the prompt is answered with a taught caption."""
        return (f"{prompt!r} is answered as {self.answer!r}: its closest action, {self.closest[0][0]}, is one an "
                f"adapter taught, and an adapter draws its move surely only for its clips' captions")

    def message(self, prompt: str) -> str:
        """One warning line with one figure, the in-domain score the decision used (the closest actions by
        name only: their cosine similarities are another measure)."""
        names = ", ".join(label for label, _ in self.closest)
        return (f"{prompt!r} is not like anything this model was trained on (in-domain score "
                f"{self.similarity:.2f}); closest actions it knows: {names}")


class KnownActions:
    """The actions of a model and their example sentences, embedded once through ``text_cache`` (anything with
    ``get_or_compute(texts) -> (tokens (B, L, C), mask (B, L))``, torch or numpy, and ``encoder.name``).
    ``detector``: anything with ``scores(embeddings (B, C) numpy) -> (B,) numpy`` (a
    :class:`~stablemofusion.text.domain.DomainDetector`, or the portable runtime's graph). numpy throughout."""

    def __init__(self, actions: dict[str, list[str]], threshold: float, text_cache, top: int = 3,
                 detector=None, embeddings: np.ndarray | None = None):
        if not actions or any(not v for v in actions.values()):
            raise SMFError("actions.json: every action needs at least one example sentence")
        self.actions, self.threshold, self.text_cache, self.top = actions, float(threshold), text_cache, top
        self.detector = detector
        self._emb: np.ndarray | None = None if embeddings is None else np.asarray(embeddings, np.float32)
        self._owner = np.asarray([i for i, examples in enumerate(actions.values()) for _ in examples])
        self.taught: dict[str, list[str]] = {}  # actions adapters added: label -> their captions
        self.taught_clips: dict[str, list[str]] = {}  # label -> the captions of its clips alone (no paraphrases)
        self._taught_emb: np.ndarray | None = None

    def with_taught(self, taught: list[dict[str, list[str]]],
                    clips: list[list[str]] | None = None) -> "KnownActions":
        """A copy that also knows adapters' actions (each a dict label -> captions): a prompt at least
        TAUGHT_SIMILARITY similar (cosine) to one of their captions is in domain, and they count among the
        closest actions. ``clips``: each adapter's clip captions (its captions less the paraphrases), what a prompt
        clearly closest to its action is answered with (``DomainCheck.answer``)."""
        import copy

        new = copy.copy(self)
        new.taught = {k: list(v) for k, v in self.taught.items()}
        new.taught_clips = {k: list(v) for k, v in self.taught_clips.items()}
        for k, actions in enumerate(taught):
            own = set(clips[k]) if clips is not None else set()
            for label, captions in actions.items():
                if not captions:
                    raise SMFError(f"adapter action {label!r} has no captions")
                new.taught.setdefault(label, []).extend(captions)
                mine = [c for c in dict.fromkeys(captions) if c in own]
                if mine:
                    new.taught_clips.setdefault(label, []).extend(c for c in mine
                                                                  if c not in new.taught_clips.get(label, []))
        new._taught_emb = None
        return new

    @classmethod
    def load(cls, path: str | Path, text_cache, load_detector=None) -> "KnownActions":
        """The known actions of an actions file, their embeddings from beside it; ``load_detector(file)`` loads the
        out-of-domain detector the file names (the torch backend's :meth:`~stablemofusion.text.domain.
        DomainDetector.load`; None: no detector)."""
        path = Path(path)
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
            actions, threshold = {k: list(v) for k, v in d["actions"].items()}, float(d["threshold"])
            detector_file = d["detector"]["file"] if d.get("detector") is not None else None
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as e:
            raise SMFError(f"{path}: not an actions file ({e})") from None
        detector = None
        if detector_file is not None:
            if Path(detector_file).name != detector_file:
                raise SMFError(f"{path}: the detector must be a file beside it, not {detector_file!r}")
            if load_detector is not None:
                detector = load_detector(path.parent / detector_file)
        known = cls(actions, threshold, text_cache, detector=detector)
        known._emb = known._stored_embeddings(path.parent / EMBEDDINGS_FILE)
        if known._emb is None:
            known._emb = known._graph_embeddings(path.parent / GRAPHS_DIR)
        return known

    def _graph_embeddings(self, folder: Path) -> np.ndarray | None:
        """The examples' embeddings kept in a model's portable graphs (``actions.npy`` beside ``graphs.json``),
        when the graphs know exactly these actions (none taught) with this text encoder; else None."""
        encoder = getattr(getattr(self.text_cache, "encoder", None), "name", "")
        try:
            manifest = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
            actions, name = manifest["actions"], manifest["text_encoder"]["name"]
            if actions.get("taught") or actions["actions"] != self.actions or name != encoder:
                return None
            path = folder / actions["embeddings"]
            if Path(actions["embeddings"]).name != actions["embeddings"] or path.stat().st_size > MAX_EMBEDDINGS_BYTES:
                return None
            emb = np.load(path, allow_pickle=False).astype(np.float32)
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None
        return emb if emb.ndim == 2 and len(emb) == len(self._owner) else None

    def _fingerprint(self) -> str:
        """sha256 of the example sentences in order, and the text encoder's name when the cache has one."""
        encoder = getattr(getattr(self.text_cache, "encoder", None), "name", "")
        return hashlib.sha256(json.dumps([encoder, self.actions]).encode()).hexdigest()

    def _stored_embeddings(self, path: Path) -> np.ndarray | None:
        """The examples' embeddings saved beside actions.json, or None when absent, unreadable or stale."""
        from safetensors import SafetensorError, safe_open

        if not path.is_file() or path.stat().st_size > MAX_EMBEDDINGS_BYTES:
            return None
        try:
            with safe_open(str(path), framework="numpy") as f:
                if (f.metadata() or {}).get("fingerprint") != self._fingerprint():
                    return None
                emb = f.get_tensor("embeddings").astype(np.float32)
        except (OSError, SafetensorError, KeyError, RuntimeError, ValueError):
            return None
        return emb if emb.ndim == 2 and len(emb) == len(self._owner) else None

    def save(self, folder: str | Path, about: str = "") -> Path:
        """Write ``actions.json`` (and the detector's file beside it) into ``folder``; returns the json path."""
        from ..core.io import write_text

        folder = Path(folder)
        d = {"about": about, "threshold": self.threshold, "actions": self.actions}
        if self.detector is not None:
            self.detector.save(folder / DETECTOR_FILE)
            d["detector"] = {"file": DETECTOR_FILE}
        if self._emb is not None or self.text_cache is not None:  # without an encoder, the next load encodes them
            self.save_embeddings(folder)
        write_text(folder / ACTIONS_FILE, json.dumps(d, indent=1) + "\n")
        return folder / ACTIONS_FILE

    def save_embeddings(self, folder: str | Path) -> Path:
        """Write the examples' embeddings (float32, with the fingerprint of sentences and encoder) into
        ``folder/actions.safetensors``."""
        from safetensors.numpy import save_file

        from ..core.io import atomic_path

        path = Path(folder) / EMBEDDINGS_FILE
        with atomic_path(path) as tmp:
            save_file({"embeddings": np.ascontiguousarray(self.examples_embedding(), dtype=np.float32)}, str(tmp),
                      metadata={"fingerprint": self._fingerprint()})
            tmp.chmod(0o644)
        return path

    def examples_embedding(self) -> np.ndarray:
        """(E, dim) unit embeddings of every example sentence, in ``actions`` order (encoded once)."""
        if self._emb is None:
            self._emb = self.embed([e for examples in self.actions.values() for e in examples])
        return self._emb

    def embed(self, texts: list[str]) -> np.ndarray:
        """(N, C) float32 unit sentence embeddings of ``texts`` (the text cache's tokens, 64 at a time)."""
        out = []
        for a in range(0, len(texts), 64):
            tokens, mask = self.text_cache.get_or_compute(texts[a:a + 64])
            out.append(sentence_embedding(np.asarray(to_numpy(tokens), np.float32), np.asarray(to_numpy(mask), bool)))
        return np.concatenate(out)

    def similarities(self, prompts: list[str]) -> np.ndarray:
        """(B, A) largest cosine similarity of each prompt to each action's examples."""
        return self._similarities(self.embed(list(prompts)))

    def _similarities(self, emb: np.ndarray) -> np.ndarray:
        return _best_per_owner(emb @ self.examples_embedding().T, self._owner, len(self.actions))

    def taught_similarities(self, emb: np.ndarray) -> np.ndarray:
        """(B, A') largest cosine similarity of sentence embeddings ``emb`` to each taught action's captions."""
        if self._taught_emb is None:
            self._taught_emb = self.embed([c for caps in self.taught.values() for c in caps])
        owner = np.asarray([i for i, caps in enumerate(self.taught.values()) for _ in caps])
        return _best_per_owner(emb @ self._taught_emb.T, owner, len(self.taught))

    def check_many(self, prompts: list[str]) -> list[DomainCheck]:
        self.examples_embedding()  # the examples first (when not stored): their encoding batches stay as they were
        emb = self.embed(list(prompts))
        sims = self._similarities(emb)
        scores = None if self.detector is None else self.detector.scores(emb)
        labels = list(self.actions)
        if self.taught:  # an adapter's actions: known when a prompt is close to one of their captions
            sims = np.concatenate([sims, self.taught_similarities(emb)], axis=1)
            labels += list(self.taught)
        out = []
        for b, row in enumerate(sims):
            order = np.argsort(-row, kind="stable")[: self.top]
            closest = tuple((labels[int(i)], float(row[i])) for i in order)
            score = closest[0][1] if scores is None else float(scores[b])
            out_of_domain = score < self.threshold
            if out_of_domain and self.taught and float(row[len(self.actions):].max()) >= TAUGHT_SIMILARITY:
                out_of_domain = False  # the score stays the base model's: the adapter's caption decided
            answer = self._answer(emb[b], closest)
            out.append(DomainCheck(score, closest, out_of_domain, None if answer == prompts[b] else answer))
        return out

    def _answer(self, emb: np.ndarray, closest: tuple[tuple[str, float], ...]) -> str | None:
        """The nearest clip caption of the taught action ``closest`` names first, where it leads the next closest
        action by ``TAUGHT_MARGIN``; else None."""
        label = closest[0][0] if closest else None
        if label not in self.taught_clips or (len(closest) > 1 and closest[0][1] - closest[1][1] < TAUGHT_MARGIN):
            return None
        # the clip captions' rows among the taught captions' embeddings (taught_similarities made them)
        labels = list(self.taught)
        start = sum(len(self.taught[name]) for name in labels[:labels.index(label)])
        rows = [start + self.taught[label].index(c) for c in self.taught_clips[label]]
        return self.taught_clips[label][int(np.argmax(self._taught_emb[rows] @ emb))]

    def check(self, prompt: str) -> DomainCheck:
        return self.check_many([prompt])[0]


def _best_per_owner(sims: np.ndarray, owner: np.ndarray, count: int) -> np.ndarray:
    """(B, count) the largest of ``sims`` (B, E) over the columns of each owner (E,) (-1 for an owner of none)."""
    best = np.full((len(sims), count), -1.0, dtype=sims.dtype)
    for k in range(count):
        cols = sims[:, owner == k]
        if cols.shape[1]:
            best[:, k] = np.maximum(best[:, k], cols.max(1))
    return best


__all__ = ["ACTIONS_FILE", "EMBEDDINGS_FILE", "DomainCheck", "KnownActions"]


def domains_of(known: "KnownActions | None", prompts: list[str]) -> list:
    """Each prompt's closest known action (None for a model without known actions), warning once per out-of-domain
    prompt (:class:`~stablemofusion.core.final.OutOfDomainWarning`); what every backend's ``domains`` is."""
    if known is None:
        return [None] * len(prompts)
    checks = list(known.check_many(prompts))
    for p, d in dict(zip(prompts, checks)).items():
        if d.out_of_domain:
            warnings.warn(d.message(p), OutOfDomainWarning, stacklevel=4)
    return checks
