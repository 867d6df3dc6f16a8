"""A batch from the command line's paths to every log's outcome: plan, run, record.

Plan: find the logs (:mod:`~fmcwlog.fleet.inputs`), give each its folder ``OUT/<name>``,
and decide per log: skip it (its results are complete, from the same bytes and options:
:mod:`~fmcwlog.fleet.state`), redo it (an older ``fmcwlog process`` output, made from
another log or other options, is replaced once the new one is complete), refuse it (the
folder holds something that is not an fmcwlog output: only ``--force`` replaces that), or
do it. Run the rest on the chosen executor. Record each outcome in ``OUT/batch.json`` as
it arrives, so that a batch stopped half-way still says what it did.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .. import __version__
from ..errors import ConfigError, OutputError
from ..io.atomic import remove_stale_partials
from ..io.digest import log_size
from ..pipeline.options import ProcessOptions, options_digest
from .inputs import LOG_PATTERNS, find_logs, unique_names
from .local import run_local
from .progress import Progress
from .state import (
    BATCH_SCHEMA,
    completeness,
    follow_renamed,
    is_fmcwlog_output,
    read_batch,
    write_batch,
)
from .tasks import Limits, LogOutcome, LogTask

logger = logging.getLogger(__name__)

MIN_MEMORY_LIMIT_MB = 1024  # the libraries alone map about 600 MB; below that a worker cannot even start


@dataclass
class BatchSummary:
    """Every log's outcome, in the order the logs were found."""

    out_dir: Path
    outcomes: list[LogOutcome]
    wall_s: float
    executor: str

    def count(self, status: str) -> int:
        return sum(o.status == status for o in self.outcomes)

    @property
    def failed(self) -> list[LogOutcome]:
        return [o for o in self.outcomes if o.status == "failed"]

    @property
    def sweeps(self) -> int:
        return sum(o.sweeps for o in self.outcomes if o.status == "done")


def default_jobs() -> int:
    """The cores this process may run on (its CPU affinity, which containers and taskset narrow)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def check_limits(limits: Limits, jobs: int | None) -> None:
    if jobs is not None and jobs < 1:
        raise ConfigError(f"--jobs must be at least 1, not {jobs}")
    if limits.memory_limit_mb and limits.memory_limit_mb < MIN_MEMORY_LIMIT_MB:
        raise ConfigError(f"--memory-limit must be 0 (none) or at least {MIN_MEMORY_LIMIT_MB} MB, not "
                          f"{limits.memory_limit_mb}: a worker maps about 600 MB of libraries before it reads a log")
    if limits.timeout_s < 0:
        raise ConfigError(f"--timeout must be 0 (none) or positive, not {limits.timeout_s:g}")


def plan(paths: Sequence[str | os.PathLike], out_dir: Path, options: Any, force: bool,
         jobs: int) -> tuple[list[LogTask], list[LogOutcome], list[str]]:
    """The tasks to run, the outcomes already known (skipped, refused), and every log's name in order."""
    if out_dir.exists() and not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a folder")
    logs = find_logs(paths, LOG_PATTERNS, skip=out_dir)
    names = unique_names(logs, LOG_PATTERNS)
    digest = options_digest(options)
    removed = remove_stale_partials(out_dir, set(names))
    for p in removed:
        logger.info("removed %s, left by a worker that no longer runs", p)
    for old, new in follow_renamed(out_dir, logs, names):
        logger.info("moved %s to %s: another log now shares its name", old, new)

    def decide(item: tuple[Path, str]) -> LogTask | LogOutcome:
        log, name = item
        target = out_dir / name
        size = log_size(log)
        if force or not target.exists():
            return LogTask(name, log, target, options, True, size)
        complete, why = completeness(target, log, digest)
        if complete:
            return LogOutcome(name, log, "skipped", reason="complete: the same log and options as before")
        if is_fmcwlog_output(target) or (target.is_dir() and not any(target.iterdir())):
            if is_fmcwlog_output(target):
                logger.info("%s: redoing %s (%s)", log, target, why)
            return LogTask(name, log, target, options, True, size)
        return LogOutcome(name, log, "failed",
                          reason=f"{target}: exists and is not a 'fmcwlog process' output; use --force to replace it")

    with ThreadPoolExecutor(max_workers=max(jobs, 1)) as pool:  # hashing many logs: I/O bound, hashlib frees the GIL
        decided = list(pool.map(decide, zip(logs, names)))
    tasks = [d for d in decided if isinstance(d, LogTask)]
    known = [d for d in decided if isinstance(d, LogOutcome)]
    return tasks, known, names


class _Record:
    """``OUT/batch.json``, rewritten (atomically) as each outcome arrives."""

    def __init__(self, out_dir: Path, options: Any, executor: str):
        self.out_dir = out_dir
        self.doc = read_batch(out_dir)
        self.doc.update(schema=BATCH_SCHEMA, fmcwlog_version=__version__, options_sha256=options_digest(options),
                        executor=executor, started=datetime.now(UTC).isoformat(timespec="seconds"))
        self.started = time.monotonic()

    def add(self, outcome: LogOutcome) -> None:
        self.doc["logs"][outcome.name] = outcome.as_dict()
        self.doc["wall_s"] = round(time.monotonic() - self.started, 3)
        write_batch(self.out_dir, self.doc)


def process_many(paths: Sequence[str | os.PathLike], out_dir: str | os.PathLike, opts: ProcessOptions | None = None,
                 force: bool = False, jobs: int | None = None, limits: Limits | None = None, ray: bool = False,
                 ray_address: str | None = None, retries: int = 2,
                 on_progress: Callable[[Progress], None] | None = None) -> BatchSummary:
    """:func:`~fmcwlog.pipeline.process.process` every log that ``paths`` name (files, rosbag2 folders, or
    folders searched for ``*.mcap``, ``*.bag`` and rosbag2 folders), each into ``out_dir/<name>`` in a
    worker process of its own; see :mod:`fmcwlog.fleet`.

    ``jobs`` workers at a time (default: every core); ``limits``: each log's memory cap and
    timeout. Logs whose results are complete from the same bytes and options are skipped
    unless ``force``. ``ray``: run them as Ray tasks instead (``ray_address`` None starts a
    local Ray; ``retries``: Ray's retries of a task whose worker or node died). A log that
    fails is an outcome with its reason (``summary.failed``), not an exception; the
    exceptions are for the batch as a whole (no logs found, bad limits, Ray unreachable).
    """
    options = opts or ProcessOptions()
    limits = limits or Limits()
    check_limits(limits, jobs)
    out_dir = Path(out_dir)
    executor = "ray" if ray else "local"
    tasks, known, names = plan(paths, out_dir, options, force, jobs or default_jobs())
    created = [d for d in (out_dir, *out_dir.parents) if not d.exists()]  # deepest first
    out_dir.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    try:
        record = _Record(out_dir, options, executor)
        for o in known:
            record.add(o)
        progress = Progress(tasks, on_progress, on_outcome=record.add)
        if not tasks:
            ran: list[LogOutcome] = []
        elif ray:
            from .ray_executor import run_on_ray

            ran = run_on_ray(tasks, limits, ray_address, jobs, retries, progress)
        else:
            ran = run_local(tasks, limits, min(jobs or default_jobs(), len(tasks)), progress)
    except BaseException:  # Ctrl-C before any log ended: leave no empty folder of ours (a finished log's stays, to resume)
        for folder in created:
            if any(folder.iterdir()):
                break
            folder.rmdir()
        raise
    wall = time.monotonic() - started
    by_name = {o.name: o for o in (*known, *ran)}
    order = {name: i for i, name in enumerate(names)}
    outcomes = sorted(by_name.values(), key=lambda o: order.get(o.name, len(order)))
    return BatchSummary(out_dir, outcomes, wall, executor)
