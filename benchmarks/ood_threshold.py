"""The out-of-domain detector (stablemofusion.text.domain): train it, calibrate it and report it on held-out
data; optionally write it into a model folder and report the free-form dev set last.

Trained on the corpus's train-split captions (in domain) against foreign captions (stablemofusion.text.foreign,
assets/lexicons/foreign.txt). Calibrated (threshold) on free-form in-domain prompts written for it
(assets/lexicons/bandai-calibration.txt, text.domain.calibration_inside). Reported on held-out data neither saw
in training:
  in domain: the calibration prompts, benchmarks/prompts_heldout_lexicon.jsonl, the held-out phrasings
             ("a person ambles along"), captions of held-out words (hard on purpose: obscure held-out verbs);
  out of domain: benchmarks/ood_heldout.txt, benchmarks/ood_calibration.txt.
Alternatives at the same flag rate: the closest action sentence (the previous check) and nearest neighbours
(mean cosine of the 5 closest training captions). The dev set (--dev) is reported once, at the end, and never
used to choose anything.

    OMP_NUM_THREADS=1 python benchmarks/ood_threshold.py [--corpus ~/.cache/smf/bandai-corpus]
        [--text-cache ~/.cache/smf/text-cache] [--write stablemofusion/assets/default_model] [--dev]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).parent


def lines(name: str) -> list[str]:
    return [x.strip() for x in (HERE / name).read_text().splitlines() if x.strip() and not x.startswith("#")]


def main() -> None:
    from stablemofusion.cli.export import ABOUT, build_known_actions
    from stablemofusion.data.lexicon import load_lexicon, person_sentence
    from stablemofusion.text.domain import FLAG_RATE, calibration_inside, embed_texts, heldout_inside

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lexicon", default="bandai")
    ap.add_argument("--corpus", type=Path, default=Path.home() / ".cache/smf/bandai-corpus")
    ap.add_argument("--text-cache", type=Path, default=None)
    ap.add_argument("--write", type=Path, default=None, help="model folder to write actions.json + ood.safetensors into")
    ap.add_argument("--dev", action="store_true", help="report the free-form dev set at the end")
    ap.add_argument("--no-alternatives", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(1)

    t0 = time.perf_counter()
    known = build_known_actions(args.lexicon, "minilm", corpus=args.corpus if args.corpus.is_dir() else None,
                                text_cache=args.text_cache)
    print(f"trained and calibrated in {time.perf_counter() - t0:.0f} s; offset {known.detector.offset:.3f} "
          f"scale {known.detector.scale:.3f} (flag rate {FLAG_RATE:.0%} of the calibration prompts)")
    cache = known.text_cache
    lex = load_lexicon(args.lexicon)
    rows = [json.loads(x) for x in (HERE / "prompts_heldout_lexicon.jsonl").read_text().splitlines() if x.strip()]
    hard = heldout_inside(args.lexicon)
    calib = calibration_inside(args.lexicon)
    phrasings = [person_sentence(p) for w in lex.contents.values() for p in w.heldout]
    sets = {"cal: calibration prompts (free-form)": calib,
            "in: prompts_heldout_lexicon.jsonl": [r["prompt"] for r in rows],
            "in: held-out phrasings": phrasings,
            "in: held-out-word captions": hard[len(phrasings):],
            "out: ood_heldout.txt": lines("ood_heldout.txt"),
            "out: ood_calibration.txt": lines("ood_calibration.txt")}
    emb = {k: embed_texts(v, cache) for k, v in sets.items()}
    calib_emb = embed_texts(calib, cache)

    methods = {"detector (MLP on the sentence embedding)": lambda e: known.detector.logits(e).numpy()}
    if not args.no_alternatives:
        from stablemofusion.text.domain import corpus_captions, lexicon_captions
        caps = corpus_captions(args.corpus) if args.corpus.is_dir() else lexicon_captions(args.lexicon)
        train = embed_texts(caps, cache)
        methods["closest action sentence (previous)"] = lambda e: known._similarities(e).max(1).values.numpy()
        methods["nearest neighbours (top-5 training captions)"] = (
            lambda e: torch.cat([(e[a:a + 256] @ train.T).topk(5, dim=1).values.mean(1)
                                 for a in range(0, len(e), 256)]).numpy())
    thresholds = {}
    print(f"\nheld-out figures: share flagged, each method's threshold flagging {FLAG_RATE:.0%} of the "
          "calibration prompts")
    for name, score in methods.items():
        t = float(np.quantile(score(calib_emb), FLAG_RATE))
        thresholds[name] = t
        s = {k: score(e) for k, e in emb.items()}
        s_in = np.concatenate([v for k, v in s.items() if k.startswith("in")])
        s_out = np.concatenate([v for k, v in s.items() if k.startswith("out")])
        auc = float((s_in[:, None] > s_out[None, :]).mean())
        print(f"  {name}: AUC {auc:.3f}; in domain flagged {np.mean(s_in < t):.1%}, out of domain flagged "
              f"{np.mean(s_out < t):.1%}")
        for k, v in s.items():
            print(f"      {k:38s} n={len(v):4d} flagged {np.mean(v < t):6.1%}")

    if args.write is not None:
        path = known.save(args.write, about=ABOUT)
        size = sum((args.write / n).stat().st_size for n in ("actions.json", "ood.safetensors"))
        print(f"\nwrote {path} and {args.write / 'ood.safetensors'} ({size / 1e3:.0f} kB)")

    if args.dev:
        dev = [json.loads(x) for x in (HERE / "prompts_freeform.jsonl").read_text().splitlines() if x.strip()]
        inside = [r["prompt"] for r in dev if r.get("content")]
        outside = [r["prompt"] for r in dev if not r.get("content")]
        print("\nfree-form dev set (reported once, not used to choose anything):")
        for name, score in methods.items():
            t = thresholds[name]
            fi, fo = score(embed_texts(inside, cache)) < t, score(embed_texts(outside, cache)) < t
            print(f"  {name}: in domain flagged {fi.sum()}/{len(inside)} ({fi.mean():.1%}), "
                  f"out of domain flagged {fo.sum()}/{len(outside)} ({fo.mean():.1%})")
        checks = known.check_many(inside + outside)
        fi = sum(c.out_of_domain for c in checks[:len(inside)])
        fo = sum(c.out_of_domain for c in checks[len(inside):])
        print(f"  shipped check (KnownActions.check): in domain flagged {fi}/{len(inside)} ({fi / len(inside):.1%}), "
              f"out of domain flagged {fo}/{len(outside)} ({fo / len(outside):.1%}); bars: <= 5%, >= 90%")


if __name__ == "__main__":
    main()
