"""User-facing errors: the CLI prints them as one line and exits with code 2."""


class SMFError(Exception):
    """Base class for errors caused by bad input (files, shapes, options)."""


class MotionFormatError(SMFError, ValueError):
    """A motion array or file has the wrong shape, values or syntax."""
