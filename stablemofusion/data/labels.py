"""Content and style labels of a labelled corpus (``clips.csv`` from `smf prepare bandai`)."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

from ..core.errors import SMFError


@dataclass(frozen=True)
class LabelInfo:
    """Labels of one corpus motion."""

    dataset: int
    content: str
    style: str


def corpus_labels(data: str | Path) -> dict[str, LabelInfo]:
    """Motion id -> labels, from ``<data>/clips.csv`` (mirrored ``M`` ids included)."""
    from .captions import mirror_label

    path = Path(data) / "clips.csv"
    if not path.is_file():
        raise SMFError(f"{data}: no clips.csv with content/style labels (a labelled corpus from `smf prepare bandai`)")
    out: dict[str, LabelInfo] = {}
    with open(path, newline="", encoding="utf-8") as f:
        for row in csv.DictReader(f):
            info = LabelInfo(int(row["dataset"]), row["content"], row["style"])
            out[row["id"]] = info
            out["M" + row["id"]] = LabelInfo(info.dataset, mirror_label(info.content), info.style)
    return out


__all__ = ["LabelInfo", "corpus_labels"]
