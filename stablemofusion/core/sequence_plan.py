"""Prompts that ask for one thing after another ("a tired man walks in a circle then waves"): split at their
sequence words into the parts of a timeline, each part with the subject of the first, each part's length its own.

The model was trained on one action per caption: given "walks in a circle then waves" whole it draws the walk and
drops the wave. Split, each part is a segment of a timeline (:mod:`~stablemofusion.core.timeline_plan`), generated
after the one before it and continuing it; path words apply to their own part.
"""

from __future__ import annotations

import re

# sequence words, with the commas and "and" around them; "A before B-ing" is A, then B ("bows before the audience"
# is one action)
SEQUENCE = re.compile(r"\s*,?\s*\b(?:and\s+then|and\s+after\s+that|after\s+that|and\s+afterwards|afterwards|then|"
                      r"and\s+finally|finally|before(?=\s+\w+ing\b))\b\s*,?\s*", re.IGNORECASE)
SUBJECT = re.compile(r"^\s*(?:(?:a|an|the|this|that|some|one)\s+(?:[\w'-]+\s+){0,3}?(?:person|man|woman|boy|girl|guy|"
                     r"lady|gentleman|figure|character|human|child|kid|teenager|dancer|runner|athlete|soldier|player|"
                     r"someone|somebody|people|adult|elder|worker)|someone|somebody|he|she|they|it|i|you)\b",
                     re.IGNORECASE)
PRONOUN = re.compile(r"^\s*(?:he|she|they|it)\b\s*", re.IGNORECASE)
LEADING = re.compile(r"^(?:and|to)\s+", re.IGNORECASE)  # words a later part drops ("..., and then to wave")
DEFAULT_SUBJECT = "a person"  # the subject of the later parts when the first has none
MAX_PARTS = 8  # parts of one prompt at most; a prompt of more sequence words is left whole
# a prompt of sequence words this close (cosine similarity) to one of the model's example sentences is that one
# action ("a person walks forward then turns left" is a caption of the corpus's walk-turn-left), not split
ONE_ACTION_SIMILARITY = 0.95


def split_sequence(prompt: str) -> list[str]:
    """The parts of a prompt that asks for one thing after another, in order (one part: the prompt as it is). A part
    without a subject takes the first part's ("a man bows, then runs" -> ["a man bows", "a man runs"]); a
    pronoun is replaced by it. Empty parts are dropped."""
    parts = [p.strip(" ,;.") for p in SEQUENCE.split(prompt)]
    parts = [p for p in parts if p]
    if len(parts) < 2 or len(parts) > MAX_PARTS:
        return [prompt]
    found = SUBJECT.match(parts[0])
    subject = found.group(0).strip() if found and not PRONOUN.match(found.group(0)) else DEFAULT_SUBJECT
    out = [parts[0]]
    for p in parts[1:]:
        p = LEADING.sub("", p, count=1)
        if PRONOUN.match(p):
            p = PRONOUN.sub(subject + " ", p, count=1)
        elif not SUBJECT.match(p):
            p = f"{subject} {p}"
        out.append(p)
    return out


def share_seconds(total: float, own: list[float], minimum: float = 0.0) -> list[float]:
    """``total`` seconds shared among parts in proportion to their ``own`` lengths, each at least ``minimum`` where
    ``total`` allows it (the parts that would fall short get ``minimum``, the others share the rest)."""
    short: set[int] = set()
    while True:
        free = [k for k in range(len(own)) if k not in short]
        rest = total - minimum * len(short)
        whole = sum(own[k] for k in free)
        out = [minimum if k in short else rest * own[k] / whole for k in range(len(own))]
        under = {k for k in free if out[k] < minimum}
        if not under or total < minimum * len(own):
            return out if total >= minimum * len(own) else [total * s / sum(own) for s in own]
        short |= under


def spread_seconds(seconds: float, at: float, median: float, fps: float, shortest: int, longest: int,
                   multiple: int) -> float:
    """A length from path words for one seed (s): ``seconds`` (the words' kind's) times the length model's length
    for the seed over its median for the same prompt (``at``, ``median``, s), so that seeds spread as the model
    spreads the prompt's lengths; whole multiples of ``multiple`` frames at ``fps``, from ``shortest`` to
    ``longest`` frames (rounded inward to multiples)."""
    frames = round(seconds * at / median * fps / multiple) * multiple
    return min(max(frames, -(-shortest // multiple) * multiple), longest // multiple * multiple) / fps


def sequence_lexicon() -> dict:
    """What the JavaScript runtime needs to split a prompt as :func:`split_sequence` does (the page's and Node.js's
    ``splitSequence``): the patterns (JavaScript reads them with the ``i`` flag), the default subject, the most
    parts, the similarity to an example sentence that keeps a prompt whole."""
    return {"words": SEQUENCE.pattern, "subject": SUBJECT.pattern, "pronoun": PRONOUN.pattern,
            "leading": LEADING.pattern, "default_subject": DEFAULT_SUBJECT, "max_parts": MAX_PARTS,
            "one_action_similarity": ONE_ACTION_SIMILARITY}


__all__ = ["DEFAULT_SUBJECT", "MAX_PARTS", "ONE_ACTION_SIMILARITY", "split_sequence", "share_seconds", "spread_seconds",
           "sequence_lexicon"]
