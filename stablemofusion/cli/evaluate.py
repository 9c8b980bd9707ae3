"""`smf evaluate --checkpoint DIR --data DIR --evaluator DIR [--quick] ...`: the T2M protocol -> markdown + JSON."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

def add_eval_args(p: argparse.ArgumentParser) -> None:
    """Arguments shared by `smf evaluate` and `smf ablate`."""
    from ..core.limits import SAMPLER, STEPS, STUDENT_SAMPLER

    p.add_argument("--data", type=Path, required=True, help="corpus folder (HumanML3D layout) with a test split")
    p.add_argument("--evaluator", type=Path, default=None, help="evaluator folder from `smf train-evaluator`")
    p.add_argument("--t2m-evaluator", type=Path, default=None,
                   help="root of the original T2M evaluator files (instead of --evaluator); needs --glove")
    p.add_argument("--glove", type=Path, default=None, help="GloVe folder of the original T2M evaluator")
    p.add_argument("--sampler", default=None, help=f"sampler (default: the model's: {SAMPLER}, a distilled student "
                                                   f"{STUDENT_SAMPLER})")
    p.add_argument("--steps", type=int, default=None,
                   help=f"sampling steps (default: the model's: {STEPS}, a distilled student its own count)")
    p.add_argument("--guidance", type=float, default=None,
                   help="classifier-free guidance scale (default: the model's, as `smf generate`)")
    p.add_argument("--replications", type=int, default=None, help="repetitions of the protocol (default 20, --quick 3)")
    p.add_argument("--quick", action="store_true", help="3 replications, 12 samples per multimodality caption")
    p.add_argument("--max-items", type=int, default=None, help="test items per replication (default all)")
    p.add_argument("--mm-captions", type=int, default=None, help="captions for multimodality (default 100; 0 = skip)")
    p.add_argument("--rprecision-batch", type=int, default=32, help="R-precision batch (protocol: 32)")
    p.add_argument("--diversity-times", type=int, default=300, help="diversity pairs (protocol: 300)")
    p.add_argument("--footskate", default="off", choices=("off", "post", "loop"), help="footskate cleanup mode")
    p.add_argument("--rigid", default="dataset", choices=("dataset", "median", "off"),
                   help="rigid final stage: bone lengths of the dataset skeleton (default) or the motion's median; "
                        "off = the model's raw motion (to measure what the stage changes)")
    p.add_argument("--rigid-rotations", default="keep", choices=("keep", "ik"),
                   help="rotation channels of the final features: the model's own (default) or inverse kinematics "
                        "of the rigid body")
    p.add_argument("--split", default="test", help="split to evaluate on (default test; tune settings on val)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda if available)")
    p.add_argument("--no-progress", action="store_true")


def add_parser(sub, name: str) -> None:
    from .flags import add_teacher_flag

    p = sub.add_parser(name,
                       description="FID, R-precision top-1/2/3, matching distance, diversity, multimodality over "
                                   "N replications (mean ± 95% interval), average inference time per sentence.")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="checkpoint or run folder (default: the shipped model; 'none' = real motion only)")
    add_teacher_flag(p)
    add_eval_args(p)
    p.add_argument("--classifier", type=Path, default=None,
                   help="motion classifier folder (`smf train-classifier`): adds label accuracy of the test captions' "
                        "motions, and of --prompts")
    p.add_argument("--prompts", type=Path, default=None,
                   help="JSON-lines prompt file with labels (e.g. benchmarks/prompts_freeform.jsonl): label accuracy "
                        "of generated motions; needs --classifier")
    p.add_argument("--prompt-samples", type=int, default=3, help="motions per prompt of --prompts (default 3)")
    p.add_argument("--prompt-seconds", default="4", help="length of the --prompts motions in seconds, or auto: the "
                                                          "length the model predicts from the prompt, as `smf generate` "
                                                          "does by default (default 4)")
    p.add_argument("--prompts-only", action="store_true", help="only the --prompts accuracy, not the T2M protocol")
    p.add_argument("--out", type=Path, default=None, help="JSON results file (a .md table is written beside it)")
    p.set_defaults(func=run)


def eval_config(args: argparse.Namespace, **kw):
    from ..core.errors import SMFError
    from ..eval.protocol import EvalConfig

    base = EvalConfig.quick() if args.quick else EvalConfig()
    over = {"sampler": args.sampler, "steps": args.steps, "guidance_scale": args.guidance,
            "footskate": args.footskate, "seed": args.seed, "max_items": args.max_items,
            "batch_size": args.rprecision_batch, "diversity_times": args.diversity_times, "split": args.split}
    if args.replications is not None:
        over["replications"] = args.replications
    if args.mm_captions is not None:
        over["mm_captions"] = args.mm_captions
    over.update(kw)
    cfg = EvalConfig(**{**base.__dict__, **over})
    if cfg.replications < 1:
        raise SMFError(f"--replications must be >= 1, got {cfg.replications}")
    if cfg.batch_size < 2 or cfg.diversity_times < 1:
        raise SMFError("--rprecision-batch must be >= 2 and --diversity-times >= 1")
    if cfg.steps is not None and cfg.steps < 1:
        raise SMFError(f"--steps must be >= 1, got {cfg.steps}")
    if cfg.max_items is not None and cfg.max_items < cfg.batch_size:
        raise SMFError(f"--max-items must be at least one batch ({cfg.batch_size})")
    return cfg


def load_embedder(args: argparse.Namespace, pipe=None):
    """Our evaluator (sharing the pipeline's text cache when both use the same language model) or the
    original T2M one, from the CLI arguments."""
    from ..core.errors import SMFError
    from ..eval.protocol import EmbeddingModel, T2MEmbedding

    if args.t2m_evaluator is not None:
        if args.glove is None:
            raise SMFError("--t2m-evaluator needs --glove DIR (the GloVe files our_vab_*.npy/pkl)")
        from ..eval.t2m_original import T2MOriginalEvaluator

        return T2MEmbedding(T2MOriginalEvaluator.from_files(args.t2m_evaluator, args.glove), None)
    if args.evaluator is None:
        raise SMFError("give --evaluator DIR (from `smf train-evaluator`) or --t2m-evaluator DIR --glove DIR")
    from ..eval.evaluator import load_evaluator
    from ..text.cache import LRUTextCache
    from ..text.frozen import load_text_encoder

    model, config = load_evaluator(args.evaluator)
    name = config.get("text_encoder", "minilm")
    if pipe is not None and pipe.text_encoder_name == name:
        return EmbeddingModel(model, pipe.text_cache)
    return EmbeddingModel(model, LRUTextCache(load_text_encoder(name), maxsize=100_000))


def skate_fn(skeleton):
    """List of joints (n, J, 3) -> mean footskate metrics at the skeleton's frame rate."""
    from ..footskate.metrics import mean_metrics

    return lambda joints: mean_metrics(joints, skeleton.fps)


def label_fn(classifier: Path, data: Path):
    """(motion ids, features) -> label accuracy per dataset of the corpus, each motion judged by its own labels."""
    from ..eval.classifier import corpus_labels, dataset_labels, label_accuracy, load_classifier

    model, labels = load_classifier(classifier), corpus_labels(data)
    by_dataset = {d: dataset_labels(labels, d) for d in {v.dataset for v in labels.values()}}

    def metrics(ids: list[str], feats: list) -> dict[str, float]:
        pred = model.predict(feats, [by_dataset[labels[i].dataset] for i in ids])
        out = {}
        for d in sorted({labels[i].dataset for i in ids}):
            sel = [k for k, i in enumerate(ids) if labels[i].dataset == d]
            acc = label_accuracy([pred[k] for k in sel], [((labels[ids[k]].content,), (labels[ids[k]].style,))
                                                          for k in sel])
            out[f"content_acc_d{d}"], out[f"style_acc_d{d}"] = acc["content_acc"], acc["style_acc"]
        return out

    return metrics


def rigid_config(args: argparse.Namespace):
    """The pipeline's rigid stage from --rigid/--rigid-rotations (None for 'off')."""
    from ..motion.rigid import RigidFitConfig

    return None if args.rigid == "off" else RigidFitConfig(bone_lengths=args.rigid, rotations=args.rigid_rotations)


def write_results(result: dict, out: Path | None, title: str) -> str:
    from ..eval.protocol import markdown_table
    from ..core.io import write_text

    from ..eval.prompts import format_prompt_accuracy

    text = f"## {title}\n\n"
    if "rows" in result:
        extra = [f"items per replication: {result['items_per_replication']}, replications: "
                 f"{result['config']['replications']}"]
        if "aits_seconds" in result:
            extra.append(f"AITS: {result['aits_seconds'] * 1000:.1f} ms per sentence")
        text += f"{markdown_table(result)}\n\n" + "; ".join(extra) + "\n"
    if "prompts" in result:
        text += f"\nPrompt following ({result['prompts']['file']}):\n\n{format_prompt_accuracy(result['prompts'])}\n"
    if out is not None:
        write_text(out, json.dumps(result, indent=2, default=float) + "\n")
        write_text(out.with_suffix(".md"), text)
    return text


def run(args: argparse.Namespace) -> None:
    from ..core.errors import SMFError
    from ..eval.protocol import evaluate
    from ..pipelines.motion_pipeline import MotionPipeline

    if not args.data.is_dir():
        raise SMFError(f"no such corpus folder: {args.data}")
    cfg = eval_config(args)
    real_only = args.checkpoint is not None and str(args.checkpoint).lower() == "none"
    if real_only and args.teacher:
        raise SMFError("--teacher needs a model: not with --checkpoint none")
    pipe = None if real_only else MotionPipeline.from_pretrained(args.checkpoint, backend="torch", teacher=args.teacher,
                                                                 device=args.device, rigid=rigid_config(args))
    if pipe is not None:
        cfg = cfg.for_pipeline(pipe)  # the model's guidance, steps and sampler where the flags leave them
    from ..motion.skeleton import get_skeleton

    sk = pipe.skeleton if pipe else get_skeleton("humanml3d")
    name = "real motion only" if real_only else str(args.checkpoint or "the shipped default model")
    name += " (its teacher)" if args.teacher else ""
    prompt_result = None
    if args.prompts is not None:
        if args.classifier is None or pipe is None:
            raise SMFError("--prompts needs --classifier DIR and a checkpoint")
        try:
            seconds = None if args.prompt_seconds == "auto" else float(args.prompt_seconds)
        except ValueError:
            seconds = -1.0
        if args.prompt_samples < 1 or not (seconds is None or seconds > 0):
            raise SMFError("--prompt-samples must be >= 1 and --prompt-seconds positive or auto")
        from ..eval.classifier import corpus_labels, load_classifier
        from ..eval.prompts import load_prompts, prompt_accuracy

        prompt_result = prompt_accuracy(pipe, load_classifier(args.classifier), load_prompts(args.prompts),
                                        corpus_labels(args.data), samples=args.prompt_samples,
                                        seconds=seconds, seed=args.seed, guidance_scale=cfg.guidance_scale,
                                        steps=cfg.steps, sampler=cfg.sampler, footskate=cfg.footskate)
        prompt_result["file"] = str(args.prompts)
    if args.prompts_only:
        if prompt_result is None:
            raise SMFError("--prompts-only needs --prompts FILE")
        result = {"checkpoint": name, "prompts": prompt_result,
                  "sampling": {"guidance_scale": cfg.guidance_scale, "steps": cfg.steps, "sampler": cfg.sampler,
                               "footskate": cfg.footskate}}
    else:
        embedder = load_embedder(args, pipe)
        result = evaluate(pipe, embedder, args.data, cfg, progress=not args.no_progress, skate_metrics=skate_fn(sk),
                          body=True, label_metrics=label_fn(args.classifier, args.data) if args.classifier else None)
        result["checkpoint"] = name
        if prompt_result is not None:
            result["prompts"] = prompt_result
    print(write_results(result, args.out, f"Evaluation of {name}"))
