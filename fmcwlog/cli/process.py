"""``fmcwlog process``: a log's trajectories and maps by both front ends, or many logs' in workers."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..fleet.tasks import Limits
from .console import console, echo_out
from .exits import SomeFailed, UserError
from .loading import loading_modules
from .paths import as_path, as_paths
from .progress import NoBar, progress

if TYPE_CHECKING:
    from ..pipeline.options import ProcessOptions

_PROCESS_HELP = """Estimate the robot's trajectory and map from LOG with the paper's improved
front end and the classic ICP baseline, side by side, and write them to OUT_DIR.

\b
improved  Doppler ego-motion, fused with the wheels by weighted least squares at any
          mount -> DBSCAN segmentation of moving points (eq. 17-19, on ego-motion-
          compensated velocity), movers followed over time -> deskew -> nearest
          neighbours in a voxel map -> GMMSC rejection (eq. 20-21) -> Huber-robust
          Gauss-Newton ICP (eq. 22-26), with the fused motion as a soft prior
baseline  all points, wheel-odometry prior, classic point-to-point ICP (unit weights)

\b
Reads /fmcw/points (or --scan-topic: a PointCloud2 or a LaserScan; without a
velocity field the Doppler stages are off and run.json says so) and /wheel/ticks
with the fmcwlog.calibration record, or --odom-topic (nav_msgs/Odometry) as the
motion prior. Never reads /ground_truth/* or fmcwlog.world. A 3-D cloud (z spread
over heights, or a ring field) is brought down to the sensor's plane: the points
within 2 deg of it are kept (--set inputs.plane_band_deg=...), their Doppler
corrected for elevation. Point times: see --time-field.

\b
The LiDAR's mount, from the first that gives it: --calibration FILE, the log's
fmcwlog.calibration record, the log's /tf_static (or a /tf transform that never
changes) from the scan's frame_id to --base-frame, else 0, 0, 0 with a warning.
A record and tf that disagree are warned of, naming both. Wheel ticks need the
wheels (the file or the record); without them /odom is the prior, with a warning.
run.json's calibration_sources says where each came from.

\b
LOG: an MCAP log, a rosbag2 folder (sqlite3 or MCAP storage; or its .db3 file) or a
ROS 1 .bag, read as recorded. A bag holds no fmcwlog.calibration record: its mount
comes from tf, and wheel ticks need --calibration FILE (the record's keys in YAML;
docs/log-format.md), else /odom is the prior.

\b
Writes to OUT_DIR:
  improved.tum, baseline.tum, wheel_odometry.tum   t x y z qx qy qz qw (evo)
  trajectories.parquet   a row per sweep and method: t, x, y, yaw, ICP iterations,
                         correspondences kept, points judged moving, ms
  <method>_map.pgm/.yaml/.png   occupancy grids (ROS map_server)
  processed.mcap   estimated odometry, maps, static/moving points (Foxglove)
  run.json         parameters, version, inputs, counts, warnings
  with the back end (the default): <method>_frontend.tum, the front end's own trajectory
  before the loop closures, and <method>_backend.json, the pose graph and its closures

\b
Parameters: --config FILE (TOML/YAML/JSON with [frontend], [segmentation], [icp],
[icp.gmmsc] tables) or --set, e.g. --set segmentation.v_th=0.25 --set icp.huber_delta=0.05.
'fmcwlog process --show-config' prints them all as TOML, each with its unit and valid
range (a value outside it is refused); --config takes it back, and so does a previous
output's run.json (--config OUT/run.json).

\b
A damaged message is skipped and counted (run.json). More than 5 % of the sweeps
skipped is said on the last line, in run.json and in the report's header; more than
half is an error, and no OUT_DIR (a failed log in a batch), unless --keep-going.

\b
--force replaces OUT_DIR only if fmcwlog made it (its .fmcwlog-output lists everything
in it), never a folder holding anything else or the LOG.

\b
Many logs: give several LOGs, or folders (searched for *.mcap, *.bag and rosbag2
folders, sub-folders too).
Each log's results go to OUT_DIR/<its name>/, the same files as a run on that log
alone, and OUT_DIR/batch.json records what became of every log. Each log runs in a
worker process of its own, --jobs at a time (default: every core), and a log that
is corrupt, raises, runs past --timeout or past --memory-limit fails alone, with its
reason, while the others finish; the exit status is then 1. Running the same command
again skips the logs whose results are complete and were made from the same bytes
and the same options (--force redoes them). --ray runs the logs as tasks on a Ray
cluster instead (pip install 'fmcwlog[ray]'): '--ray' alone starts a local Ray,
'--ray=ADDRESS' joins one (e.g. --ray=auto on a node of the cluster). Then
'fmcwlog report OUT_DIR' writes every log's report and the fleet page.
"""


TIME_FIELD_OPTION_HELP = ("The PointCloud2 field holding each point's time, and its unit: s, ms, us or ns after "
                          "header.stamp, abs_s or abs_ns since the epoch (e.g. time:s).  [default: by name and type: "
                          "t (float s, uint32 ns), time_offset_ns (uint32 ns), timestamp (float64 s since the epoch)]")


@click.command("process", help=_PROCESS_HELP)
@click.argument("logs", nargs=-1, type=click.Path(), callback=as_paths)
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False), callback=as_path,
              help="Output folder (created; must be empty unless --force).")
@click.option("--method", type=click.Choice(["improved", "baseline", "all"]), default="all", show_default=True,
              help="Which front end(s) to run; 'all' runs both in one pass over the log.")
@click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Parameter file (TOML, YAML or JSON).")
@click.option("--set", "set_items", multiple=True, metavar="SECTION.NAME=VALUE", help="Override one parameter; repeatable.")
@click.option("--scan-topic", default=None,
              help="Scan topic.  [default: /fmcw/points, else /scan, else the log's only scan topic]")
@click.option("--ticks-topic", default=None, help="Wheel-ticks topic.  [default: /wheel/ticks]")
@click.option("--odom-topic", default=None,
              help="nav_msgs/Odometry topic to use as the motion prior instead of ticks.  [default: /odom when the "
                   "log has no wheel ticks]")
@click.option("--calibration", "calibration_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Calibration file (from 'fmcwlog calibrate', or by hand: the fmcwlog.calibration record's keys, "
                   "e.g. '{lidar_x: 0.35, lidar_y: 0.0, lidar_yaw: 0.0}'); its values go before the log's record "
                   "and its tf.")
@click.option("--base-frame", default="base_link", show_default=True,
              help="The robot's frame: where neither --calibration nor the log's record gives the mount, it is "
                   "the scan's frame_id in this frame through the log's /tf_static (and /tf where it never changes).")
@click.option("--time-field", metavar="NAME:UNIT", default=None, help=TIME_FIELD_OPTION_HELP)
@click.option("--backend", type=click.Choice(["pose-graph", "none"]), default="pose-graph", show_default=True,
              help="Loop closures in a pose graph for every method (the outputs come from the optimised poses, "
                   "the front end's kept as <method>_frontend.tum), or 'none': the front ends alone.")
@click.option("--force", is_flag=True, help="Replace OUT_DIR if it is an output folder fmcwlog made.")
@click.option("--keep-going", is_flag=True,
              help="Process a log even if more than half of its sweeps had to be skipped as damaged (else it is an "
                   "error, and a failed log in a batch); the share skipped is said on the last line, in run.json "
                   "and in the report. More than 5 % is always said so.")
@click.option("--show-config", is_flag=True,
              help="Print the parameters that would be used as TOML (each with its unit and valid range; "
                   "--config takes it back), and exit.")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=None,
              help="Many logs: how many to process at once, each in a worker of its own.  One log: 1 runs both "
                   "methods in this process, 2 or more the baseline in a process of its own (the same outputs, "
                   "sooner).  [default: every core]")
@click.option("--timeout", "timeout_s", type=click.FloatRange(min=0), default=0.0, metavar="SECONDS",
              help="Many logs: a log still running after this long is stopped and reported failed (0: no limit).")
@click.option("--memory-limit", "memory_limit_mb", type=click.IntRange(min=0), default=Limits().memory_limit_mb,
              show_default=True, metavar="MB",
              help="Many logs: each worker's address-space cap (a worker maps about 1.7 GB for 250 MB resident); a "
                   "log that needs more fails alone. On Ray, each task also declares this much memory. 0: no cap.")
@click.option("--ray", "ray_address", is_flag=False, flag_value="local", default=None, metavar="[ADDRESS]",
              help="Many logs: run them as Ray tasks. '--ray' starts a local Ray; '--ray=ADDRESS' joins a cluster "
                   "(auto, HOST:6379, ray://HOST:10001).")
@click.option("--retries", type=click.IntRange(min=0), default=2, show_default=True,
              help="With --ray: how often Ray retries a log whose worker or node died.")
def process_cmd(logs, out_dir, method, config_file, set_items, scan_topic, ticks_topic, odom_topic, calibration_file,
                base_frame, time_field, backend, force, keep_going, show_config, jobs, timeout_s, memory_limit_mb, ray_address,
                retries):
    with loading_modules():  # here: --help needs none of the estimation stack
        from ..pipeline.options import ProcessOptions
        from ..pipeline.params import params_from, params_toml

    params = params_from(config_file, set_items)
    if show_config:
        echo_out(params_toml(params), nl=False)
        return
    _check_arguments(logs, out_dir, ray_address)
    methods = ProcessOptions().methods if method == "all" else (method,)
    opts = ProcessOptions(methods, scan_topic, ticks_topic, odom_topic, params, calibration=calibration_file,
                              backend=backend, base_frame=base_frame, keep_going=keep_going, time_field=time_field)
    opts.cloud_reading()  # a --time-field that is not NAME:UNIT: one line before any work
    from ..io.logs import is_rosbag2_folder

    if len(logs) == 1 and (not logs[0].is_dir() or is_rosbag2_folder(logs[0])) and ray_address is None:
        if timeout_s or memory_limit_mb != Limits().memory_limit_mb:
            console.warning("--timeout and --memory-limit apply to several logs (each in its worker); one log runs "
                            "here, in this process, without them")
        process_log(logs[0], out_dir, opts, force, jobs)
        return
    _process_many(list(logs), out_dir, opts, force, jobs, Limits(memory_limit_mb, timeout_s), ray_address, retries)


def _check_arguments(logs: tuple[Path, ...], out_dir: Path | None, ray_address: str | None) -> None:
    """The arguments click cannot require, as --show-config goes without them; and a LOG --ray swallowed."""
    if ray_address not in (None, "local") and Path(ray_address).exists():
        raise UserError(f"--ray took {ray_address!r} as its ADDRESS: put --ray after the logs, or write --ray=ADDRESS")
    if not logs:
        raise UserError("missing LOG: the log(s) (MCAP, rosbag2 folder, ROS 1 .bag) or folder(s) to process")
    if out_dir is None:
        raise UserError("missing -o/--output: the folder to write")


def process_log(log: Path, out_dir: Path, opts: ProcessOptions, force: bool, jobs: int | None = None) -> str | None:
    """One log, here (``process`` and ``run``): a progress bar with sweeps/s, then times, closures, warnings.
    The share of sweeps skipped, where more than 5 %, is the last line; it is returned for ``run``'s own last
    line."""
    import time

    with loading_modules():
        from ..pipeline.process import process

    bar = None
    started = time.perf_counter()

    def on_sweep(done: int, total: int | None) -> None:
        nonlocal bar
        if bar is None:
            bar = progress(total, "processing",
                           lambda d: f"{(d or 0) / max(time.perf_counter() - started, 1e-9):.0f} sweeps/s")
            bar.__enter__()
        bar.update(1, current_item=done)

    try:
        summary = process(log, out_dir, opts, force=force, on_sweep=on_sweep, jobs=jobs)
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    wall = time.perf_counter() - started
    console.info(f"processed {summary.sweeps} sweeps in {wall:.1f} s ({summary.sweeps / wall:.0f} sweeps/s); "
                 f"prior: {summary.prior}; Doppler: {'on' if summary.doppler else 'off'}")
    for m, ms in summary.ms_median.items():
        console.info(f"  {m:9s} median {ms:.2f} ms per sweep")
    for m, b in summary.backend.items():
        console.info(f"  {m:9s} back end: {b['closures_accepted']} loop closures accepted of {b['closures_verified']} "
                     f"verified, {b['closures_proposed']} proposed; {b['seconds']:.1f} s")
    for w in summary.warnings:
        if w != summary.many_skipped:
            console.warning(w)
    console.info(f"wrote {summary.out_dir}/")
    if summary.many_skipped:
        console.warning(summary.many_skipped)
    return summary.many_skipped


def _process_many(logs: list[Path], out_dir: Path, opts: ProcessOptions, force: bool, jobs: int | None,
                  limits: Limits, ray_address: str | None, retries: int) -> None:
    """Many logs in workers (or on Ray): a bar of logs done (a line per log in a pipe), then the totals and
    each failure; some failed: exit status 1."""
    from ..fleet.batch import process_many

    bar, shown = None, 0

    def on_progress(p) -> None:
        nonlocal bar, shown
        if bar is None:  # logs done of those to run, then: done, failed, sweeps/s over all workers, time left
            bar = progress(p.total, "logs", lambda p: p and _progress_line(p), show_eta=False)
            bar.__enter__()
        if p.finished > shown:
            bar.update(p.finished - shown, current_item=p)
            shown = p.finished
            if isinstance(bar, NoBar) and p.last is not None:  # a pipe or CI log: a line as each log ends
                console.info(_outcome_line(p))
        else:  # a worker's sweeps: the same count of logs, new figures
            bar.current_item = p
            bar.render_progress()

    try:
        summary = process_many(logs, out_dir, opts, force=force, jobs=jobs, limits=limits,
                                   ray=ray_address is not None,
                                   ray_address=None if ray_address in (None, "local") else ray_address,
                                   retries=retries, on_progress=on_progress)
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    done, skipped, failed = summary.count("done"), summary.count("skipped"), summary.failed
    rate = f" ({summary.sweeps / summary.wall_s:.0f} sweeps/s)" if done and summary.wall_s > 0 else ""
    console.info(f"{len(summary.outcomes)} logs: {done} processed, {summary.sweeps} sweeps in {summary.wall_s:.1f} s"
                 f"{rate} on {summary.executor}; {skipped} skipped (complete already); {len(failed)} failed")
    for o in failed:
        console.warning(o.reason if str(o.log) in (o.reason or "") else f"{o.log}: {o.reason}")
    console.info(f"wrote {out_dir}/<log>/ for each log and {out_dir / 'batch.json'}; "
                 f"'fmcwlog report {out_dir}' for the fleet page")
    if failed:
        raise SomeFailed(f"{len(failed)} of {len(summary.outcomes)} logs failed (reasons above, details in "
                         f"{out_dir / 'batch.json'})")


def _outcome_line(p) -> str:
    """``[3/10] name: done, 300 sweeps in 12.0 s`` (or why it failed), for the log that just ended."""
    o = p.last
    what = f"failed: {o.reason}" if o.status == "failed" else f"{o.status}, {o.sweeps} sweeps in {o.wall_s:.1f} s"
    return f"[{p.finished}/{p.total}] {o.name}: {what}"


def _progress_line(p) -> str:
    """What the bar shows beside the count of logs: done, failed, sweeps/s over all workers, time left."""
    eta = p.eta_s
    left = "" if eta is None else f", {int(eta // 60)}m{int(eta % 60):02d}s left"
    return f"{p.done} done, {p.failed} failed, {p.sweeps_per_s:.0f} sweeps/s{left}"
