"""`smf train-length --data DIR --out MODEL_DIR`: the length-from-text estimator, saved beside a model."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..text.length import INPUTS


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Fit a distribution over motion lengths (4-frame bins) from each train-split "
                                   "caption (read through --inputs); report its mean absolute error on the test split "
                                   "against the constant train median; write length.safetensors and length.json into "
                                   "--out (a checkpoint or exported model folder).")
    p.add_argument("--data", type=Path, required=True, help="corpus folder (HumanML3D layout) with train/test splits")
    p.add_argument("--out", type=Path, required=True, help="model folder to write the estimator into")
    p.add_argument("--text-cache", type=Path, default=None, help="text embedding cache folder (default OUT/text-cache)")
    p.add_argument("--text-encoder", default=None,
                   help="frozen encoder (default: the --out model's, from its config.json; minilm without one)")
    p.add_argument("--inputs", choices=INPUTS, default="sentence",
                   help="what the estimator reads of a caption: sentence (default, the shipped estimator's) the frozen "
                        "encoder's sentence embedding; text the pooled tokens of a frozen copy of the --out model's "
                        "text transformer (kept inside the estimator); both the two side by side "
                        "(docs/inference.md#length-from-text compares them)")
    p.add_argument("--steps", type=int, default=3000, help="optimisation steps (default 3000)")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    import numpy as np

    from ..core.errors import SMFError
    from ..data.layout import MotionLayout
    from ..diffusion.checkpoint import CONFIG, load_checkpoint, read_config
    from ..text.cache import TextEmbeddingCache
    from ..text.length import (TEXT_DIMS, LengthConfig, LengthEstimator, caption_features, caption_lengths,
                               length_errors, train_length_estimator)

    if args.steps < 1:
        raise SMFError("--steps must be at least 1")
    if not args.data.is_dir():
        raise SMFError(f"no such corpus folder: {args.data}")
    sk = MotionLayout(args.data).skeleton
    encoder, lo, hi = args.text_encoder or "minilm", sk.min_frames, sk.max_frames
    has_model = (args.out / CONFIG).is_file()
    if args.inputs != "sentence" and not has_model:
        raise SMFError(f"--inputs {args.inputs} reads the text transformer of the model in --out, and {args.out} "
                       f"holds none (no {CONFIG}); give a model folder or --inputs sentence")
    if has_model:  # the model the estimator goes with: its encoder and length range
        model_cfg = read_config(args.out)
        if args.text_encoder not in (None, model_cfg.text_encoder):
            raise SMFError(f"--text-encoder {args.text_encoder} differs from the model's ({model_cfg.text_encoder})")
        if model_cfg.skeleton != sk.name:
            raise SMFError(f"the corpus is on the {sk.name} skeleton, the model in {args.out} on {model_cfg.skeleton}")
        encoder, lo, hi = model_cfg.text_encoder, model_cfg.min_frames, model_cfg.max_frames
    cache = TextEmbeddingCache(args.text_cache or (args.out / "text-cache"), encoder)
    texts, lengths = caption_lengths(args.data, "train")
    width = int(cache.get_or_compute(texts[:1], device="cpu")[0].shape[-1])  # the frozen encoder's
    if args.inputs == "sentence":
        model = LengthEstimator(LengthConfig(text_encoder=encoder, in_dim=width, min_frames=lo, max_frames=hi))
    else:
        dims = {k: getattr(model_cfg.model.text, k) for k in TEXT_DIMS}
        in_dim = dims["latent"] + (width if args.inputs == "both" else 0)
        model = LengthEstimator(LengthConfig(text_encoder=encoder, in_dim=in_dim, min_frames=lo, max_frames=hi,
                                             inputs=args.inputs, text=dims))
        model.copy_text(load_checkpoint(args.out).model.text)
    emb = caption_features(model, texts, cache)
    model = train_length_estimator(model, (emb, lengths), steps=args.steps, seed=args.seed)
    median = float(np.median(lengths))
    metrics = {"train": length_errors(model, emb, lengths, median), "constant_median_frames": median,
               "fps": sk.fps, "steps": args.steps}
    if (args.data / "test.txt").is_file():
        test_texts, test_lengths = caption_lengths(args.data, "test")
        metrics["test"] = length_errors(model, caption_features(model, test_texts, cache), test_lengths, median)
    cache.close()
    if args.text_cache is None:  # the default cache is scratch space inside the model folder
        import shutil

        shutil.rmtree(args.out / "text-cache", ignore_errors=True)
    model.save(args.out, metrics)
    print(json.dumps({"out": str(args.out), **metrics}))
