"""User-facing errors: the CLI prints them as one line and exits with code 2."""


class SMFError(Exception):
    """Base class for errors caused by bad input (files, shapes, options)."""


class MotionFormatError(SMFError, ValueError):
    """A motion array or file has the wrong shape, values or syntax."""


def escape(text: object) -> str:
    """``text`` with every unprintable character (ANSI escapes, NUL, lone surrogates, newlines) as a Python
    escape, so that text from a user or a file cannot forge or garble a log line or a terminal."""
    return "".join(c if c.isprintable() else ascii(c)[1:-1] for c in str(text))
