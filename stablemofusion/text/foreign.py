"""Foreign actions: verb phrasings of things the Bandai-Namco corpus has none of, as training negatives for
the out-of-domain detector (:mod:`.domain`).

:func:`foreign_captions` fills the corpus caption grammar (:mod:`stablemofusion.data.captions`: the same
sentence structures, subjects, style words, irrelevant details and typos as the training captions) with
the phrasings of ``assets/lexicons/foreign.txt`` in place of a content's, so that a classifier trained on training captions against them can
only tell the two apart by the action. The phrasings were written for training the detector and avoid the
activities of ``benchmarks/ood_heldout.txt`` and ``benchmarks/ood_calibration.txt`` (the held-out foreign
prompts the detector is calibrated and reported on) and motions the corpus has (walks, kicks, punches,
waves, hailing someone, nodding a bow).
"""

from __future__ import annotations

import functools
import random
import zlib
from importlib import resources

PHRASES_FILE = "foreign.txt"  # in assets/lexicons: one phrasing per line, "#" comments


@functools.cache
def foreign_phrases() -> tuple[str, ...]:
    """The foreign phrasings (``assets/lexicons/foreign.txt``), in file order."""
    text = (resources.files("stablemofusion") / "assets" / "lexicons" / PHRASES_FILE).read_text(encoding="utf-8")
    return tuple(x.strip() for x in text.splitlines() if x.strip() and not x.lstrip().startswith("#"))


def foreign_lexicon(lexicon: str = "bandai"):
    """The corpus lexicon with :func:`foreign_phrases` as its only content (``foreign``), the styles kept."""
    import dataclasses

    from ..data.lexicon import Words, load_lexicon

    lex = load_lexicon(lexicon)
    return dataclasses.replace(lex, contents={"foreign": Words(foreign_phrases())})


def foreign_captions(per_phrase: int = 24, seed: int = 0, lexicon: str = "bandai") -> list[str]:
    """``per_phrase`` distinct captions per foreign phrasing, in the training captions' grammar and styles
    (training words only), deterministic for ``seed``."""
    import dataclasses

    from ..data.augment import augment_caption
    from ..data.captions import NOISE, STRUCTURES, _fill, structures_for
    from ..data.lexicon import Words

    lex = foreign_lexicon(lexicon)
    styles = sorted(lex.styles)
    out: list[str] = []
    for phrase in foreign_phrases():
        one = dataclasses.replace(lex, contents={"foreign": Words((phrase,))})
        rng = random.Random(zlib.crc32(f"{seed}|{phrase}".encode()))
        seen: set[str] = set()
        for _ in range(20 * per_phrase):
            if len(seen) == per_phrase:
                break
            style = rng.choice(styles)
            form = rng.choice(structures_for(one, style))
            text = augment_caption(_fill(STRUCTURES[form], one, "foreign", style, rng, False), rng, None, NOISE)
            if text.lower() not in seen:
                seen.add(text.lower())
                out.append(text)
    return out


__all__ = ["foreign_captions", "foreign_lexicon", "foreign_phrases"]
