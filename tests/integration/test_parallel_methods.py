"""Two methods in two processes (fmcwlog.pipeline.method_process): the same bytes as one process, the same
errors, nothing left behind.

The reference is the same run in one process (``jobs=1``), compared file by file: bytes, except
the timings (the parquet's ``ms`` column, run.json's seconds), read with plain pyarrow and json.
Failures are injected by patching a front end or back end in this process: the child (the improved
method) is forked, so it runs the patched code (the tests that need that skip where fork is not used);
the baseline runs in the parent.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from helpers import assert_one_line_error, record_scenario, run_cli_here

from fmcwlog.api import ProcessOptions, process
from fmcwlog.backend import PoseGraphBackend
from fmcwlog.errors import LogError, MapSizeError, MethodProcessError, OutputError
from fmcwlog.frontend.methods import BaselineFrontEnd, ImprovedFrontEnd
from fmcwlog.io.inputs import LogInputs
from fmcwlog.pipeline import method_process

TIMINGS = {"wall_seconds", "seconds", "ms_per_sweep_median"}
needs_fork = pytest.mark.skipif(method_process.START_METHOD != "fork",
                                reason="failures are injected by patching code the forked child inherits")


def _without_timings(doc):
    if isinstance(doc, dict):
        return {k: _without_timings(v) for k, v in doc.items() if k not in TIMINGS}
    if isinstance(doc, list):
        return [_without_timings(v) for v in doc]
    return doc


def assert_same_outputs(a: Path, b: Path) -> None:
    names = sorted(p.name for p in a.iterdir())
    assert names == sorted(p.name for p in b.iterdir())
    assert "processed.mcap" in names and "baseline_map.pgm" in names
    for name in names:
        x, y = a / name, b / name
        if name.endswith(".parquet"):
            tx, ty = pq.read_table(x), pq.read_table(y)
            assert tx.schema.equals(ty.schema, check_metadata=True) and tx.drop(["ms"]).equals(ty.drop(["ms"])), name
        elif name.endswith(".json"):
            assert _without_timings(json.loads(x.read_text())) == _without_timings(json.loads(y.read_text())), name
        else:
            assert x.read_bytes() == y.read_bytes(), name


def _count_children(monkeypatch) -> list:
    started = []
    init = method_process.MethodProcess.__init__

    def counting(self, task):
        started.append(task.methods)
        init(self, task)

    monkeypatch.setattr(method_process.MethodProcess, "__init__", counting)
    return started


def _no_children_left() -> None:
    assert multiprocessing.active_children() == []


@pytest.mark.slow
@pytest.mark.parametrize("backend, period", [("pose-graph", 1.0), ("none", 0.5), ("pose-graph", 0.0)])
def test_two_processes_write_the_bytes_of_one(crowd_log, tmp_path, monkeypatch, backend, period):
    """Every output (processed.mcap's interleaving of methods and published maps included) is the
    one-process run's; publishing every sweep, half or whole second exercises the maps' schedule."""
    started = _count_children(monkeypatch)
    opts = ProcessOptions(backend=backend, publish_period=period)
    one = process(crowd_log, tmp_path / "one", opts, jobs=1)
    assert started == []
    two = process(crowd_log, tmp_path / "two", opts, jobs=2)
    assert started == [("improved",)]
    assert_same_outputs(tmp_path / "one", tmp_path / "two")
    assert (one.sweeps, one.warnings, one.backend.keys()) == (two.sweeps, two.warnings, two.backend.keys())
    _no_children_left()


@pytest.mark.slow
def test_spawned_child_writes_the_same_bytes(crowd_log, tmp_path, monkeypatch):
    """Where fork is not available the child is a fresh interpreter (spawn): the same outputs."""
    monkeypatch.setattr(method_process, "START_METHOD", "spawn")
    process(crowd_log, tmp_path / "one", jobs=1)
    process(crowd_log, tmp_path / "two", jobs=2)
    assert_same_outputs(tmp_path / "one", tmp_path / "two")


def test_one_process_where_one_method_or_one_cpu_or_asked(monkeypatch):
    both = ("improved", "baseline")
    monkeypatch.setattr(method_process, "usable_cpus", lambda: 1)
    assert method_process.child_methods(both, None) == ()
    assert method_process.child_methods(both, 2) == ("improved",)  # asked for
    monkeypatch.setattr(method_process, "usable_cpus", lambda: 2)
    assert method_process.child_methods(both, None) == ("improved",)  # the costliest, whatever the order
    assert method_process.child_methods(both[::-1], None) == ("improved",)
    assert method_process.child_methods(both, 1) == ()
    assert method_process.child_methods(("baseline",), None) == ()
    assert method_process.child_methods(("improved",), 4) == ()


def test_fleet_workers_run_their_methods_in_one_process():
    """The fleet's workers fill the cores with logs: each runs its methods in its own process alone."""
    source = (Path(method_process.__file__).parents[1] / "fleet" / "worker.py").read_text()
    assert "process(task.log, task.out_dir, task.options, force=task.force, on_sweep=on_sweep, jobs=1)" in source


FRONT_ENDS = {"improved": ImprovedFrontEnd, "baseline": BaselineFrontEnd}


def _fail_at(monkeypatch, sweep: int, error: BaseException, method: str = "improved") -> None:
    """Make ``method``'s front end raise ``error`` on its ``sweep``-th sweep (counted in the process
    that runs it: the child inherits the count, 0, when it is forked)."""
    front = FRONT_ENDS[method]
    original = front.step
    calls = [0]

    def failing(self, *args):
        calls[0] += 1
        if calls[0] == sweep:
            raise error
        return original(self, *args)

    monkeypatch.setattr(front, "step", failing)


def _error_of(log: Path, out: Path, jobs: int) -> BaseException:
    with pytest.raises(Exception) as info:
        process(log, out, jobs=jobs)
    assert not out.exists() and not [p for p in out.parent.iterdir() if p.name.startswith(".")], "half-written"
    return info.value


@pytest.mark.slow
@needs_fork
@pytest.mark.parametrize("error", [LogError("a damaged sweep"), MapSizeError("the map is too large"),
                                   ValueError("a bug")])
@pytest.mark.parametrize("method", ["improved", "baseline"])  # in the child, in the parent
def test_front_end_error_is_the_one_process_error(crowd_log, tmp_path, monkeypatch, error, method):
    with monkeypatch.context() as patch:
        _fail_at(patch, 7, error, method)
        one = _error_of(crowd_log, tmp_path / "one", 1)
    with monkeypatch.context() as patch:
        _fail_at(patch, 7, error, method)
        two = _error_of(crowd_log, tmp_path / "two", 2)
    assert (type(two), str(two)) == (type(one), str(one))
    if isinstance(error, MapSizeError):  # as in one process: about this log
        assert str(two) == f"{crowd_log}: the map is too large"
    _no_children_left()


@pytest.mark.slow
@needs_fork
@pytest.mark.parametrize("sweeps", [(7, 7), (8, 7), (7, 8)])  # (improved's, baseline's) failing sweep
def test_of_two_errors_the_first_is_the_one_process_error(crowd_log, tmp_path, monkeypatch, sweeps):
    """Both methods fail: the one that fails first in one process (the earlier sweep; on the same sweep
    the improved, which runs first there), not the one whose process got there first."""
    got = []
    for jobs in (1, 2):
        with monkeypatch.context() as patch:
            _fail_at(patch, sweeps[0], LogError("improved failed"), "improved")
            _fail_at(patch, sweeps[1], LogError("baseline failed"), "baseline")
            got.append(str(_error_of(crowd_log, tmp_path / f"out{jobs}", jobs)))
    assert got[0] == got[1] == ("improved failed" if sweeps[0] <= sweeps[1] else "baseline failed")
    _no_children_left()


@pytest.mark.slow
@needs_fork
@pytest.mark.parametrize("method", ["improved", "baseline"])
def test_back_end_error_is_the_one_process_error(crowd_log, tmp_path, monkeypatch, method):
    error = OutputError("/tmp: cannot keep fmcwlog's temporary point store: no space left on device")
    original = PoseGraphBackend.add
    for jobs in (1, 2):
        calls = [0]

        def failing(self, r, calls=calls):
            if r.method == method:
                calls[0] += 1
                if calls[0] == 9:
                    raise error
            return original(self, r)

        with monkeypatch.context() as patch:
            patch.setattr(PoseGraphBackend, "add", failing)
            got = _error_of(crowd_log, tmp_path / f"out{jobs}", jobs)
        assert type(got) is OutputError and str(got) == str(error)
    _no_children_left()


@pytest.mark.slow
@needs_fork
def test_a_child_that_dies_is_one_line_and_exit_status_2(crowd_log, tmp_path, monkeypatch):
    parent = os.getpid()
    original = ImprovedFrontEnd.step

    def dying(self, *args):
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)
        return original(self, *args)

    monkeypatch.setattr(ImprovedFrontEnd, "step", dying)
    out = tmp_path / "out"
    code, _, err = run_cli_here("process", str(crowd_log), "-o", str(out))
    line = assert_one_line_error(code, err, str(crowd_log), "killed by SIGKILL", "--jobs 1")
    assert "improved" in line
    assert not out.exists() and list(tmp_path.iterdir()) == []
    _no_children_left()
    code, _, err = run_cli_here("process", str(crowd_log), "-o", str(out), "--jobs", "1")  # one process: no child
    assert code == 0, err


@pytest.mark.slow
@needs_fork
def test_a_child_error_is_the_same_one_line_from_the_command(crowd_log, tmp_path, monkeypatch):
    _fail_at(monkeypatch, 3, LogError(f"{crowd_log}: a damaged sweep"))
    code, _, err = run_cli_here("process", str(crowd_log), "-o", str(tmp_path / "out"))
    assert_one_line_error(code, err, f"{crowd_log}: a damaged sweep")
    _no_children_left()


def _descendants(pid: int) -> set[int]:
    found, todo = set(), [pid]
    while todo:
        p = todo.pop()
        try:
            kids = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except OSError:
            continue
        found |= {int(k) for k in kids}
        todo += [int(k) for k in kids]
    return found


@pytest.mark.slow
@pytest.mark.skipif(not Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").exists(), reason="needs Linux /proc")
def test_ctrl_c_stops_both_and_leaves_nothing(tmp_path_factory, tmp_path):
    """SIGINT to the command's process group, as a terminal's Ctrl-C: both processes end, status 130,
    no output folder, no temporary folder, no process left. (A 2-minute log, a few seconds of
    processing: still in its sweeps when the signal comes, where a short log could be done and the
    interpreter ending, which SIGINT kills.)"""
    log = record_scenario(tmp_path_factory, "corridor", 120.0)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "fmcwlog", "process", str(log), "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            # as from a terminal: a shell's background job (a CI runner's) ignores SIGINT
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while not _descendants(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)  # until the child runs: the parent's sweeps begin next
    children = _descendants(proc.pid)
    assert children, "the child process never started"
    time.sleep(0.3)
    os.killpg(proc.pid, signal.SIGINT)
    output, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, (output, err)
    assert "Traceback" not in err and "fmcwlog: aborted" in err, err
    assert not out.exists() and list(tmp_path.iterdir()) == []
    time.sleep(0.2)
    assert not [c for c in children if Path(f"/proc/{c}").exists()
                and Path(f"/proc/{c}/stat").read_text().split()[2] != "Z"], "a process was left running"


def test_method_process_error_names_the_way_out():
    assert issubclass(MethodProcessError, Exception)
    assert "SIGKILL" in method_process._exit_reason(-signal.SIGKILL)
    assert method_process._exit_reason(3) == "exit status 3"


# --- the log read by each process: its warnings and errors the parent's -----------------------


def _reading_fails_at(monkeypatch, at: int, warn_at: int | None = None) -> None:
    """Make the log's reading warn at input ``warn_at`` and raise a LogError at input ``at`` (in the
    parent, and in a forked child, which reads the log too)."""
    original = LogInputs.__iter__

    def failing(self):
        for k, item in enumerate(original(self)):
            if k == warn_at:
                warnings.warn(f"reading: input {k} looks odd", UserWarning, stacklevel=1)
            if k == at:
                raise LogError(f"{self.path}: damaged at input {k}")
            yield item

    monkeypatch.setattr(LogInputs, "__iter__", failing)


@pytest.mark.slow
def test_the_reading_s_warnings_are_those_of_one_process(crowd_log, tmp_path, monkeypatch):
    _reading_fails_at(monkeypatch, -1, warn_at=40)
    one = process(crowd_log, tmp_path / "one", jobs=1)
    two = process(crowd_log, tmp_path / "two", jobs=2)
    assert one.warnings == two.warnings and "reading: input 40 looks odd" in two.warnings
    assert_same_outputs(tmp_path / "one", tmp_path / "two")


@pytest.mark.slow
@pytest.mark.parametrize("improved_fails_at", [None, 3, 1000])
def test_an_error_reading_the_log_mid_way_is_the_one_process_error(crowd_log, tmp_path, monkeypatch,
                                                                    improved_fails_at):
    """Each process reads the log: the parent's error comes where the methods reach it, after the
    child's error on an earlier sweep, if any, as in one process."""
    if improved_fails_at is not None and method_process.START_METHOD != "fork":
        pytest.skip("the child's failure is injected by patching code the forked child inherits")
    got = []
    for jobs in (1, 2):
        with monkeypatch.context() as patch:
            _reading_fails_at(patch, 120, warn_at=40)
            if improved_fails_at is not None:
                _fail_at(patch, improved_fails_at, LogError("improved failed"), "improved")
            error = _error_of(crowd_log, tmp_path / f"out{jobs}", jobs)
        got.append((type(error), str(error)))
    assert got[0] == got[1]
    assert "improved failed" in got[0][1] if improved_fails_at == 3 else "damaged at input 120" in got[0][1]
    _no_children_left()
