"""SIGTERM ends a command as Ctrl-C does, and an interrupt Python swallowed is delivered again.

Both arrive as a :class:`KeyboardInterrupt` (click turns it into ``Abort``), so that the library's
clean-up runs: temporary outputs removed, an earlier output put back. :func:`fmcwlog.cli.exits.run`
turns them into one line and exit status 130 (Ctrl-C) or 143 (SIGTERM).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from typing import Any


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a job scheduler) ends a command as Ctrl-C does: its temporary
    outputs removed, an earlier output put back. Python's default ends at once, leaving them behind."""


def terminate(signum: int, frame: object) -> None:
    """The SIGTERM handler."""
    raise Terminated


def _deliver_again(previous: Callable[[Any], object]) -> Callable[[Any], None]:
    """An unraisable-exception hook that raises a swallowed interrupt's signal once more.

    A signal handler's exception lands in whatever bytecode runs, and where that is a callback
    Python cannot raise from (an import lock's, a ``__del__``) it is printed as 'Exception
    ignored' and the command went on to finish, exit 0 and replace the output it was told to
    stop writing (seen under load: SIGTERM mid-import). The signal is sent again from a timer
    thread 10 ms later, when the main thread has left that callback (raised from here, its
    handler would run inside the hook, and be ignored again); should it land in one again,
    this repeats."""
    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            signum = signal.SIGTERM if isinstance(unraisable.exc_value, Terminated) else signal.SIGINT
            threading.Timer(0.01, os.kill, (os.getpid(), signum)).start()
        else:
            previous(unraisable)
    return hook


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within: SIGTERM raises :class:`Terminated`, and a swallowed interrupt is delivered again
    (on the main thread only; elsewhere, nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old, old_hook = signal.signal(signal.SIGTERM, terminate), sys.unraisablehook
    sys.unraisablehook = _deliver_again(old_hook)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)
        sys.unraisablehook = old_hook
