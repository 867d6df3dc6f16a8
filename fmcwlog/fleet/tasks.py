"""A batch's unit of work (one log into one folder) and what became of it; no heavy imports here,
since a worker reads these before its memory cap is in place."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

Status = Literal["done", "skipped", "failed"]


@dataclass(frozen=True)
class Limits:
    """What one log may take.

    memory_limit_mb: the worker's address-space cap (MB, ``RLIMIT_AS``; 0: none). A worker
        maps about 1.7 GB of address space for about 250 MB resident (libraries, thread
        stacks), so a cap below about 2000 MB fails every log. On Ray each task also
        declares this much memory.
    timeout_s: wall-clock seconds after which the worker is killed (0: none).
    """

    memory_limit_mb: int = 4096
    timeout_s: float = 0.0


@dataclass(frozen=True)
class LogTask:
    """Process ``log`` into ``out_dir`` (``OUT/<name>``) with ``options``
    (an :class:`fmcwlog.pipeline.options.ProcessOptions`)."""

    name: str
    log: Path
    out_dir: Path
    options: Any
    force: bool
    size_bytes: int


@dataclass
class LogOutcome:
    """What became of one log: ``reason`` says why it failed or was skipped, in one line;
    ``detail`` keeps the end of a failed worker's stderr (a traceback) for batch.json."""

    name: str
    log: Path
    status: Status
    reason: str | None = None
    sweeps: int = 0
    wall_s: float = 0.0
    host: str | None = None
    detail: str | None = None
    summary: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"log": str(self.log), "status": self.status, "reason": self.reason, "sweeps": self.sweeps,
                "wall_s": round(self.wall_s, 3), "host": self.host, "detail": self.detail, **self.summary}
