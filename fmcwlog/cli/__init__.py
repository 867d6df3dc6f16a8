"""The ``fmcwlog`` command line: thin wrappers that parse options, call :mod:`fmcwlog.api`, and print.

Errors a user can fix (bad arguments, bad files: every :class:`fmcwlog.errors.FmcwlogError`)
end in one line on stderr, ``fmcwlog: error: ...``, and exit status 2; no traceback, no
partial output.
"""

from __future__ import annotations

from pathlib import Path

import click

from .. import __version__, api
from ..evaluation.published import PAPER_FEATURE_ERROR_REDUCTION_PCT
from ..fleet.tasks import Limits
from ..io.atomic import check_output_file, replacing_folder
from ..sim.config import SimConfig
from ..sim.scenarios import DEFAULT_SCENARIO, SCENARIOS
from ..sim.world import load_world
from .console import configure_logging, console
from .exits import SomeFailed, UserError, run_command_line
from .parameters import frontend_params, simulation_config
from .paths import as_path, as_paths
from .progress import NoBar, progress


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="fmcwlog")
@click.option("-q", "--quiet", is_flag=True, help="Print only warnings and errors (no progress, no tables).")
@click.option("-v", "--verbose", count=True, help="Also print what each step found (topics, calibration, counts).")
def cli(quiet: bool, verbose: int) -> None:
    """Record, process and evaluate FMCW LiDAR robot logs (MCAP, ROS 2 messages).

    \b
    fmcwlog record   simulate a robot with an FMCW LiDAR and wheel encoders -> log.mcap
    fmcwlog process  estimate trajectories and maps from a log, improved and baseline
    fmcwlog report   measure them against ground truth: a page, Markdown and JSON
    fmcwlog run      all three on a built-in scenario, into one folder
    fmcwlog import   real 2-D laser logs (CARMEN, CMU course format) -> log.mcap
    fmcwlog calibrate  the LiDAR's mount and the wheel radii from a log -> calib.yaml
    Logs follow the fmcwlog log format (LOG_FORMAT.md); they open in Foxglove.
    Run 'fmcwlog COMMAND --help' for each command's options, defaults and units.

    \b
    Shell completion (bash; zsh_source, fish_source for the others):
      eval "$(_FMCWLOG_COMPLETE=bash_source fmcwlog)"
    """
    configure_logging(quiet, verbose)


_RECORD_HELP = f"""Simulate a car-like robot with an FMCW LiDAR among moving people and carts,
and write the log (MCAP, ROS 2 CDR) with ground truth.

\b
Scenarios (--scenario, default {DEFAULT_SCENARIO}):
  corridor       ring corridor around a hall, the paper's 9 labelled features, a few walkers
  static         the same floor with nothing moving
  crowd          a hall where 20-40 % of the returns come from walking people and carts
  dense-crowd    the same hall packed: about half of the returns on movers, many crossing the beams
  long-corridor  100 m bare corridor: geometry alone cannot fix the along-axis position
  ring           a ring of corridors around a solid block: a lap's drift is left to loop closure
Or --world FILE: your own walls, features, movers and route (YAML/JSON; see the README).

\b
Topics written: /fmcw/points (10 Hz PointCloud2: x y z intensity velocity t, frame lidar),
/wheel/ticks (50 Hz cumulative rear-wheel counts), /ground_truth/odom (50 Hz),
/ground_truth/point_labels (10 Hz); metadata fmcwlog.calibration and fmcwlog.world.

\b
Sensor defaults are the paper's Table 1: 1550 nm, 270 deg FOV, 0.25 deg beams (1081),
30 m range, range noise 2 cm and resolution 2 cm, Doppler resolution 0.1 m/s, 10 Hz.
Any parameter can be changed with --config FILE ([sensor], [robot], [run] tables in
TOML, YAML or JSON) or --set SECTION.NAME=VALUE, e.g. --set sensor.range_sigma=0.03
--set robot.speed=1.5. 'fmcwlog record --show-config' prints them all as TOML, each
with its unit and valid range (a value outside it is refused); --config takes it back.

\b
The same --seed gives a byte-identical log. Ctrl-C stops early and still leaves a
valid, shorter log.
"""


@cli.command("record", help=_RECORD_HELP)
@click.option("-o", "--output", type=click.Path(dir_okay=False), callback=as_path, help="Log to write (.mcap).")
@click.option("--scenario", type=click.Choice(sorted(SCENARIOS)), default=None,
              help=f"Built-in world.  [default: {DEFAULT_SCENARIO}]")
@click.option("--world", "world_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="World file (YAML or JSON) instead of a built-in scenario.")
@click.option("--duration", type=float, default=None, help="Seconds to simulate.  [default: 30]")
@click.option("--seed", type=int, default=None, help="Random seed (noise, slip).  [default: 0]")
@click.option("--speed", type=float, default=None, help="Robot cruise speed, m/s.  [default: 1.0]")
@click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Parameter file: [sensor], [robot], [run] tables (TOML, YAML or JSON).")
@click.option("--set", "set_items", multiple=True, metavar="SECTION.NAME=VALUE",
              help="Override one parameter; repeatable. Applied after --config.")
@click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists (never an input file).")
@click.option("--show-config", is_flag=True,
              help="Print the parameters that would be used as TOML (each with its unit and valid range; "
                   "--config takes it back), and exit.")
def record_cmd(output, scenario, world_file, duration, seed, speed, config_file, set_items, force, show_config):
    if scenario and world_file:
        raise UserError("give --scenario or --world, not both")
    cfg = simulation_config(config_file, set_items, duration=duration, seed=seed, speed=speed)
    world = load_world(world_file) if world_file else api.scenario(scenario or DEFAULT_SCENARIO)
    if show_config:
        click.echo(cfg.toml(), nl=False)
        return
    if output is None:
        raise UserError("missing -o/--output: the log file to write")
    check_output_file(output, force, (world_file, config_file))
    _record(world, cfg, output)


def _record(world, cfg: SimConfig, output: Path) -> None:
    n = int(cfg.run.duration * cfg.sensor.scan_rate + 1e-9)
    with progress(n, f"recording {world.name}") as bar:
        last = [0]

        def step(done: int) -> None:
            bar.update(done - last[0])
            last[0] = done

        summary = api.record(world, cfg, output, on_progress=step)
    note = " (stopped early by Ctrl-C)" if summary.interrupted else ""
    console.info(
        f"wrote {summary.path}: {summary.seconds:.1f} s, {summary.sweeps} sweeps, "
        f"{summary.moving_fraction:.1%} of points on movers{note}"
    )


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
motion prior. Never reads /ground_truth/* or fmcwlog.world.

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
--force replaces OUT_DIR only if fmcwlog made it (its .fmcwlog-output lists everything
in it), never a folder holding anything else or the LOG.

\b
Many logs: give several LOGs, or folders (searched for *.mcap, sub-folders too).
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


@cli.command("process", help=_PROCESS_HELP)
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
              help="Calibration file (from 'fmcwlog calibrate', or by hand: the fmcwlog.calibration record's keys) "
                   "to use instead of the log's record.")
@click.option("--backend", type=click.Choice(["pose-graph", "none"]), default="pose-graph", show_default=True,
              help="Loop closures in a pose graph for every method (the outputs come from the optimised poses, "
                   "the front end's kept as <method>_frontend.tum), or 'none': the front ends alone.")
@click.option("--force", is_flag=True, help="Replace OUT_DIR if it is an output folder fmcwlog made.")
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
                backend, force, show_config, jobs, timeout_s, memory_limit_mb, ray_address, retries):
    from ..frontend.params import frontend_params_toml

    params = frontend_params(config_file, set_items)
    if show_config:
        click.echo(frontend_params_toml(params), nl=False)
        return
    if ray_address not in (None, "local") and Path(ray_address).exists():
        raise UserError(f"--ray took {ray_address!r} as its ADDRESS: put --ray after the logs, or write --ray=ADDRESS")
    if not logs:
        raise UserError("missing LOG: the .mcap file(s) or folder(s) to process")
    if out_dir is None:
        raise UserError("missing -o/--output: the folder to write")
    methods = api.ProcessOptions().methods if method == "all" else (method,)
    opts = api.ProcessOptions(methods, scan_topic, ticks_topic, odom_topic, params, calibration=calibration_file,
                              backend=backend)
    if len(logs) == 1 and not logs[0].is_dir() and ray_address is None:
        if timeout_s or memory_limit_mb != Limits().memory_limit_mb:
            console.warning("--timeout and --memory-limit apply to several logs (each in its worker); one log runs "
                            "here, in this process, without them")
        _process(logs[0], out_dir, opts, force, jobs)
        return
    _process_many(list(logs), out_dir, opts, force, jobs, Limits(memory_limit_mb, timeout_s), ray_address, retries)


def _process(log: Path, out_dir: Path, opts: api.ProcessOptions, force: bool, jobs: int | None = None) -> None:
    import time

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
        summary = api.process(log, out_dir, opts, force=force, on_sweep=on_sweep, jobs=jobs)
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
        console.warning(w)
    console.info(f"wrote {summary.out_dir}/")


_CALIBRATE_HELP = """Estimate the LiDAR's mount (lidar_x, lidar_y, lidar_yaw) and the wheels' effective
radii and track width from LOG itself, and write them as a calibration file that
'fmcwlog process LOG --calibration FILE' takes instead of the log's record.

\b
Doppler gives the LiDAR's velocity every sweep, the wheel ticks each wheel's rotation,
and scan matching the heading changes; their differences are the lever arm, the radii
and the track width (robust least squares over the sweeps where the robot moves). The
log needs Doppler, wheel ticks, and some turns (the lever arm shows only when turning);
what it cannot fix, and what agrees with the calibration within the estimate's
uncertainty, keeps the calibration's value; the file's comments give every estimate.

\b
'fmcwlog process' runs the same check and warns (run.json: calibration_check) when the
calibration disagrees with the log beyond the estimate's uncertainty; this command writes
the file. Units: metres and radians, the record's keys (LOG_FORMAT.md).
"""


@cli.command("calibrate", help=_CALIBRATE_HELP)
@click.argument("log", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Calibration file to write (.yaml).")
@click.option("--calibration", "calibration_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Start from this calibration file instead of the log's record.")
@click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Parameter file (TOML, YAML or JSON), as for 'process'.")
@click.option("--set", "set_items", multiple=True, metavar="SECTION.NAME=VALUE",
              help="Override one parameter; repeatable (e.g. --set self_calibration.min_speed=0.3).")
@click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists.")
def calibrate_cmd(log, output, calibration_file, config_file, set_items, force):
    check_output_file(output, force, (log, calibration_file, config_file))  # --force never overwrites an input
    params = frontend_params(config_file, set_items)
    summary = api.calibrate(log, output, api.ProcessOptions(methods=("improved",), params=params,
                                                             calibration=calibration_file), force=force)
    for name, c in summary.check["values"].items():
        flag = "  <- disagrees" if c["disagrees"] else ""
        what = "written" if name in summary.check["adopted"] else "kept   "
        console.info(f"  {name:18s} {what} {c['estimate']:+.5f} +- {c['sigma']:.5f}   (was {c['calibration']:+.5f}){flag}")
    for name, why in summary.check["not_estimated"].items():
        console.info(f"  {name:18s} kept: {why}")
    for w in summary.warnings:
        console.warning(w)
    console.info(f"wrote {summary.output}")
def _process_many(logs: list[Path], out_dir: Path, opts: api.ProcessOptions, force: bool, jobs: int | None,
                  limits: Limits, ray_address: str | None, retries: int) -> None:
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
        summary = api.process_many(logs, out_dir, opts, force=force, jobs=jobs, limits=limits,
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
    o = p.last
    what = f"failed: {o.reason}" if o.status == "failed" else f"{o.status}, {o.sweeps} sweeps in {o.wall_s:.1f} s"
    return f"[{p.finished}/{p.total}] {o.name}: {what}"


def _progress_line(p) -> str:
    eta = p.eta_s
    left = "" if eta is None else f", {int(eta // 60)}m{int(eta % 60):02d}s left"
    return f"{p.done} done, {p.failed} failed, {p.sweeps_per_s:.0f} sweeps/s{left}"


_REPORT_HELP = """Measure what 'fmcwlog process' wrote in OUT_DIR against the ground truth of the
log it came from (found through run.json, or --log), and write into OUT_DIR:

\b
  report.html   one self-contained page: trajectories over the walls, error along the
                path, feature errors of both methods (the paper's Figure 4), tables, maps
  report.md     the same tables for a pull request or a lab notebook
  report.json   stable keys for scripts, e.g. methods.improved.ate_rmse_m (see the README)

\b
Measured for improved, baseline and wheel odometry: ATE (RMSE, mean, median, max; SE(2)-
aligned and first-pose-aligned, as evo defines them), RPE over 1 m and 10 m (% of distance,
deg/m), each labelled feature's length in the map each method built and its error (the
paper's Tables 2 and 3, and the reduction of the average), precision/recall/F1 of the moving
points, ms per sweep. What cannot be computed is left empty with the reason.

With several OUT_DIRs, each gets its report and a comparison table is printed and
written to comparison.md/.json in --output (default: the current folder).

A batch folder (what 'fmcwlog process' wrote for many logs) gets each log's report in
its folder, and fleet.html and fleet.json: a row per log (duration, distance, sweeps,
ms per sweep, warnings, why it failed, ATE and feature errors where there is ground
truth), totals, and the logs that need a look: failed ones; with ground truth, the worst
errors; without, where the two methods disagree most or ICP ran out of correspondences.
"""


@cli.command("report", help=_REPORT_HELP)
@click.argument("out_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--log", "log", type=click.Path(dir_okay=False), callback=as_path, default=None,
              help="The log the folder was processed from (default: the one run.json names).")
@click.option("-o", "--output", "comparison_dir", type=click.Path(file_okay=False), callback=as_path, default=None,
              help="Where comparison.md/.json go when several folders are given.  [default: .]")
@click.option("--relations", type=click.Path(dir_okay=False), callback=as_path, default=None,
              help="A Freiburg relations file (t1 t2 x y z roll pitch yaw): the Kuemmerle et al. 2009 metric, "
                   "beside the published figures for that dataset.")
def report_cmd(out_dirs, log, comparison_dir, relations=None):
    from ..evaluation.pages import comparison_rows, terminal_table

    if log is not None and len(out_dirs) > 1:
        raise UserError("--log goes with a single output folder")
    batches = [d for d in out_dirs if api.is_batch_folder(d)]
    if batches:
        if len(out_dirs) > 1 or log is not None or relations is not None:
            raise UserError(f"{batches[0]}: a batch folder is reported alone (no other folders, --log or --relations)")
        _report_fleet(batches[0])
        return
    results = [_report(out_dir, log, relations) for out_dir in out_dirs]
    if len(results) > 1:
        header, rows = comparison_rows(results)
        console.info("\n" + terminal_table(header, rows))
        written = api.compare(results, comparison_dir or Path("."))
        console.info(f"wrote {written} and comparison.json")


def _report(out_dir: Path, log: Path | None, relations: Path | None) -> dict:
    from ..evaluation.pages import (
        DISAGREEMENT_HEADER,
        RELATIONS_HEADER,
        TRAJECTORY_HEADER,
        change_words,
        disagreement_rows,
        relations_rows,
        terminal_table,
        trajectory_rows,
    )

    ev = api.report(out_dir, log, relations)
    console.info(f"{out_dir}: {ev.result['sweeps']} sweeps of {ev.log.name}")
    if ev.gt is None and disagreement_rows(ev.result):  # a table of dashes would say nothing
        ref = ev.result["disagreement"]["reference"]
        console.info(f"no ground truth in {ev.log.name}: no errors; how far each trajectory is from the {ref} one "
                     f"once SE(2)-aligned onto it (as evo_ape -a), a disagreement, not an error:")
        console.info(terminal_table(DISAGREEMENT_HEADER, disagreement_rows(ev.result)))
    else:
        console.info(terminal_table(TRAJECTORY_HEADER[:8], [r[:8] for r in trajectory_rows(ev.result)]))
    if relations_rows(ev.result):
        console.info(terminal_table(RELATIONS_HEADER, relations_rows(ev.result)))
    scored = [r["relations"]["n"] for r in ev.result["methods"].values() if r.get("relations")]
    if relations is not None and not any(scored):  # the wrong file for this log, or stamps that never match
        console.warning(f"{relations}: none of its relations falls on this log's sweeps (each pose's stamp "
                        "must be within 1 ms of a relation's); nothing was scored")
    cmp = ev.result["feature_comparison"]
    if cmp and cmp["reduction_pct"] is not None:
        console.info(f"average feature error over the {cmp['features']} feature(s) both maps measure: "
                     f"{change_words(cmp['reduction_pct'])} (the paper: a {PAPER_FEATURE_ERROR_REDUCTION_PCT} % reduction)")
    console.info(f"wrote {ev.out_dir / 'report.html'} (and report.md, report.json)")
    return ev.result


def _report_fleet(out_dir: Path) -> None:
    from ..evaluation.fleet import FLEET_HEADER, fleet_rows
    from ..evaluation.pages import terminal_table

    with progress(None, "reporting") as bar:  # on a terminal; a batch's logs take several seconds each
        def reported(done: int, total: int, name: str) -> None:
            bar.length = total
            bar.update(1, name)

        result = api.report_fleet(out_dir, on_log=reported)
    t = result["totals"]
    console.info(f"{out_dir}: {t['logs']} logs, {t['done']} done, {t['failed']} failed, {t['sweeps']} sweeps, "
                 f"{t['duration_s'] / 60:.1f} min of log, {t['distance_m']:.0f} m")
    console.info(terminal_table(FLEET_HEADER, fleet_rows(result)))
    if result["flagged"]:
        console.info(f"\nneeds a look ({len(result['flagged'])}):")
        for f in result["flagged"]:
            console.info(f"  {f['name']}: " + "; ".join(f["flags"]))
    for r in result["logs"]:
        if r["report_error"]:
            console.warning(f"{r['name']}: no report: {r['report_error']}")
    console.info(f"wrote {out_dir / 'fleet.html'} (and fleet.json), and each log's report.html in its folder")


@cli.command("run")
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False), callback=as_path, default="fmcwlog-run",
              show_default=True, help="Folder for the log, the results and the report.")
@click.option("--scenario", type=click.Choice(sorted(SCENARIOS)), default=DEFAULT_SCENARIO, show_default=True,
              help="Built-in world (see 'fmcwlog record --help').")
@click.option("--duration", type=float, default=120.0, show_default=True, help="Seconds to simulate.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (noise, slip).")
@click.option("--force", is_flag=True, help="Replace OUT if 'fmcwlog run' made it (never a folder holding anything else).")
def run_cmd(out_dir, scenario, duration, seed, force):
    """Record a built-in scenario, process it with both front ends and report, into one folder:
    OUT/log.mcap, OUT/results/ (trajectories, maps, processed.mcap) and OUT/results/report.html.
    If any step fails, OUT is removed again (and what was there before put back).

    \b
    e.g.  fmcwlog run                                   # 2 min of corridor -> fmcwlog-run/
          fmcwlog run --scenario crowd --seed 3 -o crowd-run
    """
    cfg = simulation_config(duration=duration, seed=seed)
    with replacing_folder(out_dir, force, "fmcwlog run") as folder:
        log = folder / "log.mcap"
        _record(api.scenario(scenario), cfg, log)
        _process(log, folder / "results", api.ProcessOptions(), force=False)
        _report(folder / "results", None, None)
    console.info(f"\nopen {(out_dir / 'results' / 'report.html').resolve()} in a browser")


@cli.group("import")
def import_group() -> None:
    """Convert real robot logs into fmcwlog logs (LaserScan on /scan, Odometry on /odom)."""


@import_group.command("carmen")
@click.argument("sources", nargs=-1, required=True, type=click.Path(), callback=as_paths)
@click.option("-o", "--output", type=click.Path(), callback=as_path, required=True,
              help="Log to write (.mcap); with several sources or a folder, the folder to write them into.")
@click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists (never a SOURCE).")
def import_carmen_cmd(sources, output, force):
    """Convert a CARMEN log (plain, .xz, .gz or .bz2) into an MCAP log.

    \b
    Reads FLASER, RLASER (-> /rear_scan), ROBOTLASER1, RAWLASER1/2 (where no FLASER or
    ROBOTLASER1 / RLASER line gives that laser), ODOM and PARAM lines (the laser
    offset and field of view come from PARAM robot_frontlaser_offset / robot_front_laser_fov),
    and the CMU Wean Hall course format (O and L lines, centimetres), recognised by its first
    line. Stamps are the log's own ipc_timestamps, which benchmark relations refer to. Without
    ODOM lines, the odometry pose of each laser line becomes /odom. Malformed lines are
    skipped, counted and listed with their line numbers. Then: fmcwlog process OUTPUT -o DIR.

    \b
    Several SOURCES, or folders (searched for *.clf and *.log, plain, .gz, .xz or .bz2): each
    becomes OUTPUT/<name>.mcap; an existing one is kept unless --force, and a source that
    cannot be read is reported while the others go on (exit status 1 if any failed).
    Then: fmcwlog process OUTPUT -o DIR.
    """
    if len(sources) > 1 or sources[0].is_dir():
        _import_many(list(sources), output, force)
        return
    source = sources[0]
    if not source.is_file():
        raise UserError(f"{source}: {'no such file' if not source.exists() else 'not a regular file (a pipe or a device)'}")
    check_output_file(output, force, (source,))
    summary, fmt = api.import_carmen(source, output)
    console.info(f"wrote {output}: {summary.scans} scans, {summary.odometry} odometry poses (from "
               f"{summary.odometry_source}) over {summary.span_s:.1f} s; format {fmt}")
    if summary.bad_lines:
        shown = ", ".join(str(n) for n, _ in summary.bad_lines[:10])
        more = f" and {len(summary.bad_lines) - 10} more" if len(summary.bad_lines) > 10 else ""
        console.warning(f"skipped {len(summary.bad_lines)} malformed lines: {shown}{more} "
                   f"(first: line {summary.bad_lines[0][0]}: {summary.bad_lines[0][1]})")


def _import_many(sources: list[Path], out_dir: Path, force: bool) -> None:
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"{out_dir}: exists and is not a folder (several sources go into a folder)")
    outcomes = api.import_carmen_many(sources, out_dir, force=force)
    for o in outcomes:
        if o.status == "done" and o.summary is not None:
            bad = f", {len(o.summary.bad_lines)} malformed lines skipped" if o.summary.bad_lines else ""
            console.info(f"wrote {o.output}: {o.summary.scans} scans over {o.summary.span_s:.1f} s; format {o.format}{bad}")
        elif o.status == "skipped":
            console.info(f"kept {o.output}: it exists (--force converts it again)")
        else:
            console.warning(o.reason)
    failed = [o for o in outcomes if o.status == "failed"]
    if failed:
        raise SomeFailed(f"{len(failed)} of {len(outcomes)} sources failed (reasons above)")


def main() -> None:
    """The ``fmcwlog`` command: ``fmcwlog.__main__`` runs this once the modules are loaded."""
    run_command_line(cli)


if __name__ == "__main__":
    main()
