"""What a command prints goes through the ``fmcwlog`` logger, so that -q and -v choose it.

Information goes to stdout as it is; warnings and errors to stderr as ``fmcwlog: warning: ...``,
a library's ``warnings.warn`` among them (one line, no source line). A reader of stdout that goes
away (``fmcwlog process ... | head -1``) is no error: what is left to print is dropped, and the
command ends as it would have (:func:`echo_out`).
"""

from __future__ import annotations

import logging
import os
import sys
import warnings

import click

console = logging.getLogger("fmcwlog")  # what the CLI prints, through logging (-q, -v)


class _ConsoleHandler(logging.Handler):
    """Information to stdout as it is; warnings and errors to stderr as ``fmcwlog: warning: ...``."""

    def emit(self, record: logging.LogRecord) -> None:
        msg = record.getMessage()
        if record.levelno >= logging.WARNING:
            click.echo(f"fmcwlog: {record.levelname.lower()}: {msg}", err=True)
        else:
            echo_out(msg)


def echo_out(text: str, nl: bool = True) -> None:
    """``text`` on stdout; where its reader has gone (a broken pipe), stdout is pointed at the null
    device, so that neither this nor any later write, nor the flush at exit, fails the command."""
    try:
        click.echo(text, nl=nl)
        sys.stdout.flush()
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A library's ``warnings.warn`` (a damaged log read by ``report``, say): one line, no source line."""
    console.warning(str(message))


def configure_logging(quiet: bool, verbose: int) -> None:
    """-q: warnings and errors only; -v: debug lines too; otherwise information as well."""
    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    warnings.showwarning = _show_warning
    console.handlers[:] = [_ConsoleHandler()]
    console.setLevel(level)
    console.propagate = False
