"""Child processes that end with the process that started them.

Imports nothing but the standard library: a fleet worker calls it before it caps its memory.
"""

from __future__ import annotations

import signal

PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def die_with_parent() -> None:
    """Linux: end this process when the process that started it dies (a killed batch or Ray worker),
    rather than finish a log nobody waits for. Used by the fleet's workers and the method process."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):  # not Linux: the worker runs on to the end of its log
        pass
