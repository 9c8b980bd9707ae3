"""HumanML3D-style data folders and the text-motion training dataset."""

from .dataset import MotionTextDataset, biased_std, collate
from .layout import CaptionLine, MotionLayout, format_text_line, mean_std, parse_text_line, read_texts

__all__ = [
    "CaptionLine", "MotionLayout", "MotionTextDataset", "biased_std", "collate", "format_text_line", "mean_std",
    "parse_text_line", "read_texts",
]
