"""``fmcwlog process``: read a log once, run the front ends side by side, write the outputs.

The log is streamed in file order. A sweep waits in a short queue until the
motion prior (wheel ticks or an Odometry topic) covers its whole duration,
then every method processes it. Outputs go to a temporary folder that is
renamed to the requested one only when everything is written.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import time
import warnings
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from . import __version__
from .calibration import CalibrationError, parse_calibration
from .config_files import ConfigError, apply_to_dataclass
from .geometry import compose, inverse
from .mcap_io import (
    CALIBRATION_KEY,
    POINTS_TOPIC,
    TICKS_TOPIC,
    LogError,
    LogReader,
    OdomInput,
    SweepInput,
    TicksInput,
    iter_inputs,
)
from .outputs import ProcessedLog, write_grid, write_run_json, write_trajectories_parquet, write_tum
from .pipeline import METHODS, FrontEnd, FrontEndParams, doppler_stages
from .prior import PoseTrack

WHEEL_ODOMETRY = "wheel_odometry"


@dataclass
class ProcessOptions:
    methods: tuple[str, ...] = METHODS
    scan_topic: str | None = None  # default: /fmcw/points, else the log's only scan topic
    ticks_topic: str | None = None  # default: /wheel/ticks when present
    odom_topic: str | None = None  # an Odometry topic as the prior instead of ticks
    params: FrontEndParams = field(default_factory=FrontEndParams)


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


def load_params(config: dict | None, overrides: dict[str, dict] | None) -> FrontEndParams:
    """Front-end parameters from a parsed config file and ``--set`` overrides.

    Top-level keys of FrontEndParams go in a ``[frontend]`` table; the nested
    ``[segmentation]``, ``[icp]`` and ``[icp.gmmsc]`` tables set those stages.
    """
    params = FrontEndParams()
    for source in (config or {}, overrides or {}):
        for section, values in source.items():
            if not isinstance(values, dict):
                raise ConfigError(f"[{section}] must be a table of parameters")
            if section == "frontend":
                params = apply_to_dataclass(params, values, "frontend")
            elif section in ("segmentation", "icp"):
                params = dataclasses.replace(params, **{section: apply_to_dataclass(getattr(params, section), values, section)})
            else:
                raise ConfigError(f"unknown section [{section}] (known: frontend, segmentation, icp)")
    return params


def _choose_topics(reader: LogReader, opts: ProcessOptions) -> tuple[str, str | None, str | None]:
    topics = reader.topics
    path = reader.path
    scan = opts.scan_topic
    if scan is None:
        if POINTS_TOPIC in topics:
            scan = POINTS_TOPIC
        elif "/scan" in topics:
            scan = "/scan"
        else:
            scans = [t for t, s in topics.items() if s.endswith(("PointCloud2", "LaserScan")) and not t.startswith("/ground_truth")]
            if len(scans) != 1:
                found = ", ".join(sorted(scans)) or "none"
                raise LogError(f"{path}: no usable scan topic (PointCloud2 or LaserScan; found: {found}); "
                               "name one with --scan-topic")
            scan = scans[0]
    if scan not in topics:
        raise LogError(f"{path}: no topic {scan}")
    if not topics[scan].endswith(("PointCloud2", "LaserScan")):
        raise LogError(f"{path}: {scan} is {topics[scan]}, not a PointCloud2 or LaserScan")
    ticks, odom = opts.ticks_topic, opts.odom_topic
    if odom is not None:
        if odom not in topics:
            raise LogError(f"{path}: no topic {odom}")
        return scan, None, odom
    if ticks is None and TICKS_TOPIC in topics:
        ticks = TICKS_TOPIC
    if ticks is None and topics.get("/odom", "").endswith("Odometry"):  # an imported or ROS log
        return scan, None, "/odom"
    if ticks is not None and ticks not in topics:
        raise LogError(f"{path}: no topic {ticks}")
    return scan, ticks, None


def _prepare_out_dir(out_dir: Path, force: bool) -> Path:
    if out_dir.exists():
        if not out_dir.is_dir():
            raise LogError(f"{out_dir}: exists and is not a folder")
        if any(out_dir.iterdir()) and not force:
            raise LogError(f"{out_dir}: exists and is not empty; use --force to replace it")
    tmp = out_dir.parent / f".{out_dir.name}.partial-{os.getpid()}"
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
    except OSError as exc:
        raise LogError(f"{out_dir}: cannot create it ({exc.strerror})") from None
    return tmp


def process_log(
    log: str | Path,
    out_dir: str | Path,
    opts: ProcessOptions = ProcessOptions(),
    force: bool = False,
    on_sweep: Callable[[int, int | None], None] | None = None,
) -> ProcessSummary:
    """Run ``opts.methods`` over ``log`` and write everything into ``out_dir``.

    ``on_sweep(done, total)`` is called after each sweep (total None when unknown).
    Raises :class:`LogError` for input that cannot be processed.
    """
    log, out_dir = Path(log), Path(out_dir)
    started = time.perf_counter()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = LogReader(log)
        scan_topic, ticks_topic, odom_topic = _choose_topics(reader, opts)
        try:
            cal = parse_calibration(reader.metadata.get(CALIBRATION_KEY), need_wheels=ticks_topic is not None)
        except CalibrationError as exc:
            raise LogError(f"{log}: {exc}") from None
        total = reader.message_count(scan_topic)
        tmp = _prepare_out_dir(out_dir, force)
        try:
            summary = _run(reader, tmp, opts, cal, scan_topic, ticks_topic, odom_topic, total, on_sweep)
            summary_warnings = [str(w.message) for w in caught]
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    summary.warnings = summary_warnings + summary.warnings
    info = {
        "fmcwlog_version": __version__,
        "log": str(log.resolve()),
        "log_size_bytes": log.stat().st_size,
        "methods": list(opts.methods),
        "scan_topic": scan_topic,
        "prior": summary.prior,
        "doppler": summary.doppler,
        "mount": list(cal.mount),
        "params": dataclasses.asdict(opts.params),
        "sweeps": summary.sweeps,
        "skipped_sweeps": summary.skipped_sweeps,
        "repeated_prior_stamps": summary.repeated_prior_stamps,
        "truncated_log": summary.truncated,
        "warnings": summary.warnings,
        "ms_per_sweep_median": summary.ms_median,
        "wall_seconds": round(time.perf_counter() - started, 3),
    }
    write_run_json(tmp / "run.json", info)
    if out_dir.exists():
        shutil.rmtree(out_dir)
    os.replace(tmp, out_dir)
    summary.out_dir = out_dir
    return summary


def _run(reader, tmp, opts, cal, scan_topic, ticks_topic, odom_topic, total, on_sweep) -> ProcessSummary:
    params = opts.params
    fronts = {m: FrontEnd(m, params, cal) for m in opts.methods}
    prior = PoseTrack() if (ticks_topic or odom_topic) else None
    rows: dict[str, list] = {k: [] for k in ("method", "stamp_ns", "x", "y", "yaw", "icp_iterations",
                                             "correspondences", "moving_points", "ms")}
    traj: dict[str, tuple[list, list]] = {m: ([], []) for m in (*opts.methods, WHEEL_ODOMETRY)}
    pending: deque[SweepInput] = deque()
    processed = ProcessedLog(tmp / "processed.mcap")
    state = {"done": 0, "skipped": 0, "last_stamp": None, "doppler": None, "wheel0": None}
    sweep_span = 0.0

    def run_sweep(sweep: SweepInput) -> None:
        dop, dop_ms = (None, 0.0)
        if "improved" in fronts:
            twist = None
            if prior is not None and len(prior) >= 2:
                span = max(float(sweep.t.max()), 1e-3)
                d = prior.delta(sweep.stamp_ns * 1e-9, sweep.stamp_ns * 1e-9 + span)
                twist = (d[0] / span, d[2] / span)
            dop, dop_ms = doppler_stages(sweep, cal, params, twist)
        state["doppler"] = sweep.velocity is not None
        for m, fe in fronts.items():
            r = fe.step(sweep, prior, dop if m == "improved" else None)
            ms = r.ms + (dop_ms if m == "improved" else 0.0)
            for k, v in (("method", m), ("stamp_ns", r.stamp_ns), ("x", r.pose[0]), ("y", r.pose[1]),
                         ("yaw", r.pose[2]), ("icp_iterations", r.iterations), ("correspondences", r.correspondences),
                         ("moving_points", r.moving_points), ("ms", ms)):
                rows[k].append(v)
            traj[m][0].append(r.stamp_ns)
            traj[m][1].append(r.pose)
            processed.sweep(m, r.stamp_ns, r.pose, r.static_map_xy, r.moving_map_xy)
            if m == "improved" and dop is not None:
                processed.moving_labels(m, r.stamp_ns, r.moving_mask)
        if prior is not None and len(prior):
            p = prior.pose_at(sweep.stamp_ns * 1e-9)
            if state["wheel0"] is None:
                state["wheel0"] = p
            rel = compose(inverse(state["wheel0"]), p)
            traj[WHEEL_ODOMETRY][0].append(sweep.stamp_ns)
            traj[WHEEL_ODOMETRY][1].append(rel)
            processed.odometry(f"/{WHEEL_ODOMETRY}/odom", sweep.stamp_ns, rel)
        state["done"] += 1
        if on_sweep:
            on_sweep(state["done"], total)

    try:
        for item in iter_inputs(reader, scan_topic, ticks_topic, odom_topic):
            if isinstance(item, SweepInput):
                last = state["last_stamp"]
                if last is not None and item.stamp_ns < last:
                    raise LogError(f"{reader.path}: sweep stamps go backwards at {item.stamp_ns} ns "
                                   f"(after {last} ns)")
                if last is not None and item.stamp_ns == last:
                    state["skipped"] += 1
                    continue
                if len(item.xy) == 0:
                    raise LogError(f"{reader.path}: the sweep at {item.stamp_ns} ns has no points")
                state["last_stamp"] = item.stamp_ns
                sweep_span = max(sweep_span, float(item.t.max()))
                pending.append(item)
            else:
                try:
                    if isinstance(item, TicksInput):
                        prior.add_ticks(item.stamp_ns * 1e-9, item.left, item.right, cal.wheels)
                    elif isinstance(item, OdomInput):
                        prior.add_pose(item.stamp_ns * 1e-9, item.pose)
                except ValueError as exc:
                    raise LogError(f"{reader.path}: {exc}") from None
            while pending and (prior is None or prior.latest_time >= pending[0].stamp_ns * 1e-9 + sweep_span):
                run_sweep(pending.popleft())
        while pending:  # the end of the log: the prior is extrapolated by holding its last pose
            run_sweep(pending.popleft())
        if state["done"] == 0:
            raise LogError(f"{reader.path}: no sweeps on {scan_topic}")
        if prior is not None and len(prior) == 0:
            raise LogError(f"{reader.path}: no messages on {ticks_topic or odom_topic}, the motion prior")
        last_ns = int(rows["stamp_ns"][-1])
        for m, fe in fronts.items():
            write_grid(tmp, f"{m}_map", fe.grid)
            processed.grid(m, last_ns, fe.grid)
        processed.close()
    except BaseException:
        processed.abort()
        raise

    for m, (stamps, poses) in traj.items():
        if stamps:
            write_tum(tmp / f"{m}.tum", np.asarray(stamps), np.asarray(poses))
    write_trajectories_parquet(tmp / "trajectories.parquet", rows)
    ms = {m: float(np.median([r for r, mm in zip(rows["ms"], rows["method"]) if mm == m])) for m in fronts}
    prior_name = f"wheel ticks ({ticks_topic})" if ticks_topic else (f"odometry ({odom_topic})" if odom_topic
                                                                      else "none (constant velocity)")
    notes = []
    if not state["doppler"]:
        notes.append(f"{scan_topic} carries no Doppler velocity: ego-motion and segmentation are off")
    if state["skipped"]:
        notes.append(f"{state['skipped']} sweeps with a repeated stamp were skipped")
    if prior is not None and prior.repeated_stamps:
        notes.append(f"{prior.repeated_stamps} motion-prior messages with a repeated stamp were skipped")
    return ProcessSummary(tmp, state["done"], bool(state["doppler"]), prior_name, state["skipped"],
                          prior.repeated_stamps if prior else 0, ms, reader.contents.truncated, notes)
