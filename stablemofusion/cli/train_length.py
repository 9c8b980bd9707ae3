"""`smf train-length --data DIR --out MODEL_DIR`: the length-from-text estimator, saved beside a model."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name, help="train the length-from-text estimator of a model folder",
                       description="Fit a distribution over motion lengths (4-frame bins) from the frozen sentence "
                                   "embedding on the train split's captions; report its mean absolute error on the "
                                   "test split against the constant train median; write length.safetensors and "
                                   "length.json into --out (a checkpoint or exported model folder).")
    p.add_argument("--data", type=Path, required=True, help="corpus folder (HumanML3D layout) with train/test splits")
    p.add_argument("--out", type=Path, required=True, help="model folder to write the estimator into")
    p.add_argument("--text-cache", type=Path, default=None, help="text embedding cache folder (default OUT/text-cache)")
    p.add_argument("--text-encoder", default=None,
                   help="frozen encoder (default: the --out model's, from its config.json; minilm without one)")
    p.add_argument("--steps", type=int, default=3000, help="optimisation steps (default 3000)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import numpy as np

    from ..errors import SMFError
    from ..data.layout import MotionLayout
    from ..diffusion.checkpoint import CONFIG, read_config
    from ..text.cache import TextEmbeddingCache
    from ..text.length import LengthConfig, caption_lengths, length_errors, sentence_embeddings, train_length_estimator

    if args.steps < 1:
        raise SMFError("--steps must be at least 1")
    if not args.data.is_dir():
        raise SMFError(f"no such corpus folder: {args.data}")
    sk = MotionLayout(args.data).skeleton
    encoder, lo, hi = args.text_encoder or "minilm", sk.min_frames, sk.max_frames
    if (args.out / CONFIG).is_file():  # the model the estimator goes with: its encoder and length range
        model_cfg = read_config(args.out)
        if args.text_encoder not in (None, model_cfg.text_encoder):
            raise SMFError(f"--text-encoder {args.text_encoder} differs from the model's ({model_cfg.text_encoder})")
        if model_cfg.skeleton != sk.name:
            raise SMFError(f"the corpus is on the {sk.name} skeleton, the model in {args.out} on {model_cfg.skeleton}")
        encoder, lo, hi = model_cfg.text_encoder, model_cfg.min_frames, model_cfg.max_frames
    cache = TextEmbeddingCache(args.text_cache or (args.out / "text-cache"), encoder)
    texts, lengths = caption_lengths(args.data, "train")
    emb = sentence_embeddings(texts, cache)
    config = LengthConfig(text_encoder=encoder, in_dim=int(emb.shape[1]), min_frames=lo, max_frames=hi)
    model = train_length_estimator((emb, lengths), config, steps=args.steps, seed=args.seed)
    median = float(np.median(lengths))
    metrics = {"train": length_errors(model, emb, lengths, median), "constant_median_frames": median,
               "fps": sk.fps, "steps": args.steps}
    if (args.data / "test.txt").is_file():
        test_texts, test_lengths = caption_lengths(args.data, "test")
        metrics["test"] = length_errors(model, sentence_embeddings(test_texts, cache), test_lengths, median)
    cache.close()
    if args.text_cache is None:  # the default cache is scratch space inside the model folder
        import shutil

        shutil.rmtree(args.out / "text-cache", ignore_errors=True)
    model.save(args.out, metrics)
    print(json.dumps({"out": str(args.out), **metrics}))
