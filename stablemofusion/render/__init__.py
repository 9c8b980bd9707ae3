"""Rendering of joint motions to videos (.mp4, .gif) and stills (.png)."""

from .video import VIDEO_SUFFIXES, render_frame, render_strip, render_video, write_frames

__all__ = ["VIDEO_SUFFIXES", "render_frame", "render_strip", "render_video", "write_frames"]
