"""Corpus lexicons: the words that describe each content and style label, read from a data file.

A lexicon (``assets/lexicons/<corpus>.json``) holds, per content label, verb-phrase phrasings with marked
verbs (``<walk> forward``, ``<swing|swings|swinging> {pos} arm``) and, per style label, adjectives,
adverbs, manner phrases and personas; each list is split into ``train`` (used for training captions) and
``heldout`` (never used in training: a probe of generalisation to unseen words); a content may add ``examples``:
phrasings the known-action check matches prompts against (:func:`known_actions`) that training never uses (a raised
fist is a raise, not a punch, though "fist" is a punching word). ``same_as`` shares one
entry between synonymous labels of two datasets (``elderly`` -> ``old``); left/right contents are written
once (``-left``) and mirrored. The label tables (which dataset has which labels) are in the same file, and
``tempo_free``: the contents whose meaning does not lie in their speed (a slowed wave is a wave; a slowed run is
a jog), which `smf train --time-warp-contents tempo-free` may slow down.
"""

from __future__ import annotations

import functools
import json
import re
from dataclasses import dataclass, replace
from importlib import resources
from pathlib import Path

from ..core.errors import SMFError

STYLE_KINDS = ("adjectives", "adverbs", "manners", "personas")
_MIRROR_RE_TEMPLATE = r"(?<![A-Za-z])({words})(?![A-Za-z])"


@dataclass(frozen=True)
class Words:
    """One list of a lexicon, split into the part training may use and the held-out part; ``examples``: more
    phrasings of a content for the known-action check alone (never training captions)."""

    train: tuple[str, ...]
    heldout: tuple[str, ...] = ()
    examples: tuple[str, ...] = ()

    def pick(self, heldout: bool) -> tuple[str, ...]:
        return self.heldout if heldout else self.train


@dataclass(frozen=True)
class StyleWords:
    label: str
    adjectives: Words
    adverbs: Words
    manners: Words
    personas: Words

    def kind(self, name: str) -> Words:
        return getattr(self, name)


@dataclass(frozen=True)
class Lexicon:
    """The words of one corpus; see the module docstring."""

    name: str
    contents: dict[str, Words]
    styles: dict[str, StyleWords]
    datasets: dict[int, tuple[tuple[str, ...], tuple[str, ...]]]  # dataset -> (contents, styles)
    mirror: dict[str, str]
    heldout_words: frozenset[str]
    tempo_free: frozenset[str] = frozenset()  # contents whose meaning is not in their speed (mirrors included)

    def content(self, label: str) -> Words:
        try:
            return self.contents[label]
        except KeyError:
            raise SMFError(f"unknown content label {label!r}; known contents: {', '.join(self.contents)}") from None

    def style(self, label: str) -> StyleWords:
        try:
            return self.styles[label]
        except KeyError:
            raise SMFError(f"unknown style label {label!r}; known styles: {', '.join(self.styles)}") from None

    def content_datasets(self, label: str) -> tuple[int, ...]:
        return tuple(d for d, (c, _) in self.datasets.items() if label in c)

    def style_datasets(self, label: str) -> tuple[int, ...]:
        return tuple(d for d, (_, s) in self.datasets.items() if label in s)

    @functools.cached_property
    def _mirror_re(self) -> re.Pattern[str]:
        words = sorted(self.mirror, key=len, reverse=True)
        return re.compile(_MIRROR_RE_TEMPLATE.format(words="|".join(map(re.escape, words))), re.IGNORECASE)

    def mirror_text(self, text: str) -> str:
        """Swap the lexicon's mirror words (left <-> right ...), keeping capitalisation."""

        def swap(m: re.Match[str]) -> str:
            word = m.group(0)
            out = self.mirror[word.lower()]
            if len(word) > 1 and word.isupper():
                return out.upper()
            return out[:1].upper() + out[1:] if word[:1].isupper() else out

        return self._mirror_re.sub(swap, text)


def _words(d: dict | list | None, where: str) -> Words:
    if d is None:
        return Words(())
    if isinstance(d, list):
        return Words(tuple(d))
    if not isinstance(d, dict) or not set(d) <= {"train", "heldout", "examples"}:
        raise SMFError(f"lexicon: {where} must be a list or {{'train': [...], 'heldout': [...], 'examples': [...]}}")
    return Words(tuple(d.get("train", ())), tuple(d.get("heldout", ())), tuple(d.get("examples", ())))


def _resolve(table: dict, label: str, where: str) -> dict:
    seen = []
    entry = table[label]
    while isinstance(entry, dict) and "same_as" in entry:
        seen.append(label)
        label = entry["same_as"]
        if label in seen or label not in table:
            raise SMFError(f"lexicon: {where} {seen[0]!r}: bad same_as chain {seen + [label]}")
        entry = table[label]
    return entry


def parse_lexicon(data: dict, name: str = "lexicon") -> Lexicon:
    """A :class:`Lexicon` from the JSON object of a lexicon file (see the module docstring)."""
    mirror = {k.lower(): v.lower() for k, v in data.get("mirror", {}).items()}
    lex = Lexicon(name, {}, {}, {}, mirror, frozenset(w.lower() for w in data.get("heldout_words", ())))
    for label in data["contents"]:
        lex.contents[label] = _words(_resolve(data["contents"], label, "content"), f"content {label}")
    for label in list(lex.contents):
        mirrored = lex.mirror_text(label)
        if mirrored != label and mirrored not in lex.contents:
            w = lex.contents[label]
            lex.contents[mirrored] = Words(*(tuple(map(lex.mirror_text, part))
                                             for part in (w.train, w.heldout, w.examples)))
    for label in data["styles"]:
        entry = _resolve(data["styles"], label, "style")
        lex.styles[label] = StyleWords(label, *(_words(entry.get(k), f"style {label} {k}") for k in STYLE_KINDS))
    for c in data.get("tempo_free", ()):
        lex.content(c)
    lex = replace(lex, tempo_free=frozenset(c2 for c in data.get("tempo_free", ()) for c2 in (c, lex.mirror_text(c))))
    for d, labels in data.get("datasets", {}).items():
        lex.datasets[int(d)] = (tuple(labels["contents"]), tuple(labels["styles"]))
        for c in labels["contents"]:
            lex.content(c)
        for s in labels["styles"]:
            lex.style(s)
    return lex


@functools.lru_cache(maxsize=8)
def load_lexicon(name: str = "bandai") -> Lexicon:
    """The lexicon shipped in the package as ``assets/lexicons/<name>.json``, or a path to such a file."""
    path = Path(name)
    if path.suffix != ".json":
        path = Path(str(resources.files("stablemofusion") / "assets" / "lexicons" / f"{name}.json"))
    if not path.is_file():
        raise SMFError(f"no lexicon {name!r} (looked for {path})")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise SMFError(f"lexicon {path}: not valid JSON ({e})") from None
    return parse_lexicon(data, path.stem)


def marked_verbs(phrase: str) -> list[tuple[str, str, str]]:
    """The marked verbs of a phrasing as (base, third person, -ing) forms, in order."""
    return [verb_forms(m) for m in re.findall(r"<([^<>]+)>", phrase)]


_DOUBLE_FINAL = frozenset("run jog step sidestep jab put cut hop skip stop trot shop grab drop drag".split())


def verb_forms(marker: str) -> tuple[str, str, str]:
    """``walk`` -> (walk, walks, walking); ``swing|swings|swinging`` is taken as given."""
    parts = marker.split("|")
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    if len(parts) != 1:
        raise SMFError(f"lexicon: verb marker <{marker}> needs 1 or 3 forms")
    lemma = parts[0]
    if lemma.endswith(("s", "sh", "ch", "x", "z", "o")):
        third = lemma + "es"
    elif lemma.endswith("y") and lemma[-2] not in "aeiou":
        third = lemma[:-1] + "ies"
    else:
        third = lemma + "s"
    if lemma in _DOUBLE_FINAL:
        ing = lemma + lemma[-1] + "ing"
    elif lemma.endswith("ie"):
        ing = lemma[:-2] + "ying"
    elif lemma.endswith("e") and not lemma.endswith(("ee", "ye")):
        ing = lemma[:-1] + "ing"
    else:
        ing = lemma + "ing"
    return lemma, third, ing


def person_sentence(phrase: str) -> str:
    """A phrasing as a third-person sentence: ``<walk> forward`` -> "a person walks forward"."""
    return "a person " + re.sub(r"<([^<>]+)>", lambda m: verb_forms(m.group(1))[1], phrase).replace("{pos}", "their")


def known_actions(lex: Lexicon, threshold: float) -> dict:
    """The ``actions.json`` content of a model trained on this lexicon's corpus (see
    :mod:`stablemofusion.text.known`): each content label with "a person ..." sentences made from its
    training phrasings and its ``examples``."""
    actions = {label: [person_sentence(p) for p in words.train + words.examples]
               for label, words in lex.contents.items()}
    return {"about": f"example sentences per action from the {lex.name} lexicon's training phrasings and examples; a "
                     "prompt whose best cosine similarity to them is below threshold is out of domain",
            "threshold": threshold, "actions": actions}


__all__ = ["known_actions", "Lexicon", "StyleWords", "Words", "STYLE_KINDS", "load_lexicon", "parse_lexicon", "marked_verbs",
           "verb_forms", "person_sentence"]
