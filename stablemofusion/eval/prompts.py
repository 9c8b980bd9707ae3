"""Prompt-following on a labelled prompt file: generate each prompt, classify the motion, count hits.

A prompt file is JSON lines ``{"prompt": str, "content": label | [labels] | null, "style": label | [labels]
| null, "dataset": int | null, "ood": bool}``: ``content``/``style`` list the right answers (null style =
any style), ``dataset`` says which label set the classifier chooses from, ``ood`` marks prompts the model
cannot do (they are only used for the out-of-domain check).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import SMFError
from .classifier import LabelInfo, MotionClassifier, dataset_labels, label_accuracy


@dataclass(frozen=True)
class PromptItem:
    prompt: str
    contents: tuple[str, ...]
    styles: tuple[str, ...]
    dataset: int | None
    ood: bool = False


def _labels(value, where: str) -> tuple[str, ...]:
    if value is None:
        return ()
    if isinstance(value, str):
        return (value,)
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return tuple(value)
    raise SMFError(f"{where}: a label must be a string, a list of strings or null")


def load_prompts(path: str | Path) -> list[PromptItem]:
    """Read a prompt file (see the module docstring); one-line errors name the bad line."""
    path = Path(path)
    if not path.is_file():
        raise SMFError(f"no such prompt file: {path}")
    items = []
    for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        if not line.strip():
            continue
        where = f"{path}:{n}"
        try:
            d = json.loads(line)
        except json.JSONDecodeError as e:
            raise SMFError(f"{where}: not valid JSON ({e.msg})") from None
        if not isinstance(d, dict) or not isinstance(d.get("prompt"), str) or not d["prompt"].strip():
            raise SMFError(f"{where}: needs a non-empty string 'prompt'")
        ood = bool(d.get("ood", False))
        contents = _labels(d.get("content"), where)
        if not ood and not contents:
            raise SMFError(f"{where}: an in-domain prompt needs a 'content' label")
        dataset = d.get("dataset")
        if dataset is not None and not isinstance(dataset, int):
            raise SMFError(f"{where}: 'dataset' must be an integer or null")
        items.append(PromptItem(d["prompt"], contents, _labels(d.get("style"), where), dataset, ood))
    if not items:
        raise SMFError(f"{path}: no prompts")
    return items


def check_known(items: Sequence[PromptItem], classifier: MotionClassifier) -> None:
    for it in items:
        for c in it.contents:
            if c not in classifier.cfg.contents:
                raise SMFError(f"prompt {it.prompt!r}: content {c!r} is unknown to the classifier")
        for s in it.styles:
            if s not in classifier.cfg.styles:
                raise SMFError(f"prompt {it.prompt!r}: style {s!r} is unknown to the classifier")


def prompt_accuracy(pipe, classifier: MotionClassifier, items: Sequence[PromptItem], labels: dict[str, LabelInfo],
                    *, samples: int = 3, seconds: float | None = 4.0, seed: int = 0, batch: int = 32,
                    **sampling) -> dict:
    """Generate ``samples`` motions per in-domain prompt (seeds ``seed + k``; ``seconds`` None: the length the
    pipeline predicts from the prompt; ``sampling``: keyword arguments of the pipeline call, e.g. guidance_scale,
    steps, sampler, footskate) and classify them; accuracy per dataset and overall. With a pipeline that knows
    its actions, also the out-of-domain check: how many in-domain and out-of-domain prompts it flags."""
    inside = [it for it in items if not it.ood]
    check_known(inside, classifier)
    rep = [it for it in inside for _ in range(samples)]
    prompts = [it.prompt for it in rep]
    seeds = [seed + k for _ in inside for k in range(samples)]
    feats = []
    for a in range(0, len(prompts), batch):
        res = pipe(prompts[a:a + batch], seconds=seconds, seed=seeds[a:a + batch], **sampling)
        feats.extend(r.features for r in res)
    by_dataset = {d: dataset_labels(labels, d) for d in {it.dataset for it in rep} if d is not None}
    allowed = [by_dataset.get(it.dataset, ((), ())) for it in rep]
    pred = classifier.predict(feats, allowed)
    want = [(it.contents, it.styles) for it in rep]
    out: dict = {"samples_per_prompt": samples, "seconds": seconds, "prompts": len(inside)}
    groups = sorted({it.dataset for it in inside}, key=lambda d: (d is None, d))
    for d in groups:
        sel = [i for i, it in enumerate(rep) if it.dataset == d]
        out[f"dataset-{d}"] = label_accuracy([pred[i] for i in sel], [want[i] for i in sel])
    out["all"] = label_accuracy(pred, want)
    out["per_prompt"] = [{"prompt": it.prompt, "want": [list(it.contents), list(it.styles)],
                          "got": [list(p) for p in pred[k * samples:(k + 1) * samples]]} for k, it in enumerate(inside)]
    if getattr(pipe, "known_actions", None) is not None:
        flags = {True: [], False: []}
        for it in items:
            flags[it.ood].append(pipe.known_actions.check(it.prompt).out_of_domain)
        out["ood_check"] = {"flagged_out_of_domain": float(np.mean(flags[True])) if flags[True] else float("nan"),
                            "flagged_in_domain": float(np.mean(flags[False])) if flags[False] else float("nan"),
                            "out_of_domain_prompts": len(flags[True])}
    return out


def format_prompt_accuracy(result: dict) -> str:
    lines = ["| prompts | n (x samples) | content acc. | style acc. (n) |", "|---|---|---|---|"]
    for k, v in result.items():
        if isinstance(v, dict) and "content_acc" in v:
            lines.append(f"| {k} | {v['n'] // result['samples_per_prompt']} (x{result['samples_per_prompt']}) | "
                         f"{v['content_acc']:.3f} | {v['style_acc']:.3f} ({v['n_style'] // result['samples_per_prompt']}) |")
    text = "\n".join(lines)
    if "ood_check" in result:
        o = result["ood_check"]
        text += (f"\n\nout-of-domain warning: {o['flagged_out_of_domain']:.0%} of {o['out_of_domain_prompts']} "
                 f"out-of-domain prompts flagged, {o['flagged_in_domain']:.0%} of in-domain prompts flagged")
    return text


__all__ = ["PromptItem", "format_prompt_accuracy", "load_prompts", "prompt_accuracy"]
