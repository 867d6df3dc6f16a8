"""The Ray executor: the same per-log work as :mod:`fmcwlog.fleet.local`, as one Ray task per log.

Each task declares one CPU and ``--memory-limit`` of memory, so Ray places no more logs on a
node than its cores and memory hold; on its node it runs the log in a worker process of its
own (:func:`fmcwlog.fleet.local.run_one`: the same memory cap, timeout and one-line reasons)
into a temporary folder, and returns the results' files. The driver writes them under
``OUT/<name>`` (a temporary folder renamed when complete), so results land where the user
asked even when the nodes share no disk with it. Logs are read by the nodes at the paths
given: on a cluster they must be on storage every node sees at the same path.

A task whose node or Ray worker dies is retried by Ray (``retries`` times, then reported
failed with Ray's reason); a log that fails on its own (corrupt, timed out, out of memory)
is an outcome, not an exception, and is not retried: it would fail again.

``address``: None starts a local Ray with ``jobs`` CPUs (all, by default); anything else is
passed to ``ray.init(address=...)`` (``auto``, ``HOST:6379``, ``ray://HOST:10001``). A Ray
already initialised in this process (``ray.init`` called by the caller) is used as it is.
"""

from __future__ import annotations

import dataclasses
import logging
import socket
import tempfile
from pathlib import Path
from typing import Any

from ..errors import FmcwlogError
from ..io.atomic import atomic_folder
from .local import run_one
from .progress import Progress
from .tasks import Limits, LogOutcome, LogTask

_POLL_S = 0.5


def _ray() -> Any:
    try:
        import ray
    except ImportError:
        raise FmcwlogError("--ray needs Ray: pip install 'fmcwlog[ray]'") from None
    return ray


def process_on_node(task: LogTask, limits: Limits) -> tuple[LogOutcome, dict[str, bytes]]:
    """The Ray task: ``task`` in a worker on this node, into a temporary folder; the outcome and,
    when done, every file of the results by relative path."""
    with tempfile.TemporaryDirectory(prefix="fmcwlog-") as tmp:
        here = dataclasses.replace(task, out_dir=Path(tmp) / task.name, force=False)
        outcome = run_one(here, limits)
        outcome.host = socket.gethostname()
        files: dict[str, bytes] = {}
        if outcome.status == "done":
            for p in sorted(here.out_dir.rglob("*")):
                if p.is_file():
                    files[p.relative_to(here.out_dir).as_posix()] = p.read_bytes()
    return outcome, files


def _connect(ray: Any, address: str | None, jobs: int | None) -> bool:
    """Join or start Ray; True when this call started it (and so must stop it)."""
    if ray.is_initialized():
        return False
    quiet = {"logging_level": logging.WARNING, "log_to_driver": False}
    try:
        if address:
            ray.init(address=address, **quiet)
        else:
            ray.init(num_cpus=jobs, include_dashboard=False, **quiet)
    except (ConnectionError, RuntimeError, ValueError) as exc:
        where = address or "a local Ray"
        raise FmcwlogError(f"--ray {where}: cannot start or join it ({' '.join(str(exc).split())})") from None
    return True


def _check_memory(ray: Any, limits: Limits) -> None:
    """A task that no node can hold would wait for ever: say so instead."""
    need = limits.memory_limit_mb * 2**20
    if not need:
        return
    nodes = [n.get("Resources", {}) for n in ray.nodes() if n.get("Alive")]
    most = max((r.get("memory", 0) for r in nodes), default=0)
    if most < need:
        raise FmcwlogError(f"no Ray node has {limits.memory_limit_mb} MB of memory for one log (the largest offers "
                           f"{most / 2**20:.0f} MB); lower --memory-limit")


def _write(task: LogTask, files: dict[str, bytes]) -> None:
    with atomic_folder(task.out_dir, task.force, (task.log,), "fmcwlog process") as tmp:
        for rel, data in files.items():
            path = tmp / rel
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)


def _failed(task: LogTask, exc: BaseException, retries: int, retried: bool) -> LogOutcome:
    first = next((ln.strip() for ln in str(exc).splitlines() if ln.strip()), "")
    tries = f" (after {retries} retries)" if retries and retried else ""
    return LogOutcome(task.name, task.log, "failed", reason=f"Ray: {type(exc).__name__}{tries}: {first}"[:500],
                      detail=str(exc)[-4000:])


def run_on_ray(tasks: list[LogTask], limits: Limits, address: str | None, jobs: int | None, retries: int,
               progress: Progress) -> list[LogOutcome]:
    """Every task as a Ray task; outcomes in the order they end."""
    ray = _ray()
    started = _connect(ray, address, jobs)
    try:
        _check_memory(ray, limits)
        remote = ray.remote(process_on_node).options(
            num_cpus=1, memory=limits.memory_limit_mb * 2**20 or None, max_retries=retries, retry_exceptions=False)
        # absolute paths: a node's worker does not run in this process's folder
        pending = {remote.remote(dataclasses.replace(t, log=t.log.resolve(), out_dir=t.out_dir.resolve()), limits): t
                   for t in sorted(tasks, key=lambda t: -t.size_bytes)}
        outcomes: list[LogOutcome] = []
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=_POLL_S)
                for ref in ready:
                    task = pending.pop(ref)
                    outcome = _collect(ray, ref, task, retries)
                    outcomes.append(outcome)
                    progress.finish(outcome)
        except BaseException:
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
        return outcomes
    finally:
        if started:
            ray.shutdown()


def _collect(ray: Any, ref: Any, task: LogTask, retries: int) -> LogOutcome:
    try:
        outcome, files = ray.get(ref)
    except ray.exceptions.RayError as exc:
        # an exception inside the task is not retried (retry_exceptions=False); a dead worker or node is
        return _failed(task, exc, retries, retried=not isinstance(exc, ray.exceptions.RayTaskError))
    outcome.log = task.log
    if outcome.status == "done":
        try:
            _write(task, files)
        except (OSError, FmcwlogError) as exc:
            return LogOutcome(task.name, task.log, "failed", reason=f"{task.out_dir}: cannot write the results ({exc})",
                              host=outcome.host)
    return outcome

