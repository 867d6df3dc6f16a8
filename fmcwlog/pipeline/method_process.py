"""Two methods at once: ``process`` runs the costliest method in a child process.

The methods are independent: each has its front end, its map and its back end, and they
share only the log they read. With two or more methods asked and two or more CPUs usable
(``os.sched_getaffinity``), :func:`fmcwlog.pipeline.process.process` starts one child
(:class:`MethodProcess`) that runs the costliest method asked (``improved``,
:data:`COSTLIEST_FIRST`): front end and pose-graph back end. The parent runs the others
(``baseline``), reads the log and writes every output, so the two processes' shares are
close: the run's wall time is bounded by the larger, and the parent's adds the reading and
the outputs to the cheaper method's. The outputs stay byte for byte those of one process,
because the parent still writes every one of them, in the same order:

- each process reads the log itself (:class:`~fmcwlog.io.inputs.LogInputs`, the same inputs in
  the same order): a sweep decoded in the child costs it about what pickling it and sending it
  through a pipe cost the parent, and the parent is the busier of the two (2-minute corridor, both
  methods: wall 2.90 → 2.70 s, the same bytes). The reading's warnings are the parent's (the child
  drops its own); an error reading the log is raised by the parent where its methods reach it,
  and ends the child's inputs there (:class:`_InputsFailed`);
- per sweep the child sends its methods' :class:`~fmcwlog.types.SweepResult`\\ s, which join
  the parent's in the order of ``methods`` before the outputs take the sweep; each carries its
  ``processed.mcap`` messages encoded in the child (:class:`EncodedResult`) instead of its points,
  so the parent only writes their bytes; a back end's
  error on that sweep comes with them and is raised where the parent would have added the
  result to that back end (:class:`ChildBackend`); where both processes fail on the same
  sweep, the error raised is that of the method that comes first, which one process runs first;
- paths and maps are published at the sweeps :class:`~fmcwlog.io.outputs.ProcessOutputs`
  chooses, which depend on every map's size: the parent tells the child each next time, and
  at that sweep the child sends its front ends' maps as they stand (:class:`GridSnapshot`).
  The child never needs a time before a publishing period has passed since the last one, so
  it runs up to one ``publish_period`` of log ahead of the parent, no further;
- at the end it sends its back ends' results (optimised poses, closures, rebuilt maps) and
  its runner's diagnostics; the parent merges them in the order of ``methods``. Its own
  back ends finish first (the child's finishes meanwhile).

The child's errors reach the user as they would from one process (the same exception, raised
at the same point of the run, so the same one line and exit status 2); the log's own warnings
are the parent's (it reads the log), the estimation's warnings are forwarded with their sweep.
A child that dies without its results (killed, out of memory, crashed) is one line,
:class:`~fmcwlog.errors.MethodProcessError`. The parent ends the child on every way out
(done, an error, Ctrl-C: the child ignores SIGINT and is killed by the parent), and a child
whose parent dies is ended by the system (Linux) or by its next read or write of a closed pipe.
The child reads no file and writes none but the back end's unnamed temporary point store
(:mod:`fmcwlog.backend.point_store`): the output folder's atomicity is the parent's.

One process instead (``jobs=1``, ``fmcwlog process --jobs 1``): one CPU usable, one method
asked, and inside the fleet's workers (:mod:`fmcwlog.fleet.worker`: they run logs side by side
already). The outputs do not depend on it, so ``options_sha256`` does not either.

What it buys: the work is split, not added. With both processes pinned to one core, the
CPU seconds of parent and child add up to about one process's (120 s corridor, both methods and
the pose graph: 13.2-13.7 + 9.0-9.2 s against 22.7-26.4 s in one), so with two free cores the
wall time falls to about the parent's share; the measurements are in
``docs/design/method-process.md``.

How the child starts: ``fork`` where the system has it safely (Linux), else ``spawn`` (a fresh
interpreter importing numpy, scipy and the stages: about 1.2 s more a run).
"""

from __future__ import annotations

import dataclasses
import importlib
import os
import pickle
import queue
import signal
import sys
import threading
import traceback
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..allocator import keep_freed_memory
from ..backend import BackendResult, PoseGraphBackend
from ..errors import FmcwlogError, MethodProcessError
from ..io.clouds import CloudReading
from ..io.inputs import LogInputs
from ..io.logs import open_log
from ..io.outputs import ProcessOutputs, SweepMessages, sweep_messages
from ..kernels import compiled
from ..kernels.occupancy import OccupancyGrid
from ..types import BASELINE, IMPROVED, Calibration, InputTopics, OdomInput, SweepInput, SweepResult, TicksInput
from .children import die_with_parent
from .params import ProcessParams
from .runner import LogRunner, SweepStep

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

START_METHOD = "fork" if sys.platform.startswith("linux") else "spawn"  # numbers in the module docstring
_JOIN_S = 5.0  # s to wait for a child that was told to end, or has ended, before it is killed


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity where the system says, else the machine's)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


# the methods by their CPU a sweep, costliest first (a 120 s corridor, compiled kernels, front end + back
# end: improved 2.0 s, baseline 1.4 s); the child runs the costliest, the parent the rest and the outputs
COSTLIEST_FIRST = (IMPROVED, BASELINE)


def child_methods(methods: tuple[str, ...], jobs: int | None) -> tuple[str, ...]:
    """The methods to run in a child process: the costliest (:data:`COSTLIEST_FIRST`), when there
    are several and ``jobs`` allows two processes (None: when two or more CPUs are usable); else none."""
    if len(methods) < 2 or jobs == 1 or (jobs is None and usable_cpus() < 2):
        return ()
    rank = {m: i for i, m in enumerate(COSTLIEST_FIRST)}
    return (min(methods, key=lambda m: rank.get(m, len(rank))),)


@dataclass(frozen=True)
class ChildTask:
    """What the child runs: ``methods`` over the inputs of ``log`` read on ``topics`` as ``reading``
    says (:class:`~fmcwlog.io.clouds.CloudReading`), with ``cal`` and ``params``, each with a
    pose-graph back end if ``backend``; paths and maps are published no more often than every
    ``publish_period_ns`` of log."""

    log: Path
    methods: tuple[str, ...]
    params: ProcessParams
    cal: Calibration
    topics: InputTopics
    backend: bool
    publish_period_ns: int
    reading: CloudReading
    order: tuple[str, ...] = ()  # every method of the run, as the outputs take them (default: ``methods``)

    def rank(self, method: str) -> int:
        """``method``'s place in :attr:`order`."""
        return (self.order or self.methods).index(method)


@dataclass(frozen=True)
class GridSnapshot:
    """A front end's occupancy grid as the outputs publish it (``/M/map``), taken in the child."""

    resolution: float
    width: int
    height: int
    origin: np.ndarray
    data: np.ndarray  # nav_msgs/OccupancyGrid data, int8

    @classmethod
    def of(cls, grid: OccupancyGrid) -> GridSnapshot:
        return cls(grid.resolution, grid.width, grid.height, grid.origin, grid.to_ros_int8())

    def to_ros_int8(self) -> np.ndarray:
        return self.data


_NO_POINTS, _NO_LABELS = np.zeros((0, 2)), np.zeros(0, bool)


@dataclass(frozen=True)
class EncodedResult(SweepResult):
    """A result of the child's with its ``processed.mcap`` messages encoded there
    (:func:`~fmcwlog.io.outputs.sweep_messages`), in place of the points and covariances they
    came from: the parent writes the bytes, and neither encodes nor pickles the clouds twice."""

    messages: SweepMessages = dataclasses.field(default_factory=list)

    @classmethod
    def of(cls, r: SweepResult) -> EncodedResult:
        light = dataclasses.replace(r, twist_covariance=None, pose_covariance=None, static_map_xy=_NO_POINTS,
                                    static_velocity=None, moving_map_xy=_NO_POINTS, moving_velocity=None,
                                    moving_mask=_NO_LABELS)
        return cls(**{f.name: getattr(light, f.name) for f in dataclasses.fields(SweepResult)},
                   messages=sweep_messages(r))


@dataclass
class _Sweep:
    """The child's message for one sweep."""

    stamp_ns: int
    results: list[SweepResult]
    maps: dict[str, GridSnapshot] | None  # when this sweep publishes
    warnings: list[tuple[str, type[Warning]]]
    backend_error: tuple[str, BaseException] | None = None  # a back end's add() raised on this sweep


@dataclass
class _End:
    """The child's last message: back-end results, final front-end grids, diagnostics."""

    backends: dict[str, BackendResult]
    grids: dict[str, OccupancyGrid]
    diagnostics: tuple[dict, list[str]]
    warnings: list[tuple[str, type[Warning]]]


@dataclass
class _Error:
    """The child raised ``error`` (its traceback as text, for errors that are bugs)."""

    error: BaseException
    trace: str


class ChildBackend:
    """Stands in the parent for a back end that runs in the child: :meth:`add` raises the error
    the child's back end raised on that sweep, :meth:`finish` returns the child's result."""

    def __init__(self, method: str, process: MethodProcess):
        self.method, self.process = method, process
        self.error: BaseException | None = None

    def add(self, r: SweepResult) -> None:
        if self.error is not None:
            raise self.error

    def finish(self) -> BackendResult:
        return self.process.end().backends[self.method]


class MethodProcess:
    """``task.methods`` in a child process (module docstring). Use as a context manager: leaving
    it ends the child, however the run ends."""

    def __init__(self, task: ChildTask):
        self.task = task
        self.methods = task.methods
        self.sweeps = 0
        self._end: _End | None = None
        self._last: _End | None = None  # the last message, taken by steps() at the end of the log
        if START_METHOD == "fork":  # what both processes load, loaded once, before the fork (gtsam: at a first solve)
            importlib.import_module("fmcwlog.backend.pipeline")
            if compiled.core() is None:  # the numpy kernels' KD-trees (scipy.spatial: 0.25 s of imports)
                importlib.import_module("scipy.spatial")
        ctx = get_context(START_METHOD)
        results_in, results_out = ctx.Pipe(duplex=False)
        schedule_in, schedule_out = ctx.Pipe(duplex=False)
        own_ends = (results_in, schedule_out) if START_METHOD == "fork" else ()
        self._proc = ctx.Process(target=  # type: ignore[attr-defined]  # typeshed's BaseContext lacks it
                                 _child_main, args=(task, results_out, schedule_in, own_ends),
                                 name=f"fmcwlog {'+'.join(task.methods)}", daemon=True)
        # SIGINT blocked while it starts (the child inherits the mask, then ignores SIGINT): Ctrl-C
        # is the parent's to handle, and it ends the child
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            self._proc.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)
        results_out.close()
        schedule_in.close()
        self._schedule = schedule_out
        self._inbox: queue.Queue = queue.Queue()
        # read as the child sends, so that it never waits for the parent to make room in the pipe
        self._reader = threading.Thread(target=_read_all, args=(results_in, self._inbox), daemon=True)
        self._reader.start()
        self.backends = {m: ChildBackend(m, self) for m in task.methods}

    def __enter__(self) -> MethodProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """End the child (killed unless it sent its results and ends by itself) and wait for it."""
        self._schedule.close()
        self._proc.join(_JOIN_S if self._end is not None else 0)
        if self._proc.exitcode is None:
            self._proc.kill()
            self._proc.join()
        self._reader.join()

    def steps(self, local: Iterable[SweepStep], maps: dict, outputs: ProcessOutputs) -> Iterator[SweepStep]:
        """``local``'s steps with the child's results of each sweep joined in the order of
        ``task.order``. ``maps`` (the grids ``outputs`` publish) gets the child's maps at the sweeps
        they publish; after each sweep that published, the child is told the outputs' next
        publishing time."""
        local = iter(local)
        while True:
            try:
                step = next(local, None)
            except Exception:
                self._raise_if_first()
                raise
            try:
                msg = self._receive()
            except _InputsFailed:  # the child could not read what this process read
                raise self._out_of_step("reading the log") from None
            if step is None:
                if not isinstance(msg, _End):
                    raise self._out_of_step("the end of the log")
                self._last = msg  # its warnings said by end(), after the parent's own
                return
            if not isinstance(msg, _Sweep) or msg.stamp_ns != step.sweep.stamp_ns:
                raise self._out_of_step(f"sweep {step.sweep.stamp_ns} ns")
            self.sweeps += 1
            maps.update(msg.maps or {})
            for text, category in msg.warnings:
                warnings.warn(text, category, stacklevel=1)
            if msg.backend_error is not None:
                method, error = msg.backend_error
                self.backends[method].error = error
            publishes = outputs.publishes
            yield self._merged(step, msg.results)
            published = outputs.publishes > publishes
            if published != (msg.maps is not None):  # published without the child's maps, or the reverse
                raise self._out_of_step(f"the maps at {step.sweep.stamp_ns} ns")
            if published:
                try:
                    self._schedule.send(outputs.next_publish_ns)
                except OSError:  # the child has ended: the next message says how
                    pass

    def _raise_if_first(self) -> None:
        """Where this process failed on a sweep: the child's error on the same sweep, if its method
        comes first (in one process it runs first, so its error is the one raised); where the child's
        inputs ended there too (reading the log failed for both), this process's own error stands."""
        if self.task.rank(self.methods[0]) == 0:
            try:
                self._receive()  # its next message: that sweep's results, or its error (raised)
            except _InputsFailed:
                pass

    def end(self) -> _End:
        """The child's back ends, grids and diagnostics (waiting for them)."""
        if self._end is None:
            msg = self._last or self._receive()
            if not isinstance(msg, _End):
                raise self._out_of_step("the end of the log")
            self._end = msg
            for text, category in msg.warnings:
                warnings.warn(text, category, stacklevel=1)
        return self._end

    def _merged(self, step: SweepStep, results: list[SweepResult]) -> SweepStep:
        """``step`` with ``results`` (the child's) among its own, in the order of ``task.order``."""
        joined = sorted([*step.results, *results], key=lambda r: self.task.rank(r.method))
        return SweepStep(step.sweep, joined, step.wheel_pose, step.wheel_twist)

    def _receive(self) -> _Sweep | _End:
        msg = self._inbox.get()
        if isinstance(msg, _Error) and isinstance(msg.error, _InputsFailed):  # reading the log failed there
            raise msg.error
        if isinstance(msg, _Error):  # raised as one process would have: an FmcwlogError is one line
            if not isinstance(msg.error, FmcwlogError):  # a bug: where it was, in the child
                msg.error.add_note(f"raised in {self._who()}:\n{msg.trace}")
            raise msg.error
        if msg is None:  # the pipe closed without a last message: the child died
            self._inbox.put(None)  # and says so again to any later call
            self._proc.join(_JOIN_S)
            raise MethodProcessError(f"{self.task.log}: {self._who()} ended without its results "
                                     f"({_exit_reason(self._proc.exitcode)}) after sweep {self.sweeps}; "
                                     "--jobs 1 runs every method in one process")
        if isinstance(msg, str):  # a message that could not be read back
            raise MethodProcessError(f"{self.task.log}: {self._who()} sent what cannot be read ({msg})")
        return msg

    def _who(self) -> str:
        return f"the process running {' and '.join(self.methods)}"

    def _out_of_step(self, what: str) -> MethodProcessError:
        return MethodProcessError(f"{self.task.log}: {self._who()} is out of step with this one at {what} "
                                  "(a bug in fmcwlog; --jobs 1 runs every method in one process)")


class _InputsFailed(Exception):
    """Raised in the child where reading the log fails; the parent, reading the same log, raises its
    own error there."""


def _exit_reason(code: int | None) -> str:
    if code is None:
        return "still running"
    if code < 0:
        name = signal.Signals(-code).name if -code in signal.valid_signals() else str(-code)
        oom = ", which the system's out-of-memory killer sends" if -code == signal.SIGKILL else ""
        return f"killed by {name}{oom}"
    return f"exit status {code}"


def _read_all(conn: Connection, inbox: queue.Queue) -> None:
    """Every message of the child into ``inbox``, then None when its end of the pipe closes."""
    try:
        while True:
            try:
                inbox.put(conn.recv())
            except (EOFError, OSError):
                break
            except Exception as exc:  # noqa: BLE001 (a message that does not unpickle: said, then ended)
                inbox.put(f"{type(exc).__name__}: {exc}")
                break
    finally:
        conn.close()
        inbox.put(None)


# --- the child ------------------------------------------------------------------------------


def _child_main(task: ChildTask, out: Connection, schedule: Connection, own_ends: tuple) -> None:
    """The child process: runs the task, sends its messages, and ends quietly however it ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)  # not the command line's (fork copies it): a SIGTERM ends us
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    for conn in own_ends:  # the parent's ends, copied by fork: the pipes close when the parent dies
        conn.close()
    die_with_parent()
    try:
        _run(task, out, schedule)
    except (BrokenPipeError, EOFError, ConnectionResetError):  # the parent is gone, or done with us
        pass
    except BaseException as exc:  # noqa: BLE001 (every error goes to the parent, which raises it)
        _send_error(out, exc)
    finally:
        out.close()


def _send_error(out: Connection, exc: BaseException) -> None:
    trace = "".join(traceback.format_exception(exc))
    try:
        pickle.loads(pickle.dumps(exc))  # the parent must be able to rebuild it
    except Exception:  # noqa: BLE001
        exc = RuntimeError(f"{type(exc).__name__}: {exc}")
    try:
        out.send(_Error(exc, trace))
    except OSError:
        pass


def _run(task: ChildTask, out: Connection, schedule: Connection) -> None:
    keep_freed_memory()
    runner = LogRunner(task.methods, task.params, task.cal, task.topics, task.log)
    backends = {m: PoseGraphBackend(task.params.backend, np.asarray(task.cal.mount), task.params.map_resolution)
                for m in task.methods} if task.backend else {}
    publish = _Schedule(schedule, task.publish_period_ns)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for step in runner.run(_inputs(task)):
            msg = _Sweep(step.sweep.stamp_ns, step.results, None, [])
            for r in step.results:
                try:
                    if r.method in backends:
                        backends[r.method].add(r)
                except Exception as exc:  # noqa: BLE001 (raised in the parent where it adds the result)
                    msg.backend_error = (r.method, exc)
                    break
            msg.results = [EncodedResult.of(r) for r in step.results]  # after the back ends took them whole
            if publish.due(step.sweep.stamp_ns):
                msg.maps = {fe.name: GridSnapshot.of(fe.grid) for fe in runner.fronts}
            msg.warnings = _taken(caught)
            out.send(msg)
            if msg.backend_error is not None:
                return
        results = {m: be.finish() for m, be in backends.items()}
        grids = {} if backends else {fe.name: fe.grid for fe in runner.fronts}  # the outputs' final maps
        for grid in [*grids.values(), *(res.grid for res in results.values())]:
            grid.flush()  # cast here, not in the parent; pickled without the scans it was waiting for
        out.send(_End(results, grids, runner.diagnostics(), _taken(caught)))


def _taken(caught: list[warnings.WarningMessage]) -> list[tuple[str, type[Warning]]]:
    taken = [(str(w.message), w.category) for w in caught]
    caught.clear()
    return taken


def _inputs(task: ChildTask) -> Iterator[SweepInput | TicksInput | OdomInput]:
    """The log's inputs, read here as the parent reads them; the reading's warnings dropped (the
    parent's say them), an error reading it :class:`_InputsFailed` (the parent's is raised)."""
    items: Iterator[SweepInput | TicksInput | OdomInput] | None = None
    while True:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                if items is None:  # opened here too: what opening the log says, the parent said
                    items = iter(LogInputs(open_log(task.log), task.topics, task.cal, task.reading))
                item = next(items)
            except StopIteration:
                return
            except Exception:  # noqa: BLE001 (the parent's reading raises it)
                raise _InputsFailed from None
        yield item


class _Schedule:
    """When the outputs publish the maps, as the child learns it: first one period after the first
    sweep (:meth:`~fmcwlog.io.outputs.ProcessOutputs.add`), then never sooner than a period after
    the last time; the exact time is the parent's, asked for when that much log has passed."""

    def __init__(self, conn: Connection, period_ns: int):
        self.conn, self.period_ns = conn, period_ns
        self.earliest: int | None = None
        self.next: int | None = None

    def due(self, stamp_ns: int) -> bool:
        if self.earliest is None:  # the first sweep
            self.earliest = self.next = stamp_ns + self.period_ns
        if stamp_ns < self.earliest:
            return False
        if self.next is None:
            self.next = self.conn.recv()  # waits for the parent to reach the last publishing sweep
        assert self.next is not None
        if stamp_ns < self.next:
            return False
        self.earliest, self.next = stamp_ns + self.period_ns, None
        return True


def merge_diagnostics(first: tuple[dict, list[str]], rest: tuple[dict, list[str]]) -> tuple[dict, list[str]]:
    """Two runners' :meth:`~fmcwlog.pipeline.runner.LogRunner.diagnostics`, ``first``'s methods first."""
    (a, a_notes), (b, b_notes) = first, rest
    merged = {**b, **a, "motion_sources": {**a["motion_sources"], **b["motion_sources"]},
              "jumps": {**a.get("jumps", {}), **b.get("jumps", {})}}
    return merged, a_notes + b_notes
