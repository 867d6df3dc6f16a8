"""Loading a command's library modules: without garbage collections, and frozen out of later ones."""

from __future__ import annotations

import gc
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def loading_modules() -> Iterator[None]:
    """Imports inside run without the garbage collector, and what they made is then frozen out of
    its later collections (:func:`gc.freeze`). Modules make objects that live as long as the
    process, not garbage: the collections that importing the estimation stack sets off (about
    200, 0.03 s of CPU) free nothing, and each full collection of the run after would walk them
    all again. A child process forked later leaves their pages unwritten by its collections too."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()
        gc.freeze()
