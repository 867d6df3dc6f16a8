"""One log in a process of its own: ``python -m fmcwlog.fleet.worker`` (started by :mod:`fmcwlog.fleet.local`).

The worker caps its address space (``RLIMIT_AS``) at the megabytes its one argument gives,
before anything large is imported; the parent then writes a pickled
:class:`~fmcwlog.fleet.tasks.LogTask` to its stdin; the worker runs
:func:`fmcwlog.pipeline.process.process` and answers on stdout, one line per message:

- ``sweeps DONE TOTAL`` now and then (TOTAL ``-`` when the log's summary does not say);
- ``done {json}`` once the results are in place: sweeps, ms per sweep, warnings;
- ``failed {json}``: the one-line reason (an :class:`~fmcwlog.errors.FmcwlogError`'s
  message, "out of memory" when the cap was reached, else the exception and a note that it
  is a bug; its traceback goes to stderr, which the parent keeps).

Anything else the libraries print goes to stderr: stdout is the protocol alone. BLAS and
OpenMP thread counts are set to 1 by the parent in the worker's environment, before numpy
is loaded: each worker is one core's worth of work.
"""

from __future__ import annotations

import errno
import json
import os
import pickle
import resource
import sys
import time
import traceback

from ..errors import FmcwlogError  # tiny: safe before the cap
from ..pipeline.children import die_with_parent  # tiny too

PROGRESS_PERIOD_S = 0.25  # the parent's bar needs no more


def _cap_address_space(limit_bytes: int | None) -> None:
    if limit_bytes:
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        soft = limit_bytes if hard == resource.RLIM_INFINITY else min(limit_bytes, hard)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _out_of_memory(exc: BaseException) -> bool:
    """MemoryError, or a library that could not be mapped (the cap reached while importing)."""
    if isinstance(exc, MemoryError):
        return True
    text = str(exc)
    return (isinstance(exc, OSError) and exc.errno == errno.ENOMEM) or (
        isinstance(exc, ImportError) and ("failed to map segment" in text or "Cannot allocate memory" in text))


def main() -> int:
    die_with_parent()
    proto = os.fdopen(os.dup(sys.stdout.fileno()), "w", buffering=1)
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # stray prints land in stderr, not the protocol

    def say(kind: str, payload: object) -> None:
        proto.write(f"{kind} {payload}\n")

    cap_mb = int(sys.argv[1]) if len(sys.argv) > 1 else 0
    try:
        _cap_address_space(cap_mb * 2**20 if cap_mb else None)  # first: numpy, scipy and sklearn count too
        task = pickle.load(sys.stdin.buffer)
        from ..pipeline.process import process

        last = [0.0]

        def on_sweep(done: int, total: int | None) -> None:
            now = time.monotonic()
            if now - last[0] >= PROGRESS_PERIOD_S:
                last[0] = now
                say("sweeps", f"{done} {total if total is not None else '-'}")

        # jobs=1: the methods in this one process; the workers already fill the cores with logs
        s = process(task.log, task.out_dir, task.options, force=task.force, on_sweep=on_sweep, jobs=1)
        say("done", json.dumps({"sweeps": s.sweeps, "ms_median": s.ms_median, "warnings": s.warnings,
                                "truncated": s.truncated}))
        return 0
    except KeyboardInterrupt:
        say("failed", json.dumps({"reason": "interrupted"}))
        return 130
    except Exception as exc:  # noqa: BLE001 (each log's failure is reported, the batch goes on)
        if _out_of_memory(exc):
            cap = f"the per-log cap of {cap_mb} MB (--memory-limit)" if cap_mb else "no per-log cap"
            reason = f"out of memory ({type(exc).__name__}{': ' if str(exc) else ''}{exc}); {cap}"
        elif isinstance(exc, FmcwlogError):
            reason = str(exc)
        else:
            traceback.print_exc()
            where = traceback.extract_tb(exc.__traceback__)[-1]
            reason = (f"{type(exc).__name__}: {exc} (a bug in fmcwlog, at {os.path.basename(where.filename)}:"
                      f"{where.lineno}; please report it with this log)")
        say("failed", json.dumps({"reason": " ".join(reason.split())}))
    return 1


if __name__ == "__main__":
    sys.exit(main())
