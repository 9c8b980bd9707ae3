"""Write benchmarks/prompts_heldout_lexicon.jsonl: one caption per (dataset, content, style) made only from
the lexicon's held-out words (never in training captions). Used to choose between model variants, so that
the hand-written free-form dev set (benchmarks/prompts_freeform.jsonl) stays a test set.

    python benchmarks/make_heldout_prompts.py
"""

from __future__ import annotations

import json
from pathlib import Path


def main() -> None:
    from stablemofusion.data.captions import captions_for
    from stablemofusion.data.lexicon import load_lexicon

    lex = load_lexicon("bandai")
    lines = []
    for d, (contents, styles) in sorted(lex.datasets.items()):
        for c in contents:
            if c == "dance-long":  # longer than the model's 9.8 s: not in its training set
                continue
            for s in styles:
                (text, _), = captions_for(c, s, n=1, seed=f"heldout-{d}", heldout=True)
                lines.append({"prompt": text, "content": c, "style": s, "dataset": d})
    out = Path(__file__).with_name("prompts_heldout_lexicon.jsonl")
    out.write_text("".join(json.dumps(x) + "\n" for x in lines))
    print(f"wrote {len(lines)} prompts to {out}")


if __name__ == "__main__":
    main()
