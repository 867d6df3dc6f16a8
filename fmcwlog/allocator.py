"""Allocator settings for the long numpy loops of ``process``: freed memory is kept for reuse.

glibc's ``malloc`` hands out blocks above a threshold (128 kB, raised as blocks are freed)
straight from ``mmap`` and returns freed memory at the heap's top to the system beyond a
trim threshold, so the megabyte-sized temporaries a step makes (ray casting: ~10 arrays of
10^5 samples per scan; KD-tree rebuilds) come back as fresh pages every time, each one a
page fault. On the corridor log that was ~1800 faults and half the 7 ms of casting a scan
(4.0 ms with the settings below, identical grid), and 11 % of ``process``'s CPU time in all.
:func:`keep_freed_memory` raises both thresholds for the process (``mallopt``); the peak
resident memory is unchanged (the same blocks are reused, not added). Elsewhere than
glibc it does nothing.

The blocks freed in the heap stay resident, which is the point during the sweeps, but not under
a step that allocates elsewhere: Arrow's parquet writer takes its buffers from its own
allocator (mimalloc; pyarrow's ``memory_pool`` arguments do not reach the column writers'), so
writing ``trajectories.parquet`` added ~31 MB on top of a heap holding ~41 MB of freed blocks
(the 20-minute corridor log: the run's peak, 310 MB). :func:`release_freed_memory` gives those
freed pages back first (``malloc_trim``); the blocks stay the heap's, faulted in again if used.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from functools import cache

M_TRIM_THRESHOLD = -1  # glibc's malloc.h
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_BYTES = 16 << 20  # blocks above this still come from mmap (an occupancy grid)
TRIM_THRESHOLD_BYTES = 128 << 20  # free memory kept at the heap's top

_done = False


def keep_freed_memory() -> bool:
    """Raise glibc's mmap and trim thresholds (once per process); False where there is no glibc."""
    global _done
    if _done:
        return True
    mallopt = _glibc("mallopt")
    if mallopt is None:
        return False
    _done = bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))
    return _done


def release_freed_memory() -> bool:
    """Give the heap's freed pages back to the system (glibc's ``malloc_trim``) before a step whose
    memory comes from elsewhere; False where there is no glibc."""
    trim = _glibc("malloc_trim")
    if trim is None:
        return False
    trim(0)
    return True


@cache
def _libc() -> ctypes.CDLL | None:
    """The C library this process runs on, without a lookup: ``dlopen(NULL)`` (the program and what it
    loaded, libc among them). ``ctypes.util.find_library`` would start ``ldconfig`` in a child, which
    the kernel charges with this process's peak memory as that child's own (``RUSAGE_CHILDREN``)."""
    try:
        return ctypes.CDLL(None)
    except (OSError, TypeError):  # TypeError: Windows, where there is no such handle
        return None


@cache
def _glibc(name: str) -> Callable[..., int] | None:
    """glibc's function ``name``, looked up once; None where there is no such function (macOS, musl
    without it, Windows)."""
    try:
        return getattr(_libc(), name)
    except AttributeError:
        return None
