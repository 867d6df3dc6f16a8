"""The library surface: what the command line does, as functions (evo's ``main_*`` modules).

    from fmcwlog import api
    api.record(api.scenario("corridor"), api.SimConfig(), "corridor.mcap")
    summary = api.process("corridor.mcap", "out/")
    ev = api.report("out/")                  # ev.result["methods"]["improved"]["ate_rmse_m"]
    batch = api.process_many(["logs/"], "results/", jobs=4)   # results/<log>/; batch.failed: their reasons
    fleet = api.report_fleet("results/")     # fleet["flagged"]; results/fleet.html

Every function raises :class:`fmcwlog.errors.FmcwlogError` (with a one-line message
naming the file and the problem) for input it cannot use, and leaves nothing
half-written behind.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import __version__
from .errors import (
    CalibrationError,
    CarmenImportError,
    ConfigError,
    FmcwlogError,
    LogError,
    MapSizeError,
    OutputError,
    ReportError,
)
from .fleet.inputs import CARMEN_PATTERNS, find_logs, unique_names
from .fleet.state import is_batch_folder, options_digest, read_batch
from .fleet.tasks import Limits
from .io.atomic import (
    add_to_marker,
    atomic_batch,
    atomic_folder,
    check_output_file,
    created_parents,
    json_text,
    os_reason,
    reported_write_errors,
    write_json,
    write_text,
)
from .io.calibration import calibration_record, parse_calibration
from .io.calibration_file import read_calibration_file, write_calibration_file
from .io.carmen import parse_log
from .io.carmen_import import ImportSummary, write_mcap
from .io.digest import file_sha256
from .io.inputs import LogInputs, choose_topics
from .io.mcap_log import LogReader
from .io.topics import CALIBRATION_KEY
from .sim.config import SimConfig
from .sim.recorder import RecordSummary
from .sim.recorder import record as _record
from .sim.scenarios import DEFAULT_SCENARIO, SCENARIOS
from .sim.world import World
from .types import METHOD_NAMES, WHEEL_ODOMETRY, Calibration, InputTopics

# The estimation stack (the stages, scipy.spatial, gtsam) and the evaluation and output
# writers (pyarrow) are imported by the functions that use them: `fmcwlog record` and
# `--help` need none of them.
if TYPE_CHECKING:
    from .backend import BackendResult, PoseGraphBackend
    from .evaluation.evaluate import Evaluation, evaluate
    from .fleet.batch import BatchSummary
    from .fleet.progress import Progress
    from .frontend.params import FrontEndParams
    from .frontend.runner import LogRunner, SweepStep
    from .io.outputs import ProcessOutputs
    from .parallel_methods import ChildBackend, MethodProcess

    Backends = dict[str, PoseGraphBackend | ChildBackend]  # a child's stand in for the back ends it runs

logger = logging.getLogger(__name__)

__all__ = ["SimConfig", "FrontEndParams", "ProcessOptions", "ProcessSummary", "Evaluation", "Limits", "BatchSummary",
           "scenario", "record", "process", "process_many", "evaluate", "report", "report_fleet", "is_batch_folder",
           "compare", "import_carmen", "import_carmen_many", "calibrate", "CalibrateSummary"]


# Names of the library surface that live in heavier modules: imported on first use.
_LAZY = {"FrontEndParams": "fmcwlog.frontend.params", "Evaluation": "fmcwlog.evaluation.evaluate",
         "evaluate": "fmcwlog.evaluation.evaluate", "BatchSummary": "fmcwlog.fleet.batch"}


def __getattr__(name: str) -> Any:
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(_LAZY[name]), name)


def _frontend_params() -> FrontEndParams:
    from .frontend.params import FrontEndParams

    return FrontEndParams()


def scenario(name: str = DEFAULT_SCENARIO) -> World:
    """A built-in world by name (``corridor``, ``static``, ``crowd``, ``long-corridor``)."""
    return SCENARIOS[name]()


def record(world: World, cfg: SimConfig, out: str | Path,
           on_progress: Callable[[int], None] | None = None) -> RecordSummary:
    """Simulate ``cfg.run.duration`` seconds of ``world`` and write the log to ``out``
    (and the folders it needs: removed again if the recording fails)."""
    with reported_write_errors(out), created_parents(out):
        return _record(world, cfg, out, on_progress)


@dataclass
class ProcessOptions:
    """What :func:`process` runs: which methods, on which topics, with which parameters.

    scan_topic: default ``/fmcw/points``, else ``/scan``, else the log's only scan topic.
    ticks_topic: default ``/wheel/ticks`` when present.
    odom_topic: an Odometry topic as the motion prior instead of ticks (default ``/odom``
        when the log has no ticks).
    publish_period: paths and occupancy grids go into ``processed.mcap`` every this many
        seconds of log (s), and once more at the end.
    backend: ``pose-graph`` (loop closures for every method, :mod:`fmcwlog.backend`; the outputs
        come from the optimised poses) or ``none`` (the front ends alone).
    calibration: a calibration file (:mod:`fmcwlog.io.calibration_file`) to use instead of
        the log's ``fmcwlog.calibration`` record.
    """

    methods: tuple[str, ...] = METHOD_NAMES
    scan_topic: str | None = None
    ticks_topic: str | None = None
    odom_topic: str | None = None
    params: FrontEndParams = field(default_factory=_frontend_params)
    publish_period: float = 5.0
    calibration: Path | None = None
    backend: str = "pose-graph"


BACKENDS = ("pose-graph", "none")


@dataclass
class ProcessSummary:
    out_dir: Path
    sweeps: int
    doppler: bool
    prior: str
    skipped_sweeps: int
    repeated_prior_stamps: int
    skipped_inputs: dict[str, int]
    ms_median: dict[str, float]
    truncated: bool
    warnings: list[str]
    backend: dict[str, dict] = field(default_factory=dict)  # per method: BackendResult.summary()


def process(log: str | Path, out_dir: str | Path, opts: ProcessOptions | None = None, force: bool = False,
            on_sweep: Callable[[int, int | None], None] | None = None, jobs: int | None = None) -> ProcessSummary:
    """Run ``opts.methods`` over ``log`` and write everything into ``out_dir``.

    ``on_sweep(done, total)`` is called after each sweep (total None when unknown). The
    outputs are written to a temporary folder that replaces ``out_dir`` when complete.
    ``out_dir`` must be empty or absent; with ``force`` it may also be an output folder
    fmcwlog made, but never one holding anything else or the log itself
    (:func:`fmcwlog.io.atomic.check_output_folder`). ``jobs``: 1 runs every method in this
    process; otherwise (None: where two or more CPUs are usable) the methods after the first
    run in a child process (:mod:`fmcwlog.parallel_methods`). The outputs are the same bytes but
    the timings (the parquet's ``ms``, ``run.json``'s ``wall_seconds``, ``ms_per_sweep_median`` and
    the back ends' ``seconds``).
    """
    from .allocator import keep_freed_memory
    from .frontend.runner import LogRunner
    from .io.outputs import ProcessOutputs, odom_frame
    from .parallel_methods import merge_diagnostics

    opts = opts or ProcessOptions()
    if opts.backend not in BACKENDS:
        raise ConfigError(f"unknown back end {opts.backend!r} (known: {', '.join(BACKENDS)})")
    log, out_dir = Path(log), Path(out_dir)
    keep_freed_memory()  # numpy's large temporaries reuse memory instead of faulting in fresh pages
    started = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = LogReader(log)
        topics = choose_topics(reader, opts.scan_topic, opts.ticks_topic, opts.odom_topic)
        cal, cal_source = _calibration(reader, log, topics.ticks is not None, opts.calibration)
        total = reader.message_count(topics.scan)
        logger.debug("%s: scan %s, prior %s, %s sweeps, lidar at x %.3f m, y %.3f m, yaw %.4f rad",
                  reader.path, topics.scan, topics.prior or "none",
                  total if total is not None else "an unknown number of", *cal.mount)
        with reported_write_errors(out_dir), atomic_folder(out_dir, force, (log,), "fmcwlog process") as tmp, \
                _methods_elsewhere(log, opts, cal, topics, jobs) as elsewhere:
            digest = file_sha256(log)  # report refuses a --log whose bytes differ
            here = tuple(m for m in opts.methods if elsewhere is None or m not in elsewhere.methods)
            runner = LogRunner(here, opts.params, cal, topics, reader.path)
            inputs = LogInputs(reader, topics, cal)
            trajectories = (*opts.methods, WHEEL_ODOMETRY) if topics.prior else tuple(opts.methods)
            outputs = ProcessOutputs(tmp, trajectories, np.asarray(cal.mount), opts.publish_period)
            own_grids = {fe.name: fe.grid for fe in runner.fronts}
            grids: dict[str, Any] = {m: own_grids.get(m) for m in opts.methods}  # the child's: its maps, as published
            backends = _backends(opts, cal, elsewhere)
            steps = runner.run(inputs)
            if elsewhere is not None:
                steps = elsewhere.steps(steps, grids, outputs)
            try:
                searches = _feed(opts.methods, _steps(steps, log), outputs, backends, grids,
                                 lambda: on_sweep(runner.sweeps, total) if on_sweep else None)
                optimised = _optimise(backends, outputs, grids, tmp)
                if elsewhere is not None:
                    grids.update(elsewhere.end().grids)  # without a back end: the child's last maps
                outputs.finish(grids)
            except BaseException:
                outputs.abort()
                raise
            diagnostics, diagnostic_notes = (runner.diagnostics() if elsewhere is None else
                                             merge_diagnostics(runner.diagnostics(), elsewhere.end().diagnostics))
            notes = [str(w.message) for w in caught] + _process_notes(runner, inputs, topics) + diagnostic_notes
            summary = ProcessSummary(out_dir, runner.sweeps, bool(runner.doppler), _prior_name(topics), inputs.skipped_sweeps,
                                     inputs.repeated_prior_stamps, inputs.skipped, outputs.ms_median(),
                                     reader.contents.truncated, notes,
                                     {m: res.summary() for m, res in optimised.items()})
            write_json(tmp / "run.json", {
                "fmcwlog_version": __version__,
                "log": str(log.resolve()),
                "log_size_bytes": log.stat().st_size,
                "log_sha256": digest,
                "options_sha256": options_digest(opts),
                "methods": list(opts.methods),
                "scan_topic": topics.scan,
                "prior": summary.prior,
                "doppler": summary.doppler,
                "mount": list(cal.mount),
                "calibration_source": cal_source,
                **diagnostics,
                "frames": {name: odom_frame(name) for name in trajectories},
                "params": dataclasses.asdict(opts.params),
                "sweeps": summary.sweeps,
                "skipped_sweeps": summary.skipped_sweeps,
                "repeated_prior_stamps": summary.repeated_prior_stamps,
                "skipped_inputs": summary.skipped_inputs,
                "truncated_log": summary.truncated,
                "warnings": summary.warnings,
                "ms_per_sweep_median": summary.ms_median,
                "correlative_searches": {m: {"run": n, "kept": k, "sweeps": summary.sweeps}
                                         for m, (n, k) in searches.items()},
                "backend": {"kind": opts.backend, **summary.backend},
                "wall_seconds": round(time.perf_counter() - started, 3),
            }, sort_keys=True)
    return summary


def _prior_name(topics: InputTopics) -> str:
    """The motion prior, as ``run.json`` and the summary say it."""
    if topics.ticks:
        return f"wheel ticks ({topics.ticks})"
    return f"odometry ({topics.odom})" if topics.odom else "none (constant velocity)"


def _backends(opts: ProcessOptions, cal: Calibration, elsewhere: MethodProcess | None) -> Backends:
    """Each method's back end (none without ``opts.backend``); the child's stand in for those it runs."""
    from .backend import PoseGraphBackend

    if opts.backend != "pose-graph":
        return {}
    there = elsewhere.backends if elsewhere is not None else {}
    return {m: there[m] if m in there else
            PoseGraphBackend(opts.params.backend, np.asarray(cal.mount), opts.params.map_resolution)
            for m in opts.methods}


@contextmanager
def _methods_elsewhere(log: Path, opts: ProcessOptions, cal: Calibration, topics: InputTopics,
                       jobs: int | None) -> Iterator[MethodProcess | None]:
    """The child process that runs the methods after the first (:mod:`fmcwlog.parallel_methods`),
    ended on the way out; None where they all run here."""
    from .parallel_methods import ChildTask, MethodProcess, child_methods

    methods = child_methods(tuple(opts.methods), jobs)
    if not methods:
        yield None
        return
    task = ChildTask(log, methods, opts.params, cal, topics, opts.backend == "pose-graph",
                     int(opts.publish_period * 1e9))  # as ProcessOutputs has it
    with MethodProcess(task) as child:
        yield child


def _feed(methods: Sequence[str], steps: Iterator[SweepStep], outputs: ProcessOutputs,
          backends: Backends, grids: dict, after_sweep: Callable[[], None]) -> dict[str, list[int]]:
    """Every sweep through the front ends, into the outputs and the back ends. Returns, per method,
    how many correlative searches ran and how many of them replaced the ICP's match."""
    searches = {m: [0, 0] for m in methods}
    for step in steps:
        for r in step.results:
            outputs.add(r)
            searches[r.method][0] += r.searched
            searches[r.method][1] += r.recovered
            if r.method in backends:
                backends[r.method].add(r)
        if step.wheel_pose is not None:
            outputs.add_pose(WHEEL_ODOMETRY, step.sweep.stamp_ns, step.wheel_pose, step.wheel_twist)
        outputs.end_sweep(step.sweep.stamp_ns, grids)
        after_sweep()
    return searches


def _optimise(backends: Backends, outputs: ProcessOutputs, grids: dict,
              folder: Path) -> dict[str, BackendResult]:
    """Each back end's last optimisation: its trajectory replaces the front end's in the outputs,
    its map the front end's grid, and ``<method>_backend.json`` records its graph."""
    optimised = {m: be.finish() for m, be in backends.items()}
    for m, res in optimised.items():
        outputs.correct(m, res.poses)
        grids[m] = res.grid
        write_json(folder / f"{m}_backend.json", backend_json(res))
    return optimised


def backend_json(res: BackendResult) -> dict:
    """What ``<method>_backend.json`` holds: the nodes (optimised poses) and the verified closures."""
    return {
        "frame": "the method's own <method>/odom; base_link",
        "nodes": {"stamp_ns": res.node_stamps_ns.tolist(), "x": res.node_poses[:, 0].round(6).tolist(),
                  "y": res.node_poses[:, 1].round(6).tolist(), "yaw": res.node_poses[:, 2].round(6).tolist()},
        "closures": [{"query": c.query, "candidate": c.candidate, "query_stamp_ns": c.query_stamp_ns,
                      "candidate_stamp_ns": c.candidate_stamp_ns, "relative": [round(float(v), 6) for v in c.relative],
                      "score": round(c.score, 4), "second_score": round(c.second_score, 4),
                      "inlier_fraction": round(c.inlier_fraction, 4), "free_directions": c.free_directions,
                      "whitened_error": round(c.whitened_error, 4), "accepted": c.accepted} for c in res.closures],
        "summary": res.summary(),
    }


def _steps(steps: Iterator[SweepStep], log: Path) -> Iterator[SweepStep]:
    """The runner's steps; a map that outgrows its budget is an error about this log."""
    try:
        yield from steps
    except MapSizeError as exc:
        raise LogError(f"{log}: {exc}") from None


def _calibration(reader: LogReader, log: Path, need_wheels: bool, path: Path | None) -> tuple[Calibration, str]:
    """The calibration to process with: the file at ``path`` if given, else the log's record; and its source.

    A calibration that leaves out some of the mount's keys is warned of by :func:`parse_calibration`."""
    if path is not None:
        try:
            return parse_calibration(read_calibration_file(path), need_wheels, str(path)), str(path)
        except CalibrationError as exc:
            raise CalibrationError(f"{path}: {str(exc).removeprefix(f'{path}: ')}") from None
    try:
        record = calibration_record(reader.metadata_all(CALIBRATION_KEY), str(log))
        return parse_calibration(record, need_wheels, str(log)), f"log record {CALIBRATION_KEY}"
    except CalibrationError as exc:
        raise LogError(f"{log}: {exc}{reader.damage_note()}") from None


@dataclass
class CalibrateSummary:
    """What :func:`calibrate` found: the file written, the check (as in ``run.json``) and warnings."""

    output: Path
    check: dict
    warnings: list[str]


def calibrate(log: str | Path, output: str | Path, opts: ProcessOptions | None = None,
              force: bool = False) -> CalibrateSummary:
    """Estimate the lidar's mount and the wheels from ``log`` itself and write them as a calibration file.

    Runs the improved method over the log (nothing else is written), then
    :mod:`fmcwlog.frontend.self_calibration`. The file holds the calibration's keys (the
    log's record, or ``opts.calibration``) with the estimated values in place of its own,
    each value's standard deviation in a comment; values the log cannot fix keep theirs.
    """
    from .frontend.self_calibration import recheck

    opts = opts or ProcessOptions()
    log, output = Path(log), Path(output)
    check_output_file(output, force, (log, opts.calibration))  # --force never overwrites the log it reads
    if not output.parent.is_dir():
        raise OutputError(f"{output}: no folder {output.parent} to write it in")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = LogReader(log)
        topics = choose_topics(reader, opts.scan_topic, opts.ticks_topic, opts.odom_topic)
        if topics.ticks is None:
            raise LogError(f"{log}: no wheel ticks: the wheels' radii and the mount are estimated against them")
        cal0, cal_source = _calibration(reader, log, True, opts.calibration)
        check, adopted, passes, notes = _self_calibrate(reader, topics, cal0, opts)
    first = recheck(check["values"], cal0, opts.params.self_calibration)  # against the calibration we started from
    values: dict[str, str | float] = dict(read_calibration_file(opts.calibration) if opts.calibration
                                          else reader.metadata.get(CALIBRATION_KEY, {}))
    lines = [f"fmcwlog {__version__} calibrate: estimated from {log.name} ({check['sweeps_used']['doppler']} moving "
             f"sweeps, {check['sweeps_used']['heading_changes']} scan-matched heading changes, {passes} "
             f"pass{'es' if passes > 1 else ''}), "
             f"starting from the {cal_source}"]
    for name, c in first.items():
        if name in adopted:
            values[name] = c["estimate"]
        kept = "" if name in adopted else "; kept the calibration's: it agrees within 3 standard deviations"
        lines.append(f"{name}: {c['estimate']:.6g} +- {c['sigma']:.2g} (was {c['calibration']:.6g}){kept}")
    lines += [f"{name}: kept the calibration's: {why}" for name, why in check["not_estimated"].items()]
    with reported_write_errors(output):
        write_calibration_file(output, values, lines)
    check = {**check, "values": first, "disagrees": sorted(n for n, c in first.items() if c["disagrees"]),
             "adopted": sorted(adopted), "passes": passes}
    return CalibrateSummary(output, check, [str(w.message) for w in caught] + notes)


def _self_calibrate(reader: LogReader, topics: InputTopics, cal: Calibration,
                    opts: ProcessOptions) -> tuple[dict, set[str], int, list[str]]:
    """The calibration check over the whole log, repeated with the values it adopts
    (:func:`fmcwlog.frontend.self_calibration.adopt`) until they no longer move (at most
    ``self_calibration.passes`` times); returns the last check, the adopted names, the passes, the notes."""
    from .frontend.runner import LogRunner
    from .frontend.self_calibration import adopt, converged, with_estimate

    prm = opts.params.self_calibration
    passes, adopted = 0, set()
    while True:
        passes += 1
        runner = LogRunner(("improved",), opts.params, cal, topics, reader.path)
        for _ in runner.run(LogInputs(reader, topics, cal)):
            pass
        diagnostics, notes = runner.diagnostics()
        check = diagnostics.get("calibration_check", {})
        if not check.get("checked"):
            raise LogError(f"{reader.path}: cannot estimate the calibration: {check.get('reason', 'no Doppler')}")
        adopted = adopt(check["values"], adopted)
        if not adopted or converged(check["values"], adopted) or passes >= prm.passes:
            return check, adopted, passes, notes
        cal = with_estimate(cal, {n: check["values"][n] for n in adopted})


def _process_notes(runner: LogRunner, inputs: LogInputs, topics: InputTopics) -> list[str]:
    notes = []
    if not runner.doppler:
        notes.append(f"{topics.scan} carries no Doppler velocity: ego-motion and segmentation are off")
    notes += inputs.notes()
    if runner.beyond_prior:
        notes.append(f"{runner.beyond_prior} sweeps on {topics.scan} began after the last message on {topics.prior}: "
                     "processed with the motion prior held at its last pose")
    if runner.before_prior:
        notes.append(f"{runner.before_prior} sweeps on {topics.scan} began before the first message on {topics.prior}: "
                     "processed with the motion prior held at its first pose")
    return notes


def report(out_dir: str | Path, log: str | Path | None = None,
           relations: str | Path | None = None) -> Evaluation:
    """:func:`evaluate` ``out_dir`` and write report.html, report.md and report.json into it:
    all of them or, if any write fails (a full disk), none."""
    from .evaluation.evaluate import evaluate
    from .evaluation.pages import write_report

    ev = evaluate(out_dir, log, relations=relations)
    with reported_write_errors(ev.out_dir), atomic_batch():
        add_to_marker(ev.out_dir, write_report(ev))
    return ev


def process_many(paths: Sequence[str | Path], out_dir: str | Path, opts: ProcessOptions | None = None,
                 force: bool = False, jobs: int | None = None, limits: Limits | None = None,
                 ray: bool = False, ray_address: str | None = None, retries: int = 2,
                 on_progress: Callable[[Progress], None] | None = None) -> BatchSummary:
    """:func:`process` every log that ``paths`` name (files, or folders searched for ``*.mcap``),
    each into ``out_dir/<name>`` in a worker process of its own; see :mod:`fmcwlog.fleet`.

    ``jobs`` workers at a time (default: every core); ``limits``: each log's memory cap and
    timeout. Logs whose results are complete from the same bytes and options are skipped
    unless ``force``. ``ray``: run them as Ray tasks instead (``ray_address`` None starts a
    local Ray; ``retries``: Ray's retries of a task whose worker or node died). A log that
    fails is an outcome with its reason (``summary.failed``), not an exception; the
    exceptions are for the batch as a whole (no logs found, bad limits, Ray unreachable).
    """
    from .fleet.batch import process_many as _process_many

    return _process_many(paths, out_dir, opts or ProcessOptions(), force, jobs, limits, ray_address, ray, retries,
                         on_progress)


def report_fleet(out_dir: str | Path, on_log: Callable[[int, int, str], None] | None = None) -> dict[str, Any]:
    """:func:`report` every log folder of a batch (``process_many``'s ``out_dir``), then write
    fleet.json and fleet.html there; returns fleet.json's document
    (:mod:`fmcwlog.evaluation.fleet`). A log whose report fails gets the reason in its row.
    ``on_log(done, total, name)`` is called as each log is reported (several seconds each)."""
    from .evaluation.fleet import FleetEntry, fleet_result, log_row, write_fleet

    out_dir = Path(out_dir)
    if not is_batch_folder(out_dir):
        raise ReportError(f"{out_dir}: not a batch folder (no batch.json, no log folders with run.json)")
    batch = read_batch(out_dir)
    names = set(batch["logs"]) | {p.name for p in out_dir.iterdir()
                                  if p.is_dir() and not p.name.startswith(".") and (p / "run.json").is_file()}
    rows = []
    for i, name in enumerate(sorted(names), 1):
        folder = out_dir / name
        entry = FleetEntry(name, folder if (folder / "run.json").is_file() else None, batch["logs"].get(name, {}))
        ev, error = None, None
        if entry.folder is not None and entry.record.get("status") != "failed":
            try:
                ev = report(entry.folder)
            except FmcwlogError as exc:
                error = str(exc)
        rows.append(log_row(entry, ev, error))
        logger.debug("%s: reported", name)
        if on_log is not None:
            on_log(i, len(names), name)
    result = fleet_result(out_dir, rows, batch)
    write_fleet(out_dir, result)
    return result


def compare(results: list[dict], target: str | Path) -> Path:
    """comparison.md and comparison.json of several reports' results in ``target``; returns the .md."""
    from .evaluation.pages import comparison_rows, markdown_table

    target = Path(target)
    header, rows = comparison_rows(results)
    with reported_write_errors(target), created_parents(target / "comparison.md"), atomic_batch():
        write_text(target / "comparison.md", markdown_table(header, rows) + "\n")
        write_text(target / "comparison.json", json_text(results))
    return target / "comparison.md"


def import_carmen(source: str | Path, output: str | Path) -> tuple[ImportSummary, str]:
    """Convert a CARMEN or CMU course log into an fmcwlog MCAP log; returns the summary and the format."""
    try:
        parsed = parse_log(Path(source))
    except (OSError, EOFError, UnicodeDecodeError) as exc:  # a damaged .gz/.xz stream is an EOFError or OSError
        reason = os_reason(exc) if isinstance(exc, OSError) else str(exc) or type(exc).__name__
        raise CarmenImportError(f"{source}: cannot read ({reason})") from None
    with reported_write_errors(output), created_parents(output):
        return write_mcap(parsed, Path(output)), parsed.format


@dataclass
class ImportOutcome:
    """One source of :func:`import_carmen_many`: ``status`` done, skipped (its output exists) or failed."""

    source: Path
    output: Path
    status: str
    reason: str | None = None
    summary: ImportSummary | None = None
    format: str | None = None


def import_carmen_many(paths: Sequence[str | Path], out_dir: str | Path, force: bool = False) -> list[ImportOutcome]:
    """:func:`import_carmen` every CARMEN log that ``paths`` name (files, or folders searched for
    ``*.clf``, ``*.log``, plain, ``.gz`` or ``.xz``) into ``out_dir/<name>.mcap`` (names as
    :mod:`fmcwlog.fleet.inputs` gives them). An existing output is kept unless ``force``; a
    source that cannot be read is reported in its outcome and the others go on."""
    out_dir = Path(out_dir)
    sources = find_logs(paths, CARMEN_PATTERNS, skip=out_dir)
    outcomes = []
    for src, name in zip(sources, unique_names(sources, CARMEN_PATTERNS)):
        out = out_dir / f"{name}.mcap"
        if out.exists() and not force:
            outcomes.append(ImportOutcome(src, out, "skipped", f"{out}: exists; use --force to convert it again"))
            continue
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
            summary, fmt = import_carmen(src, out)
        except (FmcwlogError, OSError, EOFError, UnicodeDecodeError) as exc:
            outcomes.append(ImportOutcome(src, out, "failed", f"{src}: cannot import ({exc})"
                                          if not isinstance(exc, FmcwlogError) else str(exc)))
            continue
        outcomes.append(ImportOutcome(src, out, "done", summary=summary, format=fmt))
    return outcomes
