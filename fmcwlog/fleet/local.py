"""The local executor: each log in a worker process of its own, up to ``jobs`` at a time.

A worker is ``python -m fmcwlog.fleet.worker`` (:mod:`fmcwlog.fleet.worker`), not a fork
or a pool: a worker that is killed (by the timeout, by the system's OOM killer, by anyone)
takes nothing else with it, and its environment is set before numpy loads, with one BLAS
and OpenMP thread (``jobs`` workers keep ``jobs`` cores busy, no more). The parent reads
every worker's stdout through one selector, kills a worker past its deadline, and turns
whatever ended it into one :class:`~fmcwlog.fleet.tasks.LogOutcome` with a one-line
reason. A killed worker's temporary ``.NAME.partial-PID`` folder is removed, so a failed
log leaves nothing behind. Logs are started longest first, so that the batch does not
end waiting on one long log started last.
"""

from __future__ import annotations

import json
import os
import pickle
import selectors
import signal
import subprocess
import sys
import tempfile
import time
from collections import deque
from pathlib import Path

from .progress import Progress
from .state import remove_partial
from .tasks import Limits, LogOutcome, LogTask

THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "BLIS_NUM_THREADS",
                    "VECLIB_MAXIMUM_THREADS", "NUMEXPR_NUM_THREADS")
_STDERR_KEPT = 4000  # characters of a failed worker's stderr kept in batch.json


def worker_env() -> dict[str, str]:
    """The parent's environment, with one BLAS/OpenMP thread. When this fmcwlog was imported from
    a source tree, that tree goes first on the worker's path: the worker must run the same code
    as the parent (an installed fmcwlog is found as usual; a site-packages folder put first
    would shadow the standard library)."""
    env = dict(os.environ)
    env.update({v: "1" for v in THREAD_VARIABLES})
    package_root = Path(__file__).resolve().parents[2]
    if package_root.name not in ("site-packages", "dist-packages"):
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(package_root), env.get("PYTHONPATH")) if p)
    return env


class WorkerProcess:
    """One log in one worker process; :meth:`read` as its stdout becomes readable, then :meth:`outcome`."""

    def __init__(self, task: LogTask, limits: Limits, env: dict[str, str]):
        self.task, self.limits = task, limits
        self.started = time.monotonic()
        self.deadline = self.started + limits.timeout_s if limits.timeout_s > 0 else None
        self.sweeps_done: int = 0
        self.sweeps_total: int | None = None
        self.result: tuple[str, dict] | None = None
        self.killed_for: str | None = None
        self._buf = b""
        self._stderr = tempfile.TemporaryFile()
        self.proc = subprocess.Popen([sys.executable, "-m", "fmcwlog.fleet.worker", str(limits.memory_limit_mb)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, env=env)
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.stdout = self.proc.stdout
        try:
            self.proc.stdin.write(pickle.dumps(task))
            self.proc.stdin.close()
        except BrokenPipeError:  # it died at once; outcome() says how
            pass

    def read(self) -> bool:
        """Take what the worker wrote; False once it has closed its stdout (it is ending)."""
        data = os.read(self.stdout.fileno(), 65536)
        if not data:
            return False
        self._buf += data
        *lines, self._buf = self._buf.split(b"\n")
        for line in lines:
            kind, _, payload = line.decode(errors="replace").partition(" ")
            if kind == "sweeps":
                done, total = payload.split()
                self.sweeps_done, self.sweeps_total = int(done), (None if total == "-" else int(total))
            elif kind in ("done", "failed"):
                self.result = (kind, json.loads(payload))
        return True

    def overdue(self, now: float) -> bool:
        return self.deadline is not None and now > self.deadline and self.killed_for is None

    def kill(self, why: str) -> None:
        self.killed_for = why
        self.proc.kill()

    def interrupt(self) -> None:
        """Ctrl-C or an error in the parent: end the worker and remove what it had begun to write."""
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        self.stdout.close()
        self._stderr.close()
        remove_partial(self.task.out_dir.parent, self.task.name, self.proc.pid)

    def outcome(self) -> LogOutcome:
        """Wait for the worker to end, clean up after it, and say what became of the log."""
        rc = self.proc.wait()
        self.stdout.close()
        wall = time.monotonic() - self.started
        t = self.task
        if self.result is not None and self.result[0] == "done":  # said only once the results are in place
            info = self.result[1]
            self._stderr.close()
            return LogOutcome(t.name, t.log, "done", sweeps=int(info.get("sweeps", 0)), wall_s=wall,
                              summary={k: info[k] for k in ("ms_median", "warnings", "truncated") if k in info})
        self._stderr.seek(0)
        stderr = self._stderr.read().decode(errors="replace")
        self._stderr.close()
        remove_partial(t.out_dir.parent, t.name, self.proc.pid)
        return LogOutcome(t.name, t.log, "failed", reason=self._reason(rc, stderr), sweeps=0, wall_s=wall,
                          detail=stderr[-_STDERR_KEPT:] or None)

    def _at(self) -> str:
        total = f" of {self.sweeps_total}" if self.sweeps_total is not None else ""
        return f"at sweep {self.sweeps_done}{total}"

    def _reason(self, rc: int, stderr: str) -> str:
        if self.killed_for is not None:
            return f"{self.killed_for}, {self._at()}"
        if self.result is not None and self.result[0] == "failed":
            return str(self.result[1].get("reason", "failed"))
        if rc < 0:
            name = signal.Signals(-rc).name if -rc in signal.valid_signals() else str(-rc)
            oom = " (the system's out-of-memory killer sends it)" if -rc == signal.SIGKILL else ""
            return f"worker killed by {name}{oom}, {self._at()}"
        last = next((ln.strip() for ln in reversed(stderr.splitlines()) if ln.strip()), "")
        cap = self.limits.memory_limit_mb
        if cap and "memory" in stderr.lower():
            # a library that cannot allocate under the cap may exit on its own (OpenBLAS does, once
            # gtsam's libraries have taken their share of the address space) instead of raising
            return (f"probably out of memory: worker exited with status {rc} without a result"
                    f"{': ' + last if last else ''}; the per-log memory cap of {cap} MB may be too small "
                    "(--memory-limit)")
        return f"worker exited with status {rc} without a result{': ' + last if last else ''}"


def run_one(task: LogTask, limits: Limits) -> LogOutcome:
    """One log in one worker, waiting for it (a Ray task does this on its node)."""
    w = WorkerProcess(task, limits, worker_env())
    sel = selectors.DefaultSelector()
    sel.register(w.stdout, selectors.EVENT_READ)
    try:
        while True:
            wait = None if w.deadline is None else max(0.0, w.deadline - time.monotonic())
            if sel.select(wait) and not w.read():
                break
            if w.overdue(time.monotonic()):
                w.kill(f"timed out after {limits.timeout_s:g} s (--timeout)")
    except BaseException:
        w.interrupt()
        raise
    finally:
        sel.close()
    return w.outcome()


def run_local(tasks: list[LogTask], limits: Limits, jobs: int, progress: Progress) -> list[LogOutcome]:
    """Every task in its own worker, ``jobs`` at a time, longest first; outcomes in the order they end."""
    env = worker_env()
    pending = deque(sorted(tasks, key=lambda t: -t.size_bytes))
    running: dict[int, WorkerProcess] = {}
    outcomes: list[LogOutcome] = []
    sel = selectors.DefaultSelector()
    try:
        while pending or running:
            while pending and len(running) < max(jobs, 1):
                w = WorkerProcess(pending.popleft(), limits, env)
                sel.register(w.stdout, selectors.EVENT_READ, w)
                running[w.proc.pid] = w
                progress.sweeps(w.task.name, 0, None)
            deadlines = [w.deadline for w in running.values() if w.deadline is not None and w.killed_for is None]
            wait = min([0.5, *(d - time.monotonic() for d in deadlines)])
            for key, _ in sel.select(max(wait, 0.0)):
                w = key.data
                if w.read():
                    progress.sweeps(w.task.name, w.sweeps_done, w.sweeps_total)
                    continue
                sel.unregister(w.stdout)
                del running[w.proc.pid]
                outcome = w.outcome()
                outcomes.append(outcome)
                progress.finish(outcome)
            now = time.monotonic()
            for w in running.values():
                if w.overdue(now):
                    w.kill(f"timed out after {limits.timeout_s:g} s (--timeout)")
    except BaseException:
        for w in running.values():
            w.interrupt()
        raise
    finally:
        sel.close()
    return outcomes
