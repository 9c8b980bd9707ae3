"""Long and multi-prompt motions: a timeline of (prompt, seconds) segments generated as one continuous motion.

The motion is built window by window. The first window is generated from its prompt; every later window
keeps the last ``overlap`` frames made so far as its known start (prefix editing, :mod:`stablemofusion.core.edit_plan`)
and generates what follows from its own prompt, so each join continues the motion before it: features are
relative to the body, so appending a window's new frames continues the root path and heading exactly, and
the seam blending of editing keeps the velocity continuous. A segment longer than one window (the model's
``max_frames``) spans several windows with the same prompt.
"""

from __future__ import annotations

from dataclasses import dataclass

from .errors import SMFError

DEFAULT_OVERLAP = 1.0  # seconds of the motion so far that a window keeps as its start
TAIL = 8  # frames generated past what a window adds and then dropped: a motion's last frames are its least
# settled (its final velocities have no next frame to agree with), and the next window continues from them


@dataclass(frozen=True)
class Window:
    """One generation call: ``prompt``, ``keep`` frames of the motion so far as its start (0 for the first),
    then ``new`` frames added to the motion, then ``tail`` generated frames that are dropped; ``segment`` the
    timeline entry it belongs to."""

    prompt: str
    keep: int
    new: int
    segment: int
    tail: int = TAIL

    @property
    def frames(self) -> int:
        return self.keep + self.new + self.tail


def parse_timeline(text: str) -> list[tuple[str, float]]:
    """``"walk forward:4; wave both hands:3"`` -> [("walk forward", 4.0), ("wave both hands", 3.0)]."""
    segments = []
    for part in (p.strip() for p in text.split(";")):
        if not part:
            continue
        prompt, sep, seconds = part.rpartition(":")
        if not sep or not prompt.strip():
            raise SMFError(f"timeline entry {part!r} is not 'PROMPT:SECONDS'")
        try:
            value = float(seconds)
        except ValueError:
            raise SMFError(f"timeline entry {part!r}: {seconds.strip()!r} is not a number of seconds") from None
        segments.append((prompt.strip(), value))
    if not segments:
        raise SMFError("the timeline is empty; write it as 'PROMPT:SECONDS; PROMPT:SECONDS'")
    return segments


def plan_windows(segments: list[tuple[str, int]], max_frames: int, overlap: int, min_frames: int) -> list[Window]:
    """The windows of a timeline of (prompt, frames) segments: each at most ``max_frames`` frames (the
    dropped tail included), each after the first keeping ``overlap`` frames; a window shorter than
    ``min_frames`` is generated at ``min_frames`` and cut (the model's shortest length)."""
    if not 0 < overlap < max_frames - TAIL:
        raise SMFError(f"the overlap must be 1 to {max_frames - TAIL - 1} frames, got {overlap}")
    windows: list[Window] = []
    made = 0  # frames of the motion so far
    for i, (prompt, frames) in enumerate(segments):
        if not prompt.strip():
            raise SMFError(f"timeline segment {i + 1} has an empty prompt")
        if frames < 1:
            raise SMFError(f"timeline segment {i + 1} ({prompt!r}) must last at least one frame, got {frames}")
        left = frames
        while left > 0:
            keep = min(overlap, made)  # a first segment shorter than the overlap: keep what there is
            new = min(left, max_frames - keep - TAIL)
            windows.append(Window(prompt, keep, new, i))
            left -= new
            made += new
    return windows


def check_timeline(segments: list[tuple[str, float]]) -> list[tuple[str, float]]:
    """A timeline's (prompt, seconds) segments checked against the limits (the count, each prompt, each length and
    the total), before any model is loaded; one-line SMFError naming the first problem."""
    from .limits import check_prompt, check_seconds, check_segments

    check_segments(len(segments))
    for prompt, secs in segments:
        check_prompt(prompt, "every timeline prompt")
        check_seconds(secs, f"timeline segment {prompt!r}: seconds")
    check_seconds(sum(secs for _, secs in segments), "a timeline's total seconds")
    return segments


def segment_frames(segments: list[tuple[str, float]], fps: float) -> list[tuple[str, int]]:
    """A timeline's (prompt, seconds) segments checked (:func:`check_timeline`, and at least one frame each) and in
    frames at ``fps``."""
    import math

    for prompt, secs in segments:
        if not isinstance(secs, (int, float)) or not math.isfinite(secs) or secs * fps < 1:
            raise SMFError(f"timeline segment {prompt!r}: seconds must be at least one frame ({1 / fps:g} s), "
                           f"got {secs}")
    check_timeline(segments)
    return [(prompt, int(round(secs * fps))) for prompt, secs in segments]


__all__ = ["DEFAULT_OVERLAP", "Window", "check_timeline", "parse_timeline", "plan_windows", "segment_frames"]
