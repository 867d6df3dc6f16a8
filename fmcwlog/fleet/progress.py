"""How far a batch has got, for a progress bar: logs done and failed, sweeps per second over all
workers, and the time left, estimated from the bytes of log behind and ahead (logs differ in
length, so a count of logs would mislead)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from .tasks import LogOutcome, LogTask


@dataclass
class Progress:
    """Updated by an executor; ``on_outcome(outcome)`` is called as each log ends, then
    ``listener(self)`` after every change."""

    tasks: list[LogTask]
    listener: Callable[[Progress], None] | None = None
    on_outcome: Callable[[LogOutcome], None] | None = None
    started_at: float = field(default_factory=time.monotonic)
    done: int = 0
    failed: int = 0
    finished_sweeps: int = 0
    finished_bytes: int = 0
    running: dict[str, tuple[int, int | None]] = field(default_factory=dict)  # name -> sweeps done, total
    last: LogOutcome | None = None  # the log that ended most recently (for a line per log where no bar is drawn)

    def __post_init__(self) -> None:
        self._size = {t.name: t.size_bytes for t in self.tasks}
        self.total_bytes = sum(self._size.values())

    @property
    def total(self) -> int:
        return len(self.tasks)

    @property
    def finished(self) -> int:
        return self.done + self.failed

    def sweeps(self, name: str, done: int, total: int | None) -> None:
        self.running[name] = (done, total)
        self._tell()

    def finish(self, outcome: LogOutcome) -> None:
        if self.on_outcome is not None:
            self.on_outcome(outcome)
        self.running.pop(outcome.name, None)
        self.last = outcome
        if outcome.status == "failed":
            self.failed += 1
        else:
            self.done += 1
        self.finished_sweeps += outcome.sweeps
        self.finished_bytes += self._size.get(outcome.name, 0)
        self._tell()

    @property
    def elapsed_s(self) -> float:
        return time.monotonic() - self.started_at

    @property
    def sweeps_done(self) -> int:
        return self.finished_sweeps + sum(d for d, _ in self.running.values())

    @property
    def sweeps_per_s(self) -> float:
        return self.sweeps_done / max(self.elapsed_s, 1e-9)

    @property
    def eta_s(self) -> float | None:
        """Seconds left at the rate so far (None until some work is done)."""
        behind = self.finished_bytes + sum(self._size.get(n, 0) * d / t for n, (d, t) in self.running.items() if t)
        if behind <= 0:
            return None
        return self.elapsed_s * max(self.total_bytes - behind, 0) / behind

    def _tell(self) -> None:
        if self.listener is not None:
            self.listener(self)
