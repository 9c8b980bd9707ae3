"""Whether this install can encode a video format (light: imports nothing heavy)."""

from __future__ import annotations

import importlib.util

from ..core.errors import SMFError


def check_encoder(suffix: str) -> None:
    """SMFError naming the extra to install when ``suffix`` ('mp4' or '.mp4', ...) needs an encoder this install
    lacks: mp4 needs ffmpeg (the [video] extra); gif needs only Pillow."""
    if suffix.lower().lstrip(".") == "mp4" and importlib.util.find_spec("imageio_ffmpeg") is None:
        raise SMFError("mp4 needs ffmpeg, which this install lacks: pip install 'stablemofusion[video]' (or ask for gif)")
