"""Training captions for labelled motion corpora: a sentence grammar over a corpus lexicon.

The words are data (:mod:`.lexicon`: ``assets/lexicons/<corpus>.json`` for content phrasings and style
words, ``common.json`` for subjects, irrelevant details and the part-of-speech table); this module is the
grammar: :data:`STRUCTURES` are the sentence structures people use to describe a motion (statements,
imperatives, fragments, participles, two-sentence descriptions, irrelevant detail, similes), filled from
the lexicon, with some lower-casing and typos as in typed prompts. Each caption also gets HumanML3D
``word/POS`` tokens (verbs lemmatised) from a small rule tagger, for the corpus file layout.
"""

from __future__ import annotations

import functools
import json
import random
import re
import zlib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Sequence

from ..core.errors import SMFError
from .augment import AugmentConfig, augment_caption
from .lexicon import Lexicon, load_lexicon, marked_verbs, verb_forms

POS_TAGS = frozenset(
    "NOUN VERB ADJ ADV DET ADP PRON PROPN AUX CCONJ PART NUM SCONJ PUNCT INTJ".split()
)

# Sentence structures. Slots: {S} a neutral subject, {P} a styled subject (a persona such as "an old man"
# or an adjective + noun), {VP} / {VPING} / {VPB} the content's verb phrase (third person, -ing, base),
# {ADV} {MAN} {ADJ} style adverb / manner phrase / adjective, {LIKE} a persona as a simile ("like an old
# man"), {THEY} "he looks" / "they look", {DF} {DB} irrelevant detail (front / back), {CL} clothing.
STRUCTURES: dict[str, str] = {
    "statement_adv": "{S} {VP} {ADV}.",
    "statement_adv_first": "{S} {ADV} {VP}.",
    "persona": "{P} {VP}.",
    "persona_progressive": "{P} is {VPING}.",
    "persona_fragment": "{P} {VPING}",
    "manner": "{S} {VP} {MAN}.",
    "manner_progressive": "{S} is {VPING} {MAN}.",
    "mood_mid": "{S}, looking {ADJ}, {VP}.",
    "mood_end": "{S} {VP}, looking {ADJ}.",
    "imperative_adv": "{VPB} {ADV}",
    "imperative_manner": "{VPB} {MAN}.",
    "imperative_adv_first": "{ADV} {VPB}",
    "imperative_like": "{VPB} {LIKE}",
    "participle_adv": "{VPING} {ADV}",
    "participle_manner": "{VPING} {MAN}",
    "adjective_fragment": "{ADJ}, {VPING}",
    "relative": "{P} who {VP}",
    "there_is": "there is {P} {VPING}.",
    "adverb_front": "{ADV}, {S} {VP}.",
    "manner_front": "{MAN}, {S} {VP}.",
    "two_sentences": "{S} {VP}. {THEY} {ADJ}.",
    "detail_front": "{DF}, {P} {VP}.",
    "detail_back": "{P} {VP} {DB}.",
    "clothes": "{S} {CL} {VP} {ADV}.",
    "motion_of": "the motion of {P} {VPING}",
    "animation_of": "animation of {P} {VPING}.",
    "is_and": "{S} is {ADJ} and {VP}.",
    "feels_and": "{S} feels {ADJ} and {VP}.",
    "double_style": "{S} {VP} {ADV}, {MAN}.",
    "label_colon": "{P}: {VPING}",
    "simile": "{S} {VP} {LIKE}.",
    "long_description": "{DF}, {S} {CL} {VP}. {THEY} {ADJ} and keeps going {ADV}.",
    "plain": "{S} {VP}.",
    "plain_imperative": "{VPB}",
    "plain_participle": "{S} {VPING}",
    "plain_detail": "{DF}, {S} {VP}.",
}
# structures without a style slot: used for the "normal" style (among the others), never for other styles
_UNSTYLED = ("plain", "plain_imperative", "plain_participle", "plain_detail")
_STYLE_SLOTS = {"P": "personas", "ADV": "adverbs", "MAN": "manners", "ADJ": "adjectives", "LIKE": "personas"}
_HEAD_POSSESSIVE = {"man": "his", "boy": "his", "guy": "his", "grandpa": "his", "grandfather": "his", "king": "his",
                    "gentleman": "his", "father": "his", "dad": "his", "soldier": "his",
                    "woman": "her", "girl": "her", "lady": "her", "grandma": "her", "grandmother": "her",
                    "queen": "her", "ballerina": "her", "mother": "her", "mom": "her"}
_LOOKS = {"his": "he looks", "her": "she looks", "their": "they look", "its": "it looks"}
NOISE = AugmentConfig(synonym=0.0, dropout=0.0, typo=0.04, casing=0.25)


@functools.lru_cache(maxsize=1)
def common_words() -> dict:
    """``assets/lexicons/common.json``: subjects, details, clothing and the POS table of the grammar."""
    path = Path(str(resources.files("stablemofusion") / "assets" / "lexicons" / "common.json"))
    return json.loads(path.read_text(encoding="utf-8"))


@dataclass(frozen=True)
class Caption:
    """One generated caption: text, HumanML3D tokens and the sentence structure used."""

    text: str
    tokens: list[str]
    form: str


def _seed(seed: int | str, content: str, style: str) -> int:
    return zlib.crc32(f"{seed}|{content}|{style}".encode())


def _possessive(noun_phrase: str, default: str) -> str:
    return _HEAD_POSSESSIVE.get(noun_phrase.split()[-1].lower(), default)


def _fill(structure: str, lex: Lexicon, content: str, style: str, rng: random.Random, heldout: bool) -> str:
    words = common_words()
    sw = lex.style(style)
    phrase = rng.choice(lex.content(content).pick(heldout))
    subject, possessive = rng.choice(words["subjects"])
    styled, styled_pos = subject, possessive
    if "{P}" in structure or "{LIKE}" in structure:
        personas = sw.personas.pick(heldout)
        adjectives = sw.adjectives.pick(heldout)
        if personas and (not adjectives or rng.random() < 0.5 or "{LIKE}" in structure):
            styled = rng.choice(personas)
            styled_pos = _possessive(styled, "their")
        elif adjectives:
            det_nouns = [s for s in words["subjects"] if s[0].split()[0] in ("a", "an", "the")]
            (np_, styled_pos) = rng.choice(det_nouns)
            det, noun = np_.split(" ", 1)
            adj = rng.choice(adjectives)
            det = ("an" if adj[0] in "aeiou" else "a") if det in ("a", "an") else det
            styled = f"{det} {adj} {noun}"
    if "{LIKE}" in structure:
        possessive = "your" if structure.startswith("{VPB}") else possessive
    elif "{P}" in structure:
        possessive = styled_pos
    elif structure.startswith(("{VPB}", "{ADV} {VPB}")):
        possessive = "your"
    elif structure.startswith(("{VPING}", "{ADJ}")):
        possessive = "their"

    def verb_phrase(form: int) -> str:
        out = re.sub(r"<([^<>]+)>", lambda m: verb_forms(m.group(1))[form], phrase)
        return out.replace("{pos}", possessive)

    def pick(kind: str) -> str:
        items = sw.kind(kind).pick(heldout)
        return rng.choice(items).replace("{pos}", possessive) if items else ""

    fill = {
        "S": subject, "P": styled, "VP": verb_phrase(1), "VPING": verb_phrase(2), "VPB": verb_phrase(0),
        "ADV": pick("adverbs"), "MAN": pick("manners"), "ADJ": pick("adjectives"),
        "LIKE": "like " + rng.choice(sw.personas.pick(heldout) or ("",)),
        "THEY": _LOOKS.get(possessive, "they look"), "DF": rng.choice(words["details_front"]),
        "DB": rng.choice(words["details_back"]), "CL": rng.choice(words["clothes"]),
    }
    text = re.sub(r"\{(\w+)\}", lambda m: fill[m.group(1)], structure)
    text = re.sub(r"\s+", " ", text).strip()
    text = re.sub(r"(^|[.:] )([a-z])", lambda m: m.group(1) + m.group(2).upper(), text)  # sentence starts
    return text


def structures_for(lex: Lexicon, style: str, heldout: bool = False) -> list[str]:
    """Names of the structures whose style slots the style can fill (all style-free ones for "normal")."""
    sw = lex.style(style)
    out = []
    for name, structure in STRUCTURES.items():
        slots = set(re.findall(r"\{(\w+)\}", structure))
        kinds = {_STYLE_SLOTS[s] for s in slots if s in _STYLE_SLOTS}
        if name in _UNSTYLED:
            if style == "normal":
                out.append(name)
            continue
        if all(sw.kind(k).pick(heldout) for k in kinds):
            out.append(name)
    return out


@functools.lru_cache(maxsize=4)
def _tagger(lex_name: str) -> tuple[dict[str, str], dict[str, str], frozenset[str]]:
    """(verb surface -> lemma, function word -> POS, style adjectives) for :func:`tokens_of`."""
    lex = load_lexicon(lex_name)
    verbs: dict[str, str] = {}
    for words in lex.contents.values():
        for phrase in (*words.train, *words.heldout):
            for base, third, ing in marked_verbs(phrase):
                for form in (base, third, ing):
                    verbs.setdefault(form, base)
    pos = {w: tag for tag, ws in common_words()["pos"].items() for w in ws.split()}
    adjs = {w.lower() for sw in lex.styles.values() for a in (*sw.adjectives.train, *sw.adjectives.heldout)
            for w in a.split()}
    return verbs, pos, frozenset(adjs)


def tokens_of(text: str, lexicon: str = "bandai") -> list[str]:
    """HumanML3D-style ``word/POS`` tokens of a caption (punctuation dropped, verbs lemmatised)."""
    verbs, pos, adjs = _tagger(lexicon)
    out = []
    for w in re.findall(r"[A-Za-z][A-Za-z'-]*", text.lower()):
        if w in pos:
            lemma = w[:-1] if pos[w] == "VERB" and w.endswith("s") else w
            out.append(f"{lemma}/{pos[w]}")
        elif w in verbs:
            out.append(f"{verbs[w]}/VERB")
        elif w in adjs:
            out.append(f"{w}/ADJ")
        elif w.endswith("ly"):
            out.append(f"{w}/ADV")
        else:
            out.append(f"{w}/NOUN")
    return out


def generate(content: str, style: str, n: int = 6, seed: int | str = 0, *, heldout: bool = False,
             lexicon: str = "bandai", noise: AugmentConfig = NOISE) -> list[Caption]:
    """``n`` distinct captions of a clip of ``content`` in ``style``, cycling through the structures.

    ``heldout=True`` uses only the lexicon's held-out words (a probe; training never sees them).
    Deterministic for a given ``seed`` (an int or a clip id).
    """
    lex = load_lexicon(lexicon)
    lex.content(content)
    if n < 0:
        raise SMFError(f"number of captions must be >= 0, got {n}")
    rng = random.Random(_seed(seed, content, style))
    forms = structures_for(lex, style, heldout)
    rng.shuffle(forms)
    out: list[Caption] = []
    seen: set[str] = set()
    for i in range(200 * max(n, 1)):
        if len(out) == n:
            break
        form = forms[i % len(forms)]
        text = augment_caption(_fill(STRUCTURES[form], lex, content, style, rng, heldout), rng, None, noise)
        if text.lower() not in seen:
            seen.add(text.lower())
            out.append(Caption(text, tokens_of(text, lexicon), form))
    if len(out) < n:
        raise SMFError(f"could not make {n} distinct captions for {content}/{style}")
    return out


def captions_for(content: str, style: str, n: int = 6, seed: int | str = 0, *, heldout: bool = False,
                 lexicon: str = "bandai") -> list[tuple[str, list[str]]]:
    """``n`` distinct (caption, ``word/POS`` tokens) pairs for a clip of ``content`` in ``style``."""
    return [(c.text, c.tokens) for c in generate(content, style, n, seed, heldout=heldout, lexicon=lexicon)]


# ------------------------------------------------------------------------------------------- paraphrases

PARAPHRASE_HEADS = 3  # a content is described by a verb that heads at least this many of its training phrasings
_WORD = re.compile(r"[a-z]+")
_BACK = frozenset(("back", "backward", "backwards", "backing", "reverse", "turn", "turns", "turning", "around"))
# direction words besides the lexicon's mirror words


def _phrase_words(phrase: str) -> set[str]:
    """The words of a phrasing, each marked verb in all its forms."""
    words = set(_WORD.findall(re.sub(r"<[^<>]+>", " ", phrase).lower()))
    return words.union(*(set(forms) for forms in marked_verbs(phrase)))


def described_by(caption: str, lexicon: str = "bandai") -> list[str]:
    """The lexicon's contents that its training phrasings describe with one of the caption's words (any form) as
    their head verb, in at least PARAPHRASE_HEADS phrasings, at least half of which go where the caption goes
    (:func:`same_direction`): "a person runs forward" -> run and dash (running, sprinting); "walks forward" -> walk,
    not walking backwards."""
    words = set(_WORD.findall(caption.lower()))
    out = []
    for label, phrasings in load_lexicon(lexicon).contents.items():
        heads = [verbs[0] for verbs in map(marked_verbs, phrasings.train) if verbs]
        alike = [p for p in phrasings.train if same_direction(_phrase_words(p), words, lexicon)]
        if sum(bool(set(forms) & words) for forms in heads) >= PARAPHRASE_HEADS and \
                2 * len(alike) >= len(phrasings.train):
            out.append(label)
    return out


def same_direction(words: set[str], caption_words: set[str], lexicon: str = "bandai") -> bool:
    """Whether a text of ``words`` goes where a caption of ``caption_words`` goes: no direction word (left, right,
    clockwise, back, around, ...) the caption lacks, and one of the caption's where it has any."""
    every = set(load_lexicon(lexicon).mirror) | _BACK
    theirs, ours = words & every, caption_words & every
    return theirs <= ours and (bool(theirs) or not ours)


def paraphrases(caption: str, n: int, seed: int | str = 0, lexicon: str = "bandai") -> list[str]:
    """Up to ``n`` other ways to say ``caption``: its verb phrase replaced by other training phrasings of the
    contents the corpus lexicon describes with the caption's verb (:func:`described_by`; "an active person runs
    forward": run and dash, so "an active person jogs ahead", "an active person sprints flat out"), its subject and
    style words kept, each going where the caption goes (:func:`same_direction`). Empty where the lexicon describes no
    content with the caption's verb, or the caption has no subject before it. Deterministic for a ``seed``."""
    lex = load_lexicon(lexicon)
    contents = described_by(caption, lexicon)
    if n <= 0 or not contents:
        return []
    heads = {form for c in contents for verbs in map(marked_verbs, lex.contents[c].train) if verbs
             for form in verbs[0]}
    verb = next((m for m in re.finditer(r"[A-Za-z]+", caption) if m.group(0).lower() in heads), None)
    subject = caption[:verb.start()].strip() if verb is not None else ""
    if not subject:
        return []
    words = set(_WORD.findall(caption.lower()))
    pos = _possessive(subject, "their")
    own = caption[verb.start():].strip().lower().rstrip(".")
    phrases = sorted({re.sub(r"<([^<>]+)>", lambda m: verb_forms(m.group(1))[1], p).replace("{pos}", pos)
                      for c in contents for p in lex.contents[c].train if marked_verbs(p)})
    phrases = [p for p in phrases if p.lower() != own and same_direction(set(_WORD.findall(p.lower())), words, lexicon)]
    random.Random(zlib.crc32(f"{seed}|{caption}".encode())).shuffle(phrases)
    return [f"{subject} {p}" for p in phrases[:n]]


# --------------------------------------------------------------------------------------------- mirroring

_MIRROR_WORDS = {
    "left": "right", "right": "left", "leftward": "rightward", "rightward": "leftward",
    "leftwards": "rightwards", "rightwards": "leftwards", "clockwise": "counterclockwise",
    "counterclockwise": "clockwise", "anticlockwise": "clockwise",
}
_MIRROR_RE = re.compile(
    r"(?<![A-Za-z])(counter[- ]?clockwise|anti[- ]?clockwise|clockwise|leftwards?|rightwards?|left|right)"
    r"(?![A-Za-z])",
    re.IGNORECASE,
)
_RIGHT_IDIOM_NEXT = {"away", "now", "here", "there"}  # "right away" is not a direction


def _match_case(src: str, dst: str) -> str:
    if len(src) > 1 and src.isupper():
        return dst.upper()
    return dst[:1].upper() + dst[1:] if src[:1].isupper() else dst


def mirror_caption(caption: str) -> str:
    """Swap left/right (leftward, clockwise...) words, keeping their capitalisation.

    ``anticlockwise`` becomes ``clockwise``, which mirrors back to ``counterclockwise``.
    """

    def swap(m: re.Match[str]) -> str:
        word = m.group(0)
        key = re.sub(r"[- ]", "", word.lower())
        if key == "right":
            after = caption[m.end():].split(None, 1)
            before = caption[: m.start()].split()
            if (after and after[0].lower().strip(".,;!?") in _RIGHT_IDIOM_NEXT) or (
                before and before[-1].lower() == "all"
            ):
                return word
        return _match_case(word, _MIRROR_WORDS[key])

    return _MIRROR_RE.sub(swap, caption)


def mirror_tokens(tokens: Sequence[str]) -> list[str]:
    """Mirror ``word/POS`` tokens like :func:`mirror_caption` (POS tags are kept)."""
    words = [t.rsplit("/", 1)[0].lower() for t in tokens]
    out = []
    for i, tok in enumerate(tokens):
        word, sep, pos = tok.rpartition("/") if "/" in tok else (tok, "", "")
        nxt, prev = words[i + 1] if i + 1 < len(words) else "", words[i - 1] if i else ""
        idiom = words[i] == "right" and (nxt in _RIGHT_IDIOM_NEXT or prev == "all")
        if words[i] in _MIRROR_WORDS and not idiom:
            word = _match_case(word, _MIRROR_WORDS[words[i]])
        out.append(f"{word}{sep}{pos}")
    return out


def mirror_label(content: str) -> str:
    """The content label of a left/right-mirrored clip (``walk-left`` <-> ``walk-right``)."""
    load_lexicon().content(content)
    parts = [{"left": "right", "right": "left"}.get(p, p) for p in content.split("-")]
    return "-".join(parts)


