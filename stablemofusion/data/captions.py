"""Template captions for the Bandai-Namco motion datasets, with HumanML3D ``word/POS`` tokens.

Every caption is assembled from annotated pieces: verb markers ``<walk>`` (inflected to ``walks`` or
``walking``), ``{pos}`` (his/her/their, agreeing with the subject), plain words looked up in a small
lexicon, and explicit annotations ``word_POS`` / ``surface=lemma_POS`` for ambiguous or irregular
words. Tokens therefore follow HumanML3D's convention by construction: punctuation is dropped, nouns
and verbs are lemmatised (``kicks`` -> ``kick/VERB``), other words keep their lower-case form
(``is/AUX``, ``his/DET``).
"""

from __future__ import annotations

import random
import re
import zlib
from dataclasses import dataclass
from typing import Sequence

from ..errors import SMFError

POS_TAGS = frozenset(
    "NOUN VERB ADJ ADV DET ADP PRON PROPN AUX CCONJ PART NUM SCONJ PUNCT INTJ".split()
)

# --------------------------------------------------------------------------------------------- lexicon

_FUNCTION_WORDS = {
    "DET": "a an the both his her their",
    "PRON": "someone somebody something he she them",
    "ADP": "to with in at of like into through above over on for by before toward towards out from",
    "AUX": "is",
    "CCONJ": "and or",
    "SCONJ": "as if though while",
    "PART": "not",
    "NUM": "one",
    "ADV": "forward backward backwards ahead straight sideways leftward rightward back up then around "
    "high normally casually naturally happily cheerfully joyfully sadly gloomily dejectedly angrily "
    "furiously proudly confidently arrogantly timidly hesitantly nervously shyly gracefully daintily "
    "elegantly childishly playfully stiffly feebly slowly tiredly wearily sluggishly energetically "
    "vigorously actively briskly theatrically rhythmically musically heavily ponderously clumsily "
    "cockily menacingly youthfully nimbly visibly completely very downward",
    "ADJ": "happy cheerful joyful sad gloomy dejected sorrowful upset angry furious irritated proud "
    "haughty confident timid insecure hesitant unconfident shy unsure nervous masculine manly feminine "
    "graceful dainty ladylike childish childlike playful little young old elderly frail tired weary "
    "exhausted drained active energetic lively vigorous theatrical showy rhythmic huge heavy hulking "
    "big cocky thuggish menacing tough youthful sprightly relaxed calm normal ordinary natural full "
    "few short long quick open imaginary left right obvious great macho",
}
_NOUNS = (
    "person man woman figure character human individual child kid thug punk delinquent giant "
    "performer stage dancer teenager senior hand arm head fist foot leg chest waist sword air way manner "
    "fashion mood pace step line distance walk run dash kick punch bow wave turn dance routine call "
    "response gesture goodbye farewell bye time moment motion sweep anger pride energy joy heart "
    "confidence age breath flair rhythm attitude swagger speed bounce posture vigor"
)
_IRREGULAR_PLURALS = {"man": "men", "woman": "women", "child": "children", "foot": "feet"}
_VERBS = (
    "walk run dash sprint jog stride step sidestep move take turn make bow bend give wave say raise "
    "lift put hold guide show gesture point extend direct respond answer reply beckon call motion come "
    "punch throw strike jab kick perform slash swing cut dance do look act lack burst hunch face go "
    "use sweep"
)
_DOUBLE_FINAL = {"run", "jog", "step", "sidestep", "jab", "put", "cut"}


def _inflect(lemma: str) -> tuple[str, str]:
    """(third-person singular, -ing form) of a regular verb."""
    if lemma.endswith(("s", "sh", "ch", "x", "z", "o")):
        third = lemma + "es"
    elif lemma.endswith("y") and lemma[-2] not in "aeiou":
        third = lemma[:-1] + "ies"
    else:
        third = lemma + "s"
    if lemma in _DOUBLE_FINAL:
        ing = lemma + lemma[-1] + "ing"
    elif lemma.endswith("e") and not lemma.endswith(("ee", "ye")):
        ing = lemma[:-1] + "ing"
    else:
        ing = lemma + "ing"
    return third, ing


def _build_lexicon() -> dict[str, dict[str, str]]:
    lex: dict[str, dict[str, str]] = {}

    def add(surface: str, pos: str, lemma: str) -> None:
        lex.setdefault(surface, {})[pos] = lemma

    for pos, words in _FUNCTION_WORDS.items():
        for w in words.split():
            add(w, pos, w)
    for noun in _NOUNS.split():
        plural = _IRREGULAR_PLURALS.get(noun) or (noun + "es" if noun.endswith(("s", "sh", "ch", "x")) else noun + "s")
        add(noun, "NOUN", noun)
        add(plural, "NOUN", noun)
    for verb in _VERBS.split():
        for form in (verb, *_inflect(verb)):
            add(form, "VERB", verb)
    return lex


_LEXICON = _build_lexicon()


@dataclass(frozen=True)
class _Word:
    surface: str
    lemma: str
    pos: str

    @property
    def token(self) -> str:
        return f"{self.lemma if self.pos in ('NOUN', 'VERB') else self.surface}/{self.pos}"


def _lookup(item: str) -> _Word:
    """One annotated template word: ``word``, ``word_POS`` or ``surface=lemma_POS``."""
    if item == ",":
        return _Word(",", ",", "PUNCT")
    body, _, pos = item.partition("_")
    surface, _, lemma = body.partition("=")
    if lemma:
        return _Word(surface, lemma, pos)
    entries = _LEXICON.get(surface, {})
    if pos:
        if pos not in POS_TAGS:
            raise KeyError(f"unknown POS tag in caption template item {item!r}")
        return _Word(surface, entries.get(pos, surface), pos)
    if len(entries) != 1:
        raise KeyError(f"caption word {surface!r} is unknown or ambiguous ({sorted(entries)}); annotate it")
    pos, lemma = next(iter(entries.items()))
    return _Word(surface, lemma, pos)


_VOWEL_EXCEPTIONS = ("one", "uni", "use", "usu")


def _parse(text: str) -> list[_Word]:
    """Annotated sentence -> words, with the article a/an agreeing with the next word."""
    words = [_lookup(item) for item in text.replace(",", " , ").split()]
    for i, w in enumerate(words[:-1]):
        if w.pos == "DET" and w.surface in ("a", "an"):
            nxt = words[i + 1].surface
            art = "an" if nxt[0] in "aeiou" and not nxt.startswith(_VOWEL_EXCEPTIONS) else "a"
            words[i] = _Word(art, art, "DET")
    return words


# --------------------------------------------------------------------------------------------- labels


@dataclass(frozen=True)
class Content:
    """An action label and its verb-phrase templates (``!`` marks energetic wording)."""

    label: str
    datasets: tuple[int, ...]
    phrases: tuple[str, ...]


@dataclass(frozen=True)
class Style:
    """A style label and the ways to say it."""

    label: str
    datasets: tuple[int, ...]
    adjs: tuple[str, ...] = ()  # "a tired person"
    advs: tuple[str, ...] = ()  # "walks forward tiredly"
    phrases: tuple[str, ...] = ()  # "walks forward as if exhausted"
    moods: tuple[str, ...] = ()  # "a person, looking tired, walks forward"
    nouns: tuple[str, ...] = ()  # "an old man walks forward"
    low_energy: bool = False  # skip energetic wording ("strides")
    avoid: tuple[str, ...] = ()  # subject nouns that would sound redundant ("a manly man")


_PHRASES: dict[str, tuple[str, ...]] = {
    "walk": ("<walk> forward", "<walk> straight ahead", "<walk> forward in a straight line",
             "<take> a few steps_NOUN forward", "!<stride> ahead", "<walk> ahead", "<walk> a short distance forward"),
    "run": ("<run> forward", "<jog> forward", "<run> straight ahead", "<run> ahead",
            "<run> forward in a straight line", "<jog> ahead"),
    "dash": ("<dash> forward", "<sprint> forward", "<sprint> ahead", "<dash> ahead at full speed",
             "<run> forward at full speed", "<make> a quick dash_NOUN forward"),
    "walk-back": ("<walk> backwards", "<walk> backward", "<step> backwards", "<walk> backwards a few steps_NOUN",
                  "<move> backward", "<walk> backwards while <face:ing> forward"),
    "walk-left": ("<walk> to the left_NOUN", "<walk> sideways to the left_NOUN", "<sidestep> to the left_NOUN",
                  "<step> sideways to the left_NOUN", "<move> toward the left_NOUN", "<walk> leftward"),
    "bow": ("<bow>", "<bow> forward", "<take> a bow_NOUN", "<bow> {pos} head", "<bend> forward at the waist",
            "<give> a bow_NOUN", "<bow> to someone"),
    "bye": ("<wave> goodbye", "<wave> goodbye with one hand", "<wave> {pos} hand to_PART say goodbye",
            "<wave> farewell", "<say> goodbye with a wave_NOUN of {pos} hand", "<wave> bye with one hand"),
    "byebye": ("<wave> goodbye with both hands", "<wave> both hands to_PART say goodbye",
               "<wave> both arms to_PART say bye", "<wave> goodbye with both arms",
               "<say> goodbye by <wave:ing> both hands", "<wave> both hands over {pos} head to_PART say goodbye"),
    "guide": ("<show> someone the way with {pos} hand", "<gesture> to_PART show someone the way",
              "<point> the way with an open hand", "<guide> someone forward with a hand_NOUN gesture_NOUN",
              "<extend> {pos} arm to_PART show the way",
              "<direct> someone with a sweeping=sweep_VERB gesture_NOUN of {pos} arm"),
    "respond": ("<respond> to someone by <raise:ing> {pos} hand", "<raise> a hand in response to a call_NOUN",
                "<answer> a call_NOUN with a wave_NOUN of {pos} hand",
                "<respond> to a call_NOUN with a hand_NOUN gesture_NOUN",
                "<reply> to someone with a gesture_NOUN", "<answer> someone by <raise:ing> {pos} hand"),
    "call": ("<beckon> someone over_ADV", "<beckon> someone with {pos} hand", "<call> someone over_ADV with {pos} hand",
             "<wave> someone over_ADV", "<motion> for someone to_PART come closer=close_ADV",
             "<gesture> for someone to_PART come over_ADV"),
    "punch": ("<punch> forward", "<throw> a punch_NOUN", "<punch> the air", "<throw> a few punches_NOUN",
              "<strike> forward with {pos} fist", "<jab> forward with {pos} fist"),
    "kick": ("<kick> forward", "<kick> with one leg", "<throw> a kick_NOUN", "<kick> the air",
             "<perform> a kick_NOUN", "<kick> out_ADP with {pos} foot", "<kick> one leg forward"),
    "slash": ("<slash> with an imaginary sword", "<make> a slashing=slash_VERB motion_NOUN with {pos} arm",
              "<swing> {pos} arm in a slashing=slash_VERB motion_NOUN", "<slash> through the air",
              "<swing> an imaginary sword", "<slash> downward with an imaginary sword"),
    "dance-long": ("<dance>", "<dance> for a long time", "<perform> a long dance_NOUN", "<dance> around",
                   "<do> a long dance_NOUN routine", "<dance> through a full routine"),
    "dance-short": ("<dance>", "<do> a short dance_NOUN", "<perform> a short dance_NOUN",
                    "<dance> for a moment", "<do> a quick dance_NOUN move_NOUN", "<dance> a few steps_NOUN"),
    "walk-turn-left": ("<walk> forward and <turn> left_ADV", "<walk> and <turn> to the left_NOUN",
                       "<walk> forward , then <turn> left_ADV", "<walk> forward before <turn:ing> left_ADV",
                       "<walk> and <make> a left_ADJ turn_NOUN", "<turn> left_ADV while <walk:ing>",
                       "<walk> forward and <turn> to {pos} left_NOUN"),
    "wave-both-hands": ("<wave> both hands", "<wave> both hands in the air", "<wave> with both hands",
                        "<raise> both hands and <wave> them", "<wave> both arms above {pos} head",
                        "<wave> both arms"),
    "wave-left-hand": ("<wave> {pos} left_ADJ hand", "<wave> with {pos} left_ADJ hand",
                       "<raise> {pos} left_ADJ hand and <wave>", "<wave> {pos} left_ADJ arm",
                       "<wave> {pos} left_ADJ hand in the air", "<wave> using=use_VERB {pos} left_ADJ hand"),
    "raise-up-both-hands": ("<raise> both hands", "<raise> both arms up", "<lift> both hands above {pos} head",
                            "<put> both hands up", "<raise> both hands into the air",
                            "<raise> both arms over_ADP {pos} head", "<hold> both arms up"),
    "raise-up-left-hand": ("<raise> {pos} left_ADJ hand", "<lift> {pos} left_ADJ arm up",
                           "<raise> {pos} left_ADJ hand into the air", "<put> {pos} left_ADJ hand up",
                           "<raise> {pos} left_ADJ arm above {pos} head", "<raise> {pos} left_ADJ hand high"),
}

_DATASET1_CONTENTS = ("walk run dash walk-back walk-left walk-right bow bye guide byebye respond call punch "
                      "kick slash dance-long dance-short").split()
_DATASET2_CONTENTS = ("walk walk-turn-left walk-turn-right run wave-both-hands wave-left-hand wave-right-hand "
                      "raise-up-both-hands raise-up-left-hand raise-up-right-hand").split()

_OLD = dict(
    adjs=("old", "elderly", "frail"),
    advs=("stiffly", "feebly", "slowly"),
    phrases=("like an old man", "like an old woman", "like an elderly person", "in an elderly way"),
    moods=("looking old and frail", "bent=bend_VERB with age", "hunched=hunch_VERB over_ADP"),
    nouns=("an old man", "an old woman", "an elderly person", "an elderly man", "an elderly woman"),
    low_energy=True,
)
_TIRED = dict(
    adjs=("tired", "weary", "exhausted"),
    advs=("tiredly", "wearily", "sluggishly"),
    phrases=("as if exhausted", "as though tired", "in a tired way", "with very little energy"),
    moods=("looking tired", "visibly exhausted", "out_ADP of breath"),
    low_energy=True,
)
_MASCULINE = dict(
    adjs=("masculine", "manly", "macho"),
    phrases=("in a masculine way", "in a manly fashion", "with a masculine posture", "like a macho man"),
    moods=("looking masculine", "looking manly and tough"),
    avoid=("man",),
)
_STYLE_SPECS: dict[str, dict] = {
    "normal": dict(
        advs=("normally", "casually", "naturally"),
        phrases=("in a normal way", "in a relaxed manner", "in an ordinary way", "in a natural way"),
        moods=("looking relaxed", "looking calm"),
    ),
    "happy": dict(
        adjs=("happy", "cheerful", "joyful"),
        advs=("happily", "cheerfully", "joyfully"),
        phrases=("in a happy mood", "in a cheerful way", "in a joyful manner", "with obvious joy"),
        moods=("looking happy", "looking cheerful", "full of joy"),
    ),
    "sad": dict(
        adjs=("sad", "gloomy", "dejected", "sorrowful"),
        advs=("sadly", "gloomily", "dejectedly"),
        phrases=("in a sad way", "with a heavy heart", "in a gloomy mood"),
        moods=("looking sad", "looking dejected", "visibly upset"),
        low_energy=True,
    ),
    "angry": dict(
        adjs=("angry", "furious", "irritated"),
        advs=("angrily", "furiously"),
        phrases=("in an angry way", "in a fit=fit_NOUN of anger", "with obvious anger"),
        moods=("looking angry", "visibly furious", "full of anger"),
    ),
    "proud": dict(
        adjs=("proud", "haughty", "confident"),
        advs=("proudly", "confidently", "arrogantly"),
        phrases=("with great pride", "in a proud manner", "with {pos} head held=hold_VERB high"),
        moods=("looking proud", "looking confident", "full of pride"),
    ),
    "not-confident": dict(
        adjs=("timid", "insecure", "hesitant", "unconfident", "shy"),
        advs=("timidly", "hesitantly", "nervously", "shyly"),
        phrases=("without=without_ADP confidence", "in an unsure way", "in a timid manner",
                 "with little confidence"),
        moods=("looking unsure", "lacking confidence", "looking nervous"),
        low_energy=True,
    ),
    "masculinity": _MASCULINE,
    "masculine": _MASCULINE,
    "feminine": dict(
        adjs=("feminine", "graceful", "dainty"),
        advs=("gracefully", "daintily", "elegantly"),
        phrases=("in a feminine way", "in a feminine manner", "in a ladylike fashion"),
        moods=("looking feminine", "looking graceful"),
        avoid=("woman",),
    ),
    "childish": dict(
        adjs=("childish", "childlike", "playful"),
        advs=("childishly", "playfully"),
        phrases=("like a child", "like a little kid", "in a childish way"),
        moods=("acting like a child", "looking playful"),
        nouns=("a child", "a little kid", "a young child"),
    ),
    "old": _OLD,
    "elderly": _OLD,
    "tired": _TIRED,
    "exhausted": dict(_TIRED, adjs=("exhausted", "tired", "weary", "drained"),
                      phrases=("as if exhausted", "in an exhausted way", "as though completely exhausted",
                               "with very little energy")),
    "active": dict(
        adjs=("active", "energetic", "lively", "vigorous"),
        advs=("energetically", "vigorously", "actively", "briskly"),
        phrases=("with lots=lot_NOUN of energy", "in an energetic way", "with great vigor"),
        moods=("full of energy", "looking energetic", "bursting with energy"),
    ),
    "musical": dict(
        adjs=("theatrical", "musical_ADJ", "showy"),
        advs=("theatrically", "rhythmically", "musically"),
        phrases=("like a musical_ADJ performer", "as if in a musical_NOUN", "like a performer on stage",
                 "with theatrical flair"),
        moods=("as if on stage", "full of theatrical flair"),
        nouns=("a stage performer", "a musical_ADJ performer"),
    ),
    "giant": dict(
        adjs=("giant_ADJ", "huge", "heavy", "hulking"),
        advs=("heavily", "ponderously", "clumsily"),
        phrases=("like a giant_NOUN", "like a huge giant_NOUN", "as if huge and heavy"),
        moods=("moving like a giant_NOUN", "looking huge and heavy"),
        nouns=("a giant_NOUN", "a huge giant_NOUN"),
    ),
    "chimpira": dict(
        adjs=("cocky", "thuggish", "swaggering=swagger_VERB", "menacing"),
        advs=("cockily", "menacingly"),
        phrases=("with a swagger_NOUN", "like a thug", "like a street=street_NOUN punk", "in a thuggish way",
                 "with a delinquent attitude"),
        moods=("acting tough", "looking like a thug", "looking cocky and menacing"),
        nouns=("a thug", "a street=street_NOUN punk", "a young delinquent"),
    ),
    "youthful": dict(
        adjs=("youthful", "young", "lively", "sprightly"),
        advs=("youthfully", "nimbly"),
        phrases=("in a youthful way", "with youthful energy", "like a young person", "with a youthful bounce"),
        moods=("looking young and lively", "full of youthful energy"),
        nouns=("a young person", "a young man", "a young woman", "a teenager"),
    ),
}
_DATASET1_STYLES = ("normal happy sad angry proud not-confident masculinity feminine childish old tired active "
                    "musical giant chimpira").split()
_DATASET2_STYLES = "active elderly exhausted feminine masculine normal youthful".split()

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


def _datasets(label: str, d1: Sequence[str], d2: Sequence[str]) -> tuple[int, ...]:
    return tuple(i for i, labels in ((1, d1), (2, d2)) if label in labels)


CONTENTS: dict[str, Content] = {}
STYLES: dict[str, Style] = {}


def _register() -> None:
    for left in ("walk-left", "walk-turn-left", "wave-left-hand", "raise-up-left-hand"):
        _PHRASES[left.replace("left", "right")] = tuple(mirror_caption(p) for p in _PHRASES[left])
    for label in dict.fromkeys(_DATASET1_CONTENTS + _DATASET2_CONTENTS):
        datasets = _datasets(label, _DATASET1_CONTENTS, _DATASET2_CONTENTS)
        CONTENTS[label] = Content(label, datasets, _PHRASES[label])
    for label in dict.fromkeys(_DATASET1_STYLES + _DATASET2_STYLES):
        datasets = _datasets(label, _DATASET1_STYLES, _DATASET2_STYLES)
        STYLES[label] = Style(label, datasets, **_STYLE_SPECS[label])


# --------------------------------------------------------------------------------------------- mirroring


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
    _get(CONTENTS, content, "content")
    parts = [{"left": "right", "right": "left"}.get(p, p) for p in content.split("-")]
    return "-".join(parts)


# --------------------------------------------------------------------------------------------- captions


@dataclass(frozen=True)
class Caption:
    """One generated caption: text, HumanML3D tokens and the sentence form used."""

    text: str
    tokens: list[str]
    form: str


# Sentence forms: S subject, AS styled subject, VP "walks forward", VPING "walking forward",
# ADV adverb, PH manner phrase, MOOD descriptive phrase.
_FORMS: dict[str, str] = {
    "adv_end": "S VP ADV",
    "adv_pre": "S ADV VP",
    "adj_simple": "AS VP",
    "adj_prog": "AS is VPING",
    "adj_np": "AS VPING",
    "phrase": "S VP PH",
    "phrase_prog": "S is VPING PH",
    "mood_mid": "S , MOOD , VP",
    "mood_end": "S VP , MOOD",
}
_NOUN_SUBJECTS = (("a", "person"), ("the", "person"), ("a", "man"), ("a", "woman"), ("the", "man"),
                  ("the", "woman"), ("the", "figure"), ("the", "character"))
_PRONOUN_SUBJECTS = (("someone", "their"), ("somebody", "their"), ("he", "his"), ("she", "her"))
_POSSESSIVE = {"man": "his", "woman": "her", "boy": "his", "girl": "her"}


def _get(table: dict, label: str, kind: str):
    try:
        return table[label]
    except KeyError:
        raise SMFError(f"unknown {kind} label {label!r}; known {kind}s: {', '.join(table)}") from None


def _seed(seed: int | str, content: str, style: str) -> int:
    return zlib.crc32(f"{seed}|{content}|{style}".encode())


def _subject(rng: random.Random, style: Style | None, pronoun: bool = True, vp: str = "") -> tuple[str, str]:
    """(annotated noun phrase, possessive); with a style, an adjective or a style noun is used."""
    if style is not None and style.nouns and (not style.adjs or rng.random() < 0.35):
        phrase = rng.choice(style.nouns)
        head = phrase.split()[-1].split("_")[0].split("=")[0]
        return phrase, _POSSESSIVE.get(head, "their")
    if style is None and pronoun and rng.random() < 0.3:
        choices = [p for p in _PRONOUN_SUBJECTS if p[0] not in vp]  # not "someone beckons someone"
        return rng.choice(choices)
    nouns = [dn for dn in _NOUN_SUBJECTS if style is None or dn[1] not in style.avoid]
    det, noun = rng.choice(nouns)
    adj = f" {rng.choice(style.adjs)}" if style is not None and style.adjs else ""
    return f"{det}{adj} {noun}", _POSSESSIVE.get(noun, "their")


def _verb_phrase(template: str, ing: bool, possessive: str) -> str:
    def verb(m: re.Match[str]) -> str:
        lemma, form = m.group(1), m.group(2)
        third, ing_form = _inflect(lemma)
        surface = ing_form if (ing or form == "ing") else third
        return f"{surface}={lemma}_VERB"

    return re.sub(r"<(\w+)(?::(\w+))?>", verb, template.lstrip("!")).replace("{pos}", possessive)


def _render(form: str, content: Content, style: Style, rng: random.Random) -> Caption:
    pattern = _FORMS[form]
    vp = rng.choice([p for p in content.phrases if not (style.low_energy and p.startswith("!"))])
    subj, possessive = _subject(rng, style if "AS" in pattern else None, form != "mood_mid", vp)
    # avoid "waves with one hand with little confidence"
    manner = [p for p in style.phrases if not (p.startswith("with ") and " with " in vp)] or style.phrases
    fill = {
        "S": subj,
        "AS": subj,
        "VP": _verb_phrase(vp, False, possessive),
        "VPING": _verb_phrase(vp, True, possessive),
        "ADV": rng.choice(style.advs) if style.advs else "",
        "PH": rng.choice(manner).replace("{pos}", possessive) if manner else "",
        "MOOD": rng.choice(style.moods).replace("{pos}", possessive) if style.moods else "",
    }
    words = _parse(" ".join(fill.get(piece, piece) for piece in pattern.split()))
    text = " ".join(w.surface for w in words).replace(" ,", ",") + "."
    tokens = [w.token for w in words if w.pos != "PUNCT"]
    return Caption(text, tokens, form)


def generate(content: str, style: str, n: int = 6, seed: int | str = 0) -> list[Caption]:
    """``n`` distinct captions of a clip, cycling through the sentence forms the style allows."""
    c, s = _get(CONTENTS, content, "content"), _get(STYLES, style, "style")
    if n < 0:
        raise SMFError(f"number of captions must be >= 0, got {n}")
    rng = random.Random(_seed(seed, content, style))
    needs = {"ADV": s.advs, "PH": s.phrases, "MOOD": s.moods}
    forms = [f for f, p in _FORMS.items() if all(needs.get(piece, True) for piece in p.split())]
    rng.shuffle(forms)
    out: list[Caption] = []
    seen: set[str] = set()
    for _ in range(200 * max(n, 1)):
        if len(out) == n:
            return out
        cap = _render(forms[len(out) % len(forms)], c, s, rng)
        if cap.text not in seen:
            seen.add(cap.text)
            out.append(cap)
    if len(out) < n:
        raise SMFError(f"could not make {n} distinct captions for {content}/{style}")
    return out


def captions_for(content: str, style: str, n: int = 6, seed: int | str = 0) -> list[tuple[str, list[str]]]:
    """``n`` distinct (caption, ``word/POS`` tokens) pairs for a clip of ``content`` in ``style``.

    Deterministic for a given ``seed`` (an int or a clip id).
    """
    return [(cap.text, cap.tokens) for cap in generate(content, style, n, seed)]


_register()
