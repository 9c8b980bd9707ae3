"""The one error type of the server, and log lines that cannot carry terminal control codes."""

from __future__ import annotations

import logging

from ..errors import SMFError

log = logging.getLogger("stablemofusion.serve")


class ServeError(SMFError):
    """A request answered with ``status`` and ``{"error": message}`` (one line)."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = " ".join(str(message).split("\n"))


def escape(text: object) -> str:
    """``text`` with every unprintable character (ANSI escapes, NUL, lone surrogates, newlines) as a Python
    escape, so that a client's prompt cannot forge or garble log lines."""
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in str(text))


def log_event(level: int, message: str, *texts: object) -> None:
    """Log ``message % texts`` with every text escaped."""
    log.log(level, message, *(escape(t) for t in texts))
