"""How reliably a model draws each of its known actions, as data beside the model (``reliability.json``, made by
``benchmarks/action_reliability.py``): a prompt whose closest known action the model draws badly is warned about,
with why (its few clips, its measured accuracy)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .errors import SMFError
from .folders import CONFIG, companion_file

RELIABILITY_FILE = "reliability.json"
MAX_RELIABILITY_BYTES = 1 << 20
# how much closer (cosine similarity) a prompt must be to an action drawn badly than to every action drawn well to be
# warned about, and how close at least (below, every known action is a poor match and the closest names none): the
# smallest margin, with the floor, that warns none of the other prompts of the held-out lexicon probe and of
# benchmarks/prompts_weak_dev.jsonl ("a person waves" is a little closer to calling than to waving; "a confident
# model struts down the runway" is closest to kicking, at 0.37); benchmarks/weak_warnings.py, docs/prompts.md
WEAK_MARGIN = 0.06
WEAK_FLOOR = 0.40


@dataclass(frozen=True)
class ActionReliability:
    """One known action: ``accuracy`` the share of motions for held-out wording judged to be it (None: not
    measured), ``clips`` the corpus clips that taught it, ``weak`` whether prompts of it are warned about."""

    accuracy: float | None
    clips: int
    weak: bool


def read_reliability(path: str | Path | None) -> dict[str, ActionReliability] | None:
    """The table of a ``reliability.json`` (None for no file); SMFError for a file that is not one."""
    if path is None or not Path(path).is_file():
        return None
    path = Path(path)
    try:
        if path.stat().st_size > MAX_RELIABILITY_BYTES:
            raise ValueError("too large")
        rows = json.loads(path.read_text(encoding="utf-8"))["actions"]
        return {str(a): ActionReliability(None if r["accuracy"] is None else float(r["accuracy"]), int(r["clips"]),
                                          bool(r["weak"])) for a, r in rows.items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as e:
        raise SMFError(f"{path}: not a reliability table ({e})") from None


def graphs_reliability(graphs_folder: str | Path) -> dict[str, ActionReliability] | None:
    """The reliability table of the model whose portable graphs are in ``graphs_folder`` (its model folder's, the
    graphs sitting in its ``onnx/``; None for graphs exported on their own or a model without one)."""
    folder = Path(graphs_folder).parent
    return read_reliability(companion_file(folder, RELIABILITY_FILE)) if (folder / CONFIG).is_file() else None


def weak_action(domain, table: dict[str, ActionReliability] | None, margin: float = WEAK_MARGIN,
                floor: float = WEAK_FLOOR) -> str | None:
    """The action to warn about for a prompt's domain check: its closest known action when the model draws it badly
    (``table``), it is at least ``floor`` similar and closer than every action drawn well by more than ``margin``;
    None for an out-of-domain prompt, without a table or a check."""
    if table is None or domain is None or domain.out_of_domain or not domain.closest:
        return None
    action, similarity = domain.closest[0]
    drawn_well = [s for a, s in domain.closest if not (a in table and table[a].weak)]
    weak = (action in table and table[action].weak and similarity >= floor
            and similarity - max(drawn_well, default=0.0) > margin)
    return action if weak else None


def weak_message(prompt: str, action: str, r: ActionReliability) -> str:
    """One warning line for a prompt whose closest known action the model draws badly."""
    measured = "" if r.accuracy is None else f"; {r.accuracy:.0%} of its motions for other wordings were judged right"
    return (f"{prompt!r} is closest to {action!r}, which this model draws badly (it was taught by {r.clips} "
            f"clip{'s' if r.clips != 1 else ''}{measured}): the motion may not show it")


__all__ = ["ActionReliability", "RELIABILITY_FILE", "WEAK_FLOOR", "WEAK_MARGIN", "graphs_reliability",
           "read_reliability", "weak_action", "weak_message"]
