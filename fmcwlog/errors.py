"""The one exception family of fmcwlog: every error a user can fix is a :class:`FmcwlogError`.

Each message is one line that names the file (or the parameter) and what is wrong with it;
the command line prints it as ``fmcwlog: error: ...`` and exits with status 2. Anything
else that escapes is a bug in fmcwlog, not in the user's input.
"""

from __future__ import annotations


class FmcwlogError(Exception):
    """Base of every error a user can fix; the message names the file or parameter and the problem."""


class ConfigError(FmcwlogError, ValueError):
    """A parameter or config file is invalid; the message says which and why."""


class LogError(FmcwlogError):
    """A log cannot be read or written; the message names the file and the problem."""


class CalibrationError(FmcwlogError, ValueError):
    """A calibration value is missing, not a number, or out of its physical range."""


class WorldError(FmcwlogError, ValueError):
    """A world description is invalid; the message says where and why."""


class CarmenImportError(FmcwlogError, ValueError):
    """A CARMEN or CMU log holds nothing usable; the message says why."""


class RelationsError(FmcwlogError, ValueError):
    """A relations file cannot be read; the message names it and the line."""


class ReportError(FmcwlogError):
    """An output folder or log cannot be evaluated; the message says which and why."""


class OutputError(FmcwlogError):
    """An output cannot be written where it was asked for; the message says where and why."""


class MethodProcessError(FmcwlogError):
    """The process running some of the methods (:mod:`fmcwlog.pipeline.method_process`) ended without its
    results: killed, out of memory or crashed; the message says how, and that ``--jobs 1`` avoids it."""


class MapSizeError(FmcwlogError, ValueError):
    """An occupancy grid would exceed its cell budget (points far off, or a resolution too fine)."""


EXCERPT_CHARS = 80  # the most of a user's input a message quotes


def excerpt(text: str, limit: int = EXCERPT_CHARS) -> str:
    """``text`` from a user's input as a message quotes it: control characters escaped, at most
    ``limit`` characters, cut with ``…`` (``'1111…' (4000001 characters)``) where it is longer."""
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text[:limit + 1])
    if len(text) <= limit and len(shown) <= limit:
        return shown
    return f"{shown[:limit - 1]}… ({len(text)} characters)"


def os_reason(exc: OSError) -> str:
    """``No space left on device`` -> ``no space left on device``: the end of a one-line message."""
    text = exc.strerror or str(exc) or type(exc).__name__
    return text[:1].lower() + text[1:]
