"""The one error type of the server, and log lines that cannot carry terminal control codes."""

from __future__ import annotations

import logging

from ..core.errors import SMFError, escape

log = logging.getLogger("stablemofusion.serve")


class ServeError(SMFError):
    """A request answered with ``status`` and ``{"error": message}`` (one line)."""

    def __init__(self, status: int, message: str, retry_after: int | None = None):
        super().__init__(message)
        self.status = status
        self.message = " ".join(str(message).split("\n"))
        self.retry_after = retry_after  # seconds, sent as the Retry-After header (503: when to come back)


def log_event(level: int, message: str, *texts: object) -> None:
    """Log ``message % texts`` with every text escaped."""
    log.log(level, message, *(escape(t) for t in texts))
