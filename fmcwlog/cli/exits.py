"""How a command ends: its exit status, and an error as one line on stderr.

Errors a user can fix (bad arguments, bad files: every :class:`fmcwlog.errors.FmcwlogError`,
a file system refusal, :class:`UserError`) end in ``fmcwlog: error: ...`` and exit status 2; no
traceback, no partial output. Some of many inputs failing (:class:`SomeFailed`) is status 1;
Ctrl-C 130, SIGTERM 143.
"""

from __future__ import annotations

import signal
import sys

import click

from ..errors import FmcwlogError, os_reason
from .interrupts import Terminated, sigterm_as_interrupt


class UserError(click.ClickException):
    """A command's arguments do not fit together (or miss one): exit status 2, as click's own."""

    exit_code = 2


class SomeFailed(click.ClickException):
    """Some of many inputs failed, each reported as it did."""

    exit_code = 1  # not 2: the command and its input were fine, some logs were not


MAX_MESSAGE_CHARS = 4000  # beyond any message but one quoting a user's input whole


def one_line(message: str) -> str:
    """A message as one printable line: a line break or control character a user's input carried in
    (a file name, a key) is shown escaped, never breaking the line. Messages quote input through
    :func:`fmcwlog.errors.excerpt`; one longer than :data:`MAX_MESSAGE_CHARS` all the same is cut in the
    middle, so that no input, however long, is echoed whole."""
    if len(message) > MAX_MESSAGE_CHARS:
        head, tail = MAX_MESSAGE_CHARS // 2, MAX_MESSAGE_CHARS // 4
        message = f"{message[:head]}… ({len(message) - head - tail} characters left out) …{message[-tail:]}"
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)


def run_command_line(group: click.Group) -> None:
    """``group`` on ``sys.argv``, each way it can end turned into its exit status (and one line)."""
    try:
        with sigterm_as_interrupt():
            group.main(standalone_mode=False, prog_name="fmcwlog")
    except click.exceptions.NoArgsIsHelpError as exc:  # bare 'fmcwlog' (or a bare group): its help, no error
        click.echo(exc.ctx.get_help() if exc.ctx else exc.format_message())
        sys.exit(0)
    except click.exceptions.Abort as exc:
        terminated = isinstance(exc.__cause__, Terminated)
        click.echo("fmcwlog: terminated" if terminated else "fmcwlog: aborted", err=True)
        sys.exit(128 + signal.SIGTERM if terminated else 130)
    except click.ClickException as exc:
        click.echo(f"fmcwlog: error: {one_line(exc.format_message())}", err=True)
        sys.exit(2 if isinstance(exc, (click.UsageError, UserError)) else exc.exit_code)
    except FmcwlogError as exc:  # bad input or parameters: the message names the file or parameter
        click.echo(f"fmcwlog: error: {one_line(str(exc))}", err=True)
        sys.exit(2)
    except OSError as exc:  # a file system refusal no command caught: still one line
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"fmcwlog: error: {one_line(where + os_reason(exc))}", err=True)
        sys.exit(2)
