"""The library surface: what the command line does, as functions (evo's ``main_*`` modules).

    from fmcwlog import api
    api.record(api.scenario("corridor"), api.SimConfig(), "corridor.mcap")
    summary = api.process("corridor.mcap", "out/")
    ev = api.report("out/")                  # ev.result["methods"]["improved"]["ate_rmse_m"]

Every function raises :class:`fmcwlog.errors.FmcwlogError` (with a one-line message
naming the file and the problem) for input it cannot use, and leaves nothing
half-written behind.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .backend import BackendResult, PoseGraphBackend
from .errors import CalibrationError, ConfigError, LogError
from .evaluation.evaluate import Evaluation, evaluate
from .evaluation.pages import comparison_rows, markdown_table, write_report
from .frontend.methods import METHOD_NAMES, WHEEL_ODOMETRY
from .frontend.params import FrontEndParams
from .frontend.runner import LogRunner
from .io.atomic import atomic_folder, check_output_folder, json_text, write_json, write_text
from .io.calibration import parse_calibration
from .io.carmen import parse_log
from .io.carmen_import import ImportSummary, write_mcap
from .io.inputs import choose_topics, iter_inputs
from .io.mcap_log import LogReader
from .io.outputs import ProcessOutputs, odom_frame
from .io.topics import CALIBRATION_KEY
from .sim.config import SimConfig
from .sim.recorder import RecordSummary
from .sim.recorder import record as _record
from .sim.scenarios import DEFAULT_SCENARIO, SCENARIOS
from .sim.world import World

logger = logging.getLogger(__name__)

__all__ = ["SimConfig", "FrontEndParams", "ProcessOptions", "ProcessSummary", "Evaluation", "scenario", "record",
           "process", "evaluate", "report", "compare", "import_carmen"]


def scenario(name: str = DEFAULT_SCENARIO) -> World:
    """A built-in world by name (``corridor``, ``static``, ``crowd``, ``long-corridor``)."""
    return SCENARIOS[name]()


def record(world: World, cfg: SimConfig, out: str | Path,
           on_progress: Callable[[int], None] | None = None) -> RecordSummary:
    """Simulate ``cfg.run.duration`` seconds of ``world`` and write the log to ``out``."""
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
    """

    methods: tuple[str, ...] = METHOD_NAMES
    scan_topic: str | None = None
    ticks_topic: str | None = None
    odom_topic: str | None = None
    params: FrontEndParams = field(default_factory=FrontEndParams)
    publish_period: float = 5.0
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
    ms_median: dict[str, float]
    truncated: bool
    warnings: list[str]
    backend: dict[str, dict] = field(default_factory=dict)  # per method: BackendResult.summary()


def process(log: str | Path, out_dir: str | Path, opts: ProcessOptions | None = None, force: bool = False,
            on_sweep: Callable[[int, int | None], None] | None = None) -> ProcessSummary:
    """Run ``opts.methods`` over ``log`` and write everything into ``out_dir``.

    ``on_sweep(done, total)`` is called after each sweep (total None when unknown). The
    outputs are written to a temporary folder that replaces ``out_dir`` when complete.
    """
    opts = opts or ProcessOptions()
    if opts.backend not in BACKENDS:
        raise ConfigError(f"unknown back end {opts.backend!r} (known: {', '.join(BACKENDS)})")
    log, out_dir = Path(log), Path(out_dir)
    started = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = LogReader(log)
        topics = choose_topics(reader, opts.scan_topic, opts.ticks_topic, opts.odom_topic)
        try:
            cal = parse_calibration(reader.metadata.get(CALIBRATION_KEY), need_wheels=topics.ticks is not None)
        except CalibrationError as exc:
            raise LogError(f"{log}: {exc}") from None
        total = reader.message_count(topics.scan)
        logger.debug("%s: scan %s, prior %s, %s sweeps, lidar at x %.3f m, y %.3f m, yaw %.4f rad",
                  reader.path, topics.scan, topics.prior or "none",
                  total if total is not None else "an unknown number of", *cal.mount)
        check_output_folder(out_dir, force)
        with atomic_folder(out_dir) as tmp:
            runner = LogRunner(opts.methods, opts.params, cal, topics, reader.path)
            trajectories = (*opts.methods, WHEEL_ODOMETRY) if topics.prior else tuple(opts.methods)
            outputs = ProcessOutputs(tmp, trajectories, np.asarray(cal.mount), opts.publish_period)
            grids = {fe.name: fe.grid for fe in runner.fronts}
            backends = {m: PoseGraphBackend(opts.params.backend, np.asarray(cal.mount), opts.params.map_resolution)
                        for m in opts.methods} if opts.backend == "pose-graph" else {}
            try:
                searches = _feed(runner, iter_inputs(reader, topics), outputs, backends, grids,
                                 lambda: on_sweep(runner.sweeps, total) if on_sweep else None)
                optimised = _optimise(backends, outputs, grids, tmp)
                outputs.finish(grids)
            except BaseException:
                outputs.abort()
                raise
            notes = [str(w.message) for w in caught] + _process_notes(runner, topics.scan)
            if topics.ticks:
                prior = f"wheel ticks ({topics.ticks})"
            else:
                prior = f"odometry ({topics.odom})" if topics.odom else "none (constant velocity)"
            summary = ProcessSummary(out_dir, runner.sweeps, bool(runner.doppler), prior, runner.skipped_sweeps,
                                     runner.repeated_prior_stamps, outputs.ms_median(), reader.contents.truncated,
                                     notes, {m: res.summary() for m, res in optimised.items()})
            write_json(tmp / "run.json", {
                "fmcwlog_version": __version__,
                "log": str(log.resolve()),
                "log_size_bytes": log.stat().st_size,
                "methods": list(opts.methods),
                "scan_topic": topics.scan,
                "prior": summary.prior,
                "doppler": summary.doppler,
                "mount": list(cal.mount),
                "frames": {name: odom_frame(name) for name in trajectories},
                "params": dataclasses.asdict(opts.params),
                "sweeps": summary.sweeps,
                "skipped_sweeps": summary.skipped_sweeps,
                "repeated_prior_stamps": summary.repeated_prior_stamps,
                "truncated_log": summary.truncated,
                "warnings": summary.warnings,
                "ms_per_sweep_median": summary.ms_median,
                "correlative_searches": {m: {"run": n, "kept": k, "sweeps": summary.sweeps}
                                         for m, (n, k) in searches.items()},
                "backend": {"kind": opts.backend, **summary.backend},
                "wall_seconds": round(time.perf_counter() - started, 3),
            }, sort_keys=True)
    return summary


def _feed(runner: LogRunner, inputs, outputs: ProcessOutputs, backends: dict[str, PoseGraphBackend],
          grids: dict, after_sweep: Callable[[], None]) -> dict[str, list[int]]:
    """Every sweep through the front ends, into the outputs and the back ends. Returns, per method,
    how many correlative searches ran and how many of them replaced the ICP's match."""
    searches = {fe.name: [0, 0] for fe in runner.fronts}
    for step in runner.run(inputs):
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


def _optimise(backends: dict[str, PoseGraphBackend], outputs: ProcessOutputs, grids: dict,
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


def _process_notes(runner: LogRunner, scan_topic: str) -> list[str]:
    notes = []
    if not runner.doppler:
        notes.append(f"{scan_topic} carries no Doppler velocity: ego-motion and segmentation are off")
    if runner.skipped_sweeps:
        notes.append(f"{runner.skipped_sweeps} sweeps with a repeated stamp were skipped")
    if runner.repeated_prior_stamps:
        notes.append(f"{runner.repeated_prior_stamps} motion-prior messages with a repeated stamp were skipped")
    return notes


def report(out_dir: str | Path, log: str | Path | None = None,
           relations: str | Path | None = None) -> Evaluation:
    """:func:`evaluate` ``out_dir`` and write report.html, report.md and report.json into it."""
    ev = evaluate(out_dir, log, relations=relations)
    write_report(ev)
    return ev


def compare(results: list[dict], target: str | Path) -> Path:
    """comparison.md and comparison.json of several reports' results in ``target``; returns the .md."""
    target = Path(target)
    target.mkdir(parents=True, exist_ok=True)
    header, rows = comparison_rows(results)
    write_text(target / "comparison.md", markdown_table(header, rows) + "\n")
    write_text(target / "comparison.json", json_text(results))
    return target / "comparison.md"


def import_carmen(source: str | Path, output: str | Path) -> tuple[ImportSummary, str]:
    """Convert a CARMEN or CMU course log into an fmcwlog MCAP log; returns the summary and the format."""
    parsed = parse_log(Path(source))
    return write_mcap(parsed, Path(output)), parsed.format
