"""`smf export --checkpoint RUN --out DIR [--card MODEL_CARD.md] [--teacher-folder TEACHER] [--text-side MODEL]
[--guidance G]`: a small release folder (EMA weights, fp16); a distilled student's with its teacher inside; its
default guidance scale (docs/models.md). `smf export --onnx --checkpoint MODEL --out DIR`: the model's portable
graphs (docs/runtime.md). `smf export --final-stage --out DIR`: the final stage's graphs (the package ships them in
stablemofusion/assets/final_stage/; docs/game-engines.md)."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_parser(sub, name: str) -> None:
    p = sub.add_parser(name,
                       description="Export a checkpoint for shipping: EMA weights only, float16 by default.")
    p.add_argument("--checkpoint", type=Path, default=None, help="checkpoint or training run folder (required but "
                   "with --final-stage)")
    p.add_argument("--out", type=Path, required=True, help="release folder to write (replaced atomically)")
    p.add_argument("--card", type=Path, default=None, help="model card (markdown) copied in as MODEL_CARD.md")
    p.add_argument("--dtype", default="float16", choices=("float16", "bfloat16", "float32"))
    p.add_argument("--teacher-folder", type=Path, default=None, metavar="TEACHER",
                   help="for a distilled student: its teacher (checkpoint, run or exported folder), exported too into "
                        "OUT/teacher/, which the student's config then names (`--teacher` of generate, edit, serve, ...)")
    p.add_argument("--guidance", type=float, default=None,
                   help="the guidance scale the model samples with by default, recorded in its config (default: the "
                        "checkpoint's, else the package's); choose it on held-out data (docs/models.md)")
    p.add_argument("--text-side", type=Path, default=None, metavar="MODEL",
                   help="copy the length estimator, known actions and out-of-domain detector of this model folder "
                        "(default: the checkpoint's own, if it has them)")
    p.add_argument("--lexicon", default=None,
                   help="corpus lexicon (e.g. bandai) whose actions the model knows: writes actions.json and the "
                        "out-of-domain detector ood.safetensors, so prompts unlike the training captions get a warning")
    p.add_argument("--corpus", type=Path, default=None,
                   help="corpus folder whose train-split captions the detector learns as in domain (default: captions "
                        "made from the lexicon's grammar, as the corpus's are)")
    p.add_argument("--text-cache", type=Path, default=None,
                   help="text embedding cache folder of the training run, read (never written) to skip encoding")
    p.add_argument("--ood-flag-rate", type=float, default=None,
                   help="share of held-out in-domain prompts the detector's threshold flags (default: the calibrated "
                        "FLAG_RATE of stablemofusion.text.domain)")
    p.add_argument("--onnx", action="store_true",
                   help="instead: write the portable graphs (ONNX, docs/runtime.md) of the model folder --checkpoint "
                        "(and its teacher) into --out, for the torch-free runtime (`--engine onnx`)")
    p.add_argument("--adapter", type=Path, action="append", default=None,
                   help="with --onnx: an adapter file from `smf adapt`, merged into the graphs' weights (repeat it to "
                        "merge several): the adapted model for the runtime, the browser page and Blender")
    p.add_argument("--final-stage", action="store_true",
                   help="instead: write the final stage's graphs (bend, follow, rigid, contacts, cleanup, pose .onnx: "
                        "the Python's functions, float64) into --out; any model's, needs no checkpoint")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    from ..core.errors import SMFError

    if args.final_stage:
        from ..backends.onnx_export import export_final_stage

        for path in export_final_stage(args.out):
            print(f"wrote {path} ({path.stat().st_size / 1e6:.2f} MB)")
        return
    if args.checkpoint is None:
        raise SMFError("--checkpoint is required (but with --final-stage)")
    if args.onnx:
        from .options import check_adapter_flags

        check_adapter_flags(args, teacher_part=True)  # before PyTorch is imported
        from ..backends.onnx_export import export_onnx

        out = export_onnx(args.checkpoint, args.out, adapters=args.adapter,
                          text_encoder_from=_text_encoder_graphs(args.checkpoint) if args.adapter else None)
        size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
        print(f"exported the graphs of {args.checkpoint} -> {out} ({size / 1e6:.1f} MB)")
        return
    import torch

    from ..diffusion.checkpoint import export_checkpoint

    if args.adapter:
        raise SMFError("--adapter goes with --onnx (the graphs of the adapted model); elsewhere load adapters with "
                       "--adapter at generate, edit and serve")

    extra = {}
    if args.card is not None:
        if not args.card.is_file():
            raise SMFError(f"no such model card: {args.card}")
        extra["MODEL_CARD.md"] = args.card.read_text(encoding="utf-8")
    copies = text_side_files(args.text_side if args.text_side is not None else args.checkpoint,
                             required=args.text_side is not None)
    known = None
    if args.lexicon is not None:  # built first: a failure leaves no half-written release
        from ..diffusion.checkpoint import load_checkpoint
        from ..text import ACTIONS_FILE, DETECTOR_FILE, EMBEDDINGS_FILE

        copies = {n: f for n, f in copies.items() if n not in (ACTIONS_FILE, EMBEDDINGS_FILE, DETECTOR_FILE)}
        known = build_known_actions(args.lexicon, load_checkpoint(args.checkpoint).config.text_encoder,
                                    corpus=args.corpus, text_cache=args.text_cache, flag_rate=args.ood_flag_rate)
    out = export_checkpoint(args.checkpoint, args.out, dtype=getattr(torch, args.dtype), extra_files=extra,
                            teacher=args.teacher_folder, copy_files=copies, guidance=args.guidance)
    if known is not None:
        known.save(out, about=ABOUT)
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    print(f"exported {args.checkpoint} -> {out} ({size / 1e6:.1f} MB)")


def text_side_files(folder: Path, *, required: bool) -> dict[str, Path]:
    """The text-side files (:data:`~stablemofusion.text.TEXT_SIDE_FILES`) that go with the model in ``folder``
    (name -> file); ``required``: SMFError when it has none."""
    from ..diffusion.checkpoint import companion_files, resolve
    from ..core.errors import SMFError
    from ..text import TEXT_SIDE_FILES

    if required and not resolve(folder).is_dir():
        raise SMFError(f"no such model folder: {folder}")
    found = companion_files(folder, TEXT_SIDE_FILES)
    if required and not found:
        raise SMFError(f"{folder} has none of the text-side files ({', '.join(TEXT_SIDE_FILES)})")
    return found


ABOUT = ("closest actions: example sentences per action from the lexicon's training phrasings and examples; out of "
         "domain: the detector's calibrated in-domain score (similarity) below threshold (stablemofusion.text.domain)")


def build_known_actions(lexicon: str, encoder: str, *, corpus: Path | None = None, text_cache: Path | None = None,
                        flag_rate: float | None = None, progress: bool = True):
    """The :class:`~stablemofusion.text.known.KnownActions` of a model trained on ``lexicon``'s corpus with the
    text encoder ``encoder``: its actions' example sentences and a trained, calibrated out-of-domain detector.
    With a labelled ``corpus`` (``clips.csv``), only the lexicon's actions that the corpus holds are known."""
    from ..data.lexicon import known_actions, load_lexicon
    from ..core.errors import SMFError
    from ..text.cache import LRUTextCache, TextEmbeddingCache
    from ..text.domain import FLAG_RATE, DomainDetector, build_detector, corpus_captions, lexicon_captions
    from ..text.frozen import load_text_encoder
    from ..text.known import KnownActions

    if corpus is not None and not corpus.is_dir():
        raise SMFError(f"no such corpus folder: {corpus}")
    captions = corpus_captions(corpus) if corpus is not None else lexicon_captions(lexicon)
    if text_cache is not None:
        # read only: pending rows are never flushed into the training run's cache
        cache = TextEmbeddingCache(text_cache, load_text_encoder(encoder), flush_every=1 << 62)
    else:
        cache = LRUTextCache(load_text_encoder(encoder), maxsize=len(captions) + 20_000)
    detector: DomainDetector = build_detector(captions, cache, lexicon=lexicon,
                                              flag_rate=FLAG_RATE if flag_rate is None else flag_rate,
                                              encoder=encoder, progress=progress)
    actions = known_actions(load_lexicon(lexicon), DomainDetector.THRESHOLD)["actions"]
    if corpus is not None and (corpus / "clips.csv").is_file():  # a corpus without some actions does not know them
        from ..data.labels import corpus_labels

        present = {info.content for info in corpus_labels(corpus).values()}
        actions = {a: examples for a, examples in actions.items() if a in present}
    return KnownActions(actions, DomainDetector.THRESHOLD, cache, detector=detector)


def _text_encoder_graphs(checkpoint) -> Path | None:
    """A graphs folder whose MiniLM graph an adapted export copies (adapters leave MiniLM as it is): the model
    folder's own, else the shipped model's; None: export it again."""
    from ..core.folders import model_folder
    from ..backends.onnx_graphs import MANIFEST
    from ..backends.onnx_backend import GRAPHS_DIR, default_graphs_path

    folder = model_folder(checkpoint) / GRAPHS_DIR
    return folder if (folder / MANIFEST).is_file() else default_graphs_path()
