"""Out-of-domain check: how close a prompt is to the actions a model was trained on.

A model folder may hold ``actions.json``: ``{"threshold": float, "actions": {label: [example sentences]}}``
(written by ``smf export --lexicon NAME`` from the corpus lexicon). A prompt's similarity to an action is
the largest cosine similarity between its sentence embedding (the frozen encoder's mean-pooled, normalised
token states, :func:`~stablemofusion.text.frozen.sentence_embedding`) and those of the action's examples.
Below ``threshold`` the prompt is out of domain: the pipeline still generates, and warns naming the closest
actions it knows.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import torch

from ..errors import SMFError
from .frozen import sentence_embedding

ACTIONS_FILE = "actions.json"


@dataclass(frozen=True)
class DomainCheck:
    """``similarity`` to the closest known action, the ``closest`` (label, similarity) pairs, best first."""

    similarity: float
    closest: tuple[tuple[str, float], ...]
    out_of_domain: bool

    def to_dict(self, prompt: str) -> dict:
        """JSON fields for a result: similarity, closest actions, and a one-line warning when out of domain."""
        out = {"similarity": round(self.similarity, 4), "out_of_domain": self.out_of_domain,
               "closest_actions": [[label, round(sim, 4)] for label, sim in self.closest]}
        if self.out_of_domain:
            out["warning"] = self.message(prompt)
        return out

    def message(self, prompt: str) -> str:
        names = ", ".join(f"{label} ({sim:.2f})" for label, sim in self.closest)
        return (f"{prompt!r} is not like anything this model was trained on (similarity {self.similarity:.2f}); "
                f"closest actions it knows: {names}")


class KnownActions:
    """The actions of a model and their example sentences, embedded once through ``text_cache``."""

    def __init__(self, actions: dict[str, list[str]], threshold: float, text_cache, top: int = 3):
        if not actions or any(not v for v in actions.values()):
            raise SMFError("actions.json: every action needs at least one example sentence")
        self.actions, self.threshold, self.text_cache, self.top = actions, float(threshold), text_cache, top
        self._emb: torch.Tensor | None = None
        self._owner = torch.tensor([i for i, examples in enumerate(actions.values()) for _ in examples])

    @classmethod
    def load(cls, path: str | Path, text_cache) -> "KnownActions":
        path = Path(path)
        try:
            d = json.loads(path.read_text(encoding="utf-8"))
            return cls({k: list(v) for k, v in d["actions"].items()}, float(d["threshold"]), text_cache)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as e:
            raise SMFError(f"{path}: not an actions file ({e})") from None

    def embed(self, texts: list[str]) -> torch.Tensor:
        out = []
        for a in range(0, len(texts), 64):
            tokens, mask = self.text_cache.get_or_compute(texts[a:a + 64])
            out.append(sentence_embedding(tokens.float().cpu(), mask.cpu()))
        return torch.cat(out)

    def similarities(self, prompts: list[str]) -> torch.Tensor:
        """(B, A) largest cosine similarity of each prompt to each action's examples."""
        if self._emb is None:
            self._emb = self.embed([e for examples in self.actions.values() for e in examples])
        sims = self.embed(list(prompts)) @ self._emb.T  # (B, E)
        best = torch.full((len(prompts), len(self.actions)), -1.0)
        return best.scatter_reduce(1, self._owner.expand(len(prompts), -1), sims, reduce="amax")

    def check_many(self, prompts: list[str]) -> list[DomainCheck]:
        sims = self.similarities(prompts)
        labels = list(self.actions)
        out = []
        for row in sims:
            order = torch.argsort(row, descending=True)[: self.top]
            closest = tuple((labels[int(i)], float(row[i])) for i in order)
            out.append(DomainCheck(closest[0][1], closest, closest[0][1] < self.threshold))
        return out

    def check(self, prompt: str) -> DomainCheck:
        return self.check_many([prompt])[0]


__all__ = ["ACTIONS_FILE", "DomainCheck", "KnownActions"]
