"""Calibrate the out-of-domain threshold of ``actions.json`` (smf export --lexicon).

In domain: the lexicon's held-out phrasings as sentences ("a person ambles along"), which the example
sentences do not contain. Out of domain: benchmarks/ood_calibration.txt. Prints both similarity
distributions and the threshold with the best balanced accuracy. The free-form dev set is not used here.

    python benchmarks/ood_threshold.py [--lexicon bandai]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def main() -> None:
    from stablemofusion.data.lexicon import known_actions, load_lexicon, person_sentence
    from stablemofusion.text.cache import LRUTextCache
    from stablemofusion.text.frozen import load_text_encoder
    from stablemofusion.text.known import KnownActions

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lexicon", default="bandai")
    args = ap.parse_args()
    lex = load_lexicon(args.lexicon)
    cache = LRUTextCache(load_text_encoder("minilm"), maxsize=10_000)
    known = KnownActions(known_actions(lex, 0.0)["actions"], 0.0, cache)
    inside = [person_sentence(p) for w in lex.contents.values() for p in w.heldout]
    path = Path(__file__).with_name("ood_calibration.txt")
    outside = [line.strip() for line in path.read_text().splitlines() if line.strip() and not line.startswith("#")]
    s_in = np.array([d.similarity for d in known.check_many(inside)])
    s_out = np.array([d.similarity for d in known.check_many(outside)])
    for name, s in (("in domain (held-out phrasings)", s_in), ("out of domain (calibration)", s_out)):
        q = np.percentile(s, [0, 5, 25, 50, 75, 95, 100])
        print(f"{name}: n={len(s)} percentiles 0/5/25/50/75/95/100: " + " ".join(f"{v:.3f}" for v in q))
    grid = np.round(np.arange(0.2, 0.8, 0.01), 2)
    bal = [(np.mean(s_in >= t) + np.mean(s_out < t)) / 2 for t in grid]
    best = grid[int(np.argmax(bal))]
    # a false warning on a prompt the model can do costs more than a missed one: keep 95% of in-domain prompts
    keep95 = float(np.floor(np.percentile(s_in, 5) * 100) / 100)
    for name, t in (("best balanced accuracy", best), ("keeps 95% of in-domain (chosen)", keep95)):
        print(f"{name}: threshold {t:.2f}: in-domain kept {np.mean(s_in >= t):.1%}, "
              f"out-of-domain flagged {np.mean(s_out < t):.1%}")


if __name__ == "__main__":
    main()
