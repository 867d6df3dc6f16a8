"""One log through both front ends and their back ends into an output folder: ``fmcwlog process``.

The path of a sweep, in one place (:func:`process` is the recipe, step by step):

    open_log -> LogInputs (decoded, checked sweeps, ticks, odometry; :mod:`fmcwlog.io.inputs`)
      -> LogRunner (each method's :class:`~fmcwlog.frontend.methods.FrontEnd` step, with the
         motion prior; :mod:`fmcwlog.pipeline.runner`) -> SweepResult
      -> ProcessOutputs (trajectories, maps, processed.mcap; :mod:`fmcwlog.io.outputs`)
         and PoseGraphBackend (:mod:`fmcwlog.backend`), whose optimised poses replace the front
         end's in the outputs at the end.

Where two or more CPUs are usable the costliest method runs in a child process
(:mod:`fmcwlog.pipeline.method_process`) and its results join the same stream.
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
from typing import Any

import numpy as np

from .. import __version__
from ..allocator import keep_freed_memory
from ..backend import BackendResult, PoseGraphBackend
from ..errors import ConfigError, LogError, MapSizeError
from ..io.atomic import atomic_folder, reported_write_errors, write_json
from ..io.calibration import LoadedCalibration, load_calibration
from ..io.digest import log_sha256, log_size
from ..io.inputs import MANY_SKIPPED_SHARE, MOST_SKIPPED_SHARE, LogInputs, SkippedShare
from ..io.logs import Log, open_log
from ..io.outputs import ProcessOutputs, odom_frame
from ..io.topic_choice import choose_topics, odometry_instead_of_ticks
from ..types import BASELINE, IMPROVED, WHEEL_ODOMETRY, Calibration, InputTopics
from .method_process import ChildBackend, ChildTask, EncodedResult, MethodProcess, child_methods, merge_diagnostics
from .options import BACKENDS, ProcessOptions, options_digest
from .run_record import RunRecord
from .runner import LogRunner, SweepStep

logger = logging.getLogger(__name__)

Backends = dict[str, PoseGraphBackend | ChildBackend]  # a child's stand in for the back ends it runs


@dataclass
class ProcessSummary:
    """What :func:`process` did: the output folder, the sweeps processed and skipped, the motion
    prior, the median ms per sweep per method, the warnings, and per method the back end's summary."""

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
    many_skipped: str | None = None  # more than MANY_SKIPPED_SHARE of the sweeps skipped: how many, why


def process(log: str | Path, out_dir: str | Path, opts: ProcessOptions | None = None, force: bool = False,
            on_sweep: Callable[[int, int | None], None] | None = None, jobs: int | None = None) -> ProcessSummary:
    """Run ``opts.methods`` over ``log`` and write everything into ``out_dir``.

    ``on_sweep(done, total)`` is called after each sweep (total None when unknown). The
    outputs are written to a temporary folder that replaces ``out_dir`` when complete.
    ``out_dir`` must be empty or absent; with ``force`` it may also be an output folder
    fmcwlog made, but never one holding anything else or the log itself
    (:func:`fmcwlog.io.atomic.check_output_folder`). ``jobs``: 1 runs every method in this
    process; otherwise (None: where two or more CPUs are usable) the costliest method runs in a
    child process (:mod:`fmcwlog.pipeline.method_process`). The outputs are the same bytes
    but the timings (the parquet's ``ms``, ``run.json``'s ``wall_seconds``, ``ms_per_sweep_median``
    and the back ends' ``seconds``). Raises :class:`~fmcwlog.errors.FmcwlogError` for input it
    cannot use, leaving ``out_dir`` as it was; so is a log that lost more than half its sweeps as
    damaged (:data:`~fmcwlog.io.inputs.MOST_SKIPPED_SHARE`), unless ``opts.keep_going``. A run
    that lost more than :data:`~fmcwlog.io.inputs.MANY_SKIPPED_SHARE` says so in
    ``summary.many_skipped``, the last of its warnings, and in run.json's ``many_skipped_sweeps``.
    """
    opts = opts or ProcessOptions()
    if opts.backend not in BACKENDS:
        raise ConfigError(f"unknown back end {opts.backend!r} (known: {', '.join(BACKENDS)})")
    reading = opts.cloud_reading()
    log, out_dir = Path(log), Path(out_dir)
    keep_freed_memory()  # numpy's large temporaries reuse memory instead of faulting in fresh pages
    started = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # 1. the log: its topics, the calibration, how many sweeps
        reader = open_log(log)  # an MCAP log, a rosbag2 folder or a ROS 1 bag
        log = reader.path  # a rosbag2 folder for its .db3
        topics = choose_topics(reader, opts.scan_topic, opts.ticks_topic, opts.odom_topic)
        topics, loaded = calibration_and_topics(reader, log, topics, opts)
        cal = loaded.cal
        total = reader.message_count(topics.scan)
        logger.debug("%s: scan %s, prior %s, %s sweeps, lidar at x %.3f m, y %.3f m, yaw %.4f rad",
                     reader.path, topics.scan, topics.prior or "none",
                     total if total is not None else "an unknown number of", *cal.mount)
        with reported_write_errors(out_dir), atomic_folder(out_dir, force, (log,), "fmcwlog process") as tmp, \
                _methods_elsewhere(log, opts, cal, topics, jobs) as elsewhere:
            digest = log_sha256(log)  # report refuses a --log whose bytes differ
            # 2. the front ends here (and the rest in the child), the outputs, the back ends
            here = tuple(m for m in opts.methods if elsewhere is None or m not in elsewhere.methods)
            runner = LogRunner(here, opts.params, cal, topics, reader.path)
            inputs = LogInputs(reader, topics, cal, reading)
            trajectories = (*opts.methods, WHEEL_ODOMETRY) if topics.prior else tuple(opts.methods)
            outputs = ProcessOutputs(tmp, trajectories, np.asarray(cal.mount), opts.publish_period,
                                     upside_down=cal.upside_down)
            own_grids = {fe.name: fe.grid for fe in runner.fronts}
            grids: dict[str, Any] = {m: own_grids.get(m) for m in opts.methods}  # the child's: its maps, as published
            backends = _backends(opts, cal, elsewhere)
            steps = runner.run(inputs)
            if elsewhere is not None:
                steps = elsewhere.steps(steps, grids, outputs)
            try:
                # 3. every sweep: front ends -> outputs and back ends
                searches = _feed(opts.methods, _steps(steps, log), outputs, backends, grids,
                                 lambda: on_sweep(runner.sweeps, total) if on_sweep else None)
                skipped = _skipped_share(log, inputs, opts.keep_going)
                # 4. the back ends' last optimisation replaces the front ends' poses and maps
                optimised = _optimise(backends, outputs, grids, tmp)
                if elsewhere is not None:
                    grids.update(elsewhere.end().grids)  # without a back end: the child's last maps
                _check_mapped(log, grids, runner.sweeps)
                outputs.finish(grids)
            except BaseException:
                outputs.abort()
                raise
            # 5. what the run found, said once in the summary and in run.json
            diagnostics, diagnostic_notes = _diagnostics(opts.methods, runner, elsewhere)
            notes = ([str(w.message) for w in caught] + _process_notes(runner, inputs, topics) + diagnostic_notes
                     + _backend_notes(optimised))
            many_skipped = _many_skipped_line(skipped)
            prior = _prior_name(topics, opts.methods, bool(runner.doppler))
            summary = ProcessSummary(out_dir, runner.sweeps, bool(runner.doppler), prior, inputs.skipped_sweeps,
                                     inputs.repeated_prior_stamps, inputs.skipped, outputs.ms_median(),
                                     reader.contents.truncated, notes + ([many_skipped] if many_skipped else []),
                                     {m: res.summary() for m, res in optimised.items()}, many_skipped)
            record = RunRecord(
                fmcwlog_version=__version__, log=str(log.resolve()), log_size_bytes=log_size(log),
                log_sha256=digest, options_sha256=options_digest(opts), methods=tuple(opts.methods),
                scan_topic=topics.scan, prior=summary.prior, doppler=summary.doppler, mount=cal.mount,
                lidar_upside_down=cal.upside_down,
                calibration_source=loaded.sources.describe(), calibration_sources=loaded.sources.to_json(),
                motion_sources=diagnostics["motion_sources"],
                calibration_check=diagnostics.get("calibration_check"),
                frames={name: odom_frame(name) for name in trajectories}, params=dataclasses.asdict(opts.params),
                sweeps=summary.sweeps, skipped_sweeps=summary.skipped_sweeps,
                repeated_prior_stamps=summary.repeated_prior_stamps, skipped_inputs=summary.skipped_inputs,
                truncated_log=summary.truncated, warnings=summary.warnings, ms_per_sweep_median=summary.ms_median,
                correlative_searches={m: {"run": n, "kept": k, "sweeps": summary.sweeps} for m, (n, k) in searches.items()},
                backend={"kind": opts.backend, **summary.backend},
                wall_seconds=round(time.perf_counter() - started, 3),
                many_skipped_sweeps=_many_skipped_record(skipped, opts.keep_going),
                gaps=[g.to_json() for g in runner.gaps.gaps], jumps=diagnostics.get("jumps", {}))
            write_json(tmp / "run.json", record.to_json(), sort_keys=True)
    return summary


def calibration_and_topics(reader: Log, log: Path, topics: InputTopics,
                           opts: ProcessOptions) -> tuple[InputTopics, LoadedCalibration]:
    """The calibration (:func:`fmcwlog.io.calibration.load_calibration`: the file, the log's record,
    its tf) and the topics to read with it: wheel ticks that nothing gives the wheels for give way
    to the log's ``/odom`` (:func:`fmcwlog.io.topic_choice.odometry_instead_of_ticks`)."""
    loaded = load_calibration(reader, log, topics.scan, topics.ticks is not None, opts.calibration, opts.base_frame)
    if topics.ticks is not None and loaded.cal.wheels is None:
        topics = odometry_instead_of_ticks(reader, topics, opts.ticks_topic is not None, opts.calibration)
        loaded = dataclasses.replace(loaded, sources=dataclasses.replace(loaded.sources, wheels=None))
    return topics, loaded


def _skipped_share(log: Path, inputs: LogInputs, keep_going: bool) -> SkippedShare | None:
    """The share of sweeps the log lost, where it is more than :data:`MANY_SKIPPED_SHARE` (else None);
    more than :data:`MOST_SKIPPED_SHARE` is refused, unless ``keep_going``: the results would be
    those of the few sweeps left, not of the log."""
    skipped = inputs.skipped_share()
    if skipped is None or not skipped.many:
        return None
    if skipped.most and not keep_going:
        raise LogError(f"{log}: " + skipped.text(f"more than half: not processed, as the results would not be the "
                                                 f"log's; --keep-going processes the {skipped.read - skipped.skipped} left"))
    return skipped


def _check_mapped(log: Path, grids: dict[str, Any], sweeps: int) -> None:
    """Refuse a log of which no method mapped a single cell: every point of every sweep was left out
    (closer than the front end's ``min_range``, or on a mover), so that no estimate stands on the scans."""
    sizes = [g.width * g.height for g in grids.values() if g is not None and hasattr(g, "width")]
    if sizes and not any(sizes):
        raise LogError(f"{log}: no point of its {sweeps} sweeps could be mapped: each lies closer to the sensor "
                       "than frontend.min_range or on a mover; nothing would be estimated from the scans")


def _many_skipped_line(skipped: SkippedShare | None) -> str | None:
    """The run's last word where it lost many sweeps: how many, of how many, and why."""
    if skipped is None:
        return None
    over = "more than half, processed as --keep-going asks" if skipped.most else \
        f"more than {100 * MANY_SKIPPED_SHARE:g} %"
    return skipped.text(f"{over}: the results stand on the {skipped.read - skipped.skipped} left")


def _many_skipped_record(skipped: SkippedShare | None, keep_going: bool) -> dict[str, Any] | None:
    """run.json's ``many_skipped_sweeps``: present only where more than MANY_SKIPPED_SHARE were skipped."""
    if skipped is None:
        return None
    return {"skipped": skipped.skipped, "read": skipped.read, "share": round(skipped.share, 6),
            "limit": MANY_SKIPPED_SHARE, "refused_above": MOST_SKIPPED_SHARE, "kept_going": skipped.most and keep_going,
            "main_kind": skipped.kind, "main_reason": skipped.reason}


def _prior_name(topics: InputTopics, methods: Sequence[str], doppler: bool) -> str:
    """The motion prior, as ``run.json`` and the summary say it: the odometry topic, else what each
    method guessed each sweep's pose from, and why (:mod:`fmcwlog.frontend.scan_prior`)."""
    if topics.ticks:
        return f"wheel ticks ({topics.ticks})"
    if topics.odom:
        return f"odometry ({topics.odom})"
    search = "scan-to-map correlative search"
    if not doppler:
        return f"{search} (no odometry, no wheel ticks, no Doppler in {topics.scan})"
    if BASELINE not in methods:
        return "Doppler ego-motion (no odometry, no wheel ticks)"
    if IMPROVED not in methods:
        return f"{search} (no odometry, no wheel ticks; the baseline does not use Doppler)"
    return f"Doppler ego-motion for the improved method, {search} for the baseline (no odometry, no wheel ticks)"


def _diagnostics(methods: Sequence[str], runner: LogRunner,
                 elsewhere: MethodProcess | None) -> tuple[dict, list[str]]:
    """The runners' :meth:`~fmcwlog.pipeline.runner.LogRunner.diagnostics`: this process's and the
    child's, merged with the first method's first, as one process lists them."""
    if elsewhere is None:
        return runner.diagnostics()
    here, there = runner.diagnostics(), elsewhere.end().diagnostics
    return merge_diagnostics(there, here) if methods[0] in elsewhere.methods else merge_diagnostics(here, there)


def _backends(opts: ProcessOptions, cal: Calibration, elsewhere: MethodProcess | None) -> Backends:
    """Each method's back end (none without ``opts.backend``); the child's stand in for those it runs."""
    if opts.backend != "pose-graph":
        return {}
    there = elsewhere.backends if elsewhere is not None else {}
    return {m: there[m] if m in there else
            PoseGraphBackend(opts.params.backend, np.asarray(cal.mount), opts.params.map_resolution)
            for m in opts.methods}


@contextmanager
def _methods_elsewhere(log: Path, opts: ProcessOptions, cal: Calibration, topics: InputTopics,
                       jobs: int | None) -> Iterator[MethodProcess | None]:
    """The child process that runs the costliest method (:mod:`fmcwlog.pipeline.method_process`),
    ended on the way out; None where they all run here."""
    methods = child_methods(tuple(opts.methods), jobs)
    if not methods:
        yield None
        return
    task = ChildTask(log, methods, opts.params, cal, topics, opts.backend == "pose-graph",
                     int(opts.publish_period * 1e9), opts.cloud_reading(), tuple(opts.methods))  # as ProcessOutputs has it
    with MethodProcess(task) as child:
        yield child


def _feed(methods: Sequence[str], steps: Iterator[SweepStep], outputs: ProcessOutputs,
          backends: Backends, grids: dict, after_sweep: Callable[[], None]) -> dict[str, list[int]]:
    """Every sweep through the front ends, into the outputs and the back ends. Returns, per method,
    how many correlative searches ran and how many of them replaced the ICP's match."""
    searches = {m: [0, 0] for m in methods}
    for step in steps:
        for r in step.results:
            outputs.add(r, r.messages if isinstance(r, EncodedResult) else None)  # the child's, encoded there
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
    its map the front end's grid, and ``<method>_backend.json`` records its graph. This process's
    back ends finish first, while the child's finish there; of several errors, the first method's
    is raised, as in one process."""
    done: dict[str, BackendResult] = {}
    failed: dict[str, Exception] = {}
    for m in sorted(backends, key=lambda m: isinstance(backends[m], ChildBackend)):
        try:
            done[m] = backends[m].finish()
        except Exception as exc:  # noqa: BLE001 (raised below, the first method's first)
            failed[m] = exc
    if failed:
        raise next(failed[m] for m in backends if m in failed)
    optimised = {m: done[m] for m in backends}
    for m, res in optimised.items():
        outputs.correct(m, res.poses)
        grids[m] = res.grid
        write_json(folder / f"{m}_backend.json", res.to_json())
    return optimised


def _backend_notes(optimised: dict[str, BackendResult]) -> list[str]:
    """A warning per method whose back end would have made its map worse, with the numbers
    (:mod:`fmcwlog.backend.consistency`): its outputs keep the front end's trajectory and map."""
    notes = []
    for m, res in optimised.items():
        r = res.revisits
        if res.kept_front_end and r is not None:
            notes.append(f"{m}: with its {res.accepted} loop closures the back end placed revisited places "
                         f"{r.optimised * 100:.1f} cm from where they were seen before, the front end alone "
                         f"{r.frontend * 100:.1f} cm (mean over {r.points} points of {r.queries} keyframes): the "
                         f"outputs keep the front end's trajectory and map")
    return notes


def _steps(steps: Iterator[SweepStep], log: Path) -> Iterator[SweepStep]:
    """The runner's steps; a map that outgrows its budget is an error about this log."""
    try:
        yield from steps
    except MapSizeError as exc:
        raise LogError(f"{log}: {exc}") from None


def _process_notes(runner: LogRunner, inputs: LogInputs, topics: InputTopics) -> list[str]:
    """The run's notes on its inputs: no Doppler, skipped or repaired messages, sweeps outside the prior."""
    notes = []
    if not runner.doppler:
        notes.append(f"{topics.scan} carries no Doppler velocity: ego-motion and segmentation are off")
    notes += inputs.notes()
    if runner.beyond_prior:
        notes.append(f"{runner.beyond_prior} sweeps on {topics.scan} began after the last message on {topics.prior}: "
                     "processed with the motion prior held at its last pose")
    if (gaps := runner.gaps.warning(topics.scan)) is not None:
        notes.append(gaps)
    if runner.before_prior:
        notes.append(f"{runner.before_prior} sweeps on {topics.scan} began before the first message on {topics.prior}: "
                     "processed with the motion prior held at its first pose")
    return notes
