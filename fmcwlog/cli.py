"""The ``fmcwlog`` command line: thin wrappers that parse options, call :mod:`fmcwlog.api`, and print.

Errors a user can fix (bad arguments, bad files: every :class:`fmcwlog.errors.FmcwlogError`)
end in one line on stderr, ``fmcwlog: error: ...``, and exit status 2; no traceback, no
partial output.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import click

from . import __version__, api
from .config import parse_set_option, read_config_file
from .errors import FmcwlogError
from .evaluation.published import PAPER_FEATURE_ERROR_REDUCTION_PCT
from .sim.config import SimConfig, apply_overrides
from .sim.scenarios import DEFAULT_SCENARIO, SCENARIOS
from .sim.world import load_world

console = logging.getLogger("fmcwlog")  # what the CLI prints, through logging (-q, -v)


class UserError(click.ClickException):
    exit_code = 2


class _ConsoleHandler(logging.Handler):
    """Information to stdout as it is; warnings and errors to stderr as ``fmcwlog: warning: ...``."""

    def emit(self, record: logging.LogRecord) -> None:
        msg = record.getMessage()
        if record.levelno >= logging.WARNING:
            click.echo(f"fmcwlog: {record.levelname.lower()}: {msg}", err=True)
        else:
            click.echo(msg)


def _configure_logging(quiet: bool, verbose: int) -> None:
    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    console.handlers[:] = [_ConsoleHandler()]
    console.setLevel(level)
    console.propagate = False


class _NoBar:
    def update(self, n: int, current_item=None) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        pass


def _progress(total: int | None, label: str, rate_label=None):
    """A progress bar on stderr when it is a terminal (and not --quiet); silent in pipes and CI logs."""
    if not sys.stderr.isatty() or not console.isEnabledFor(logging.INFO):
        return _NoBar()
    return click.progressbar(length=total or 0, label=label, file=sys.stderr, show_pos=True,
                             item_show_func=rate_label or (lambda _: None))


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
    Logs follow the fmcwlog log format (LOG_FORMAT.md); they open in Foxglove.
    Run 'fmcwlog COMMAND --help' for each command's options, defaults and units.

    \b
    Shell completion (bash; zsh_source, fish_source for the others):
      eval "$(_FMCWLOG_COMPLETE=bash_source fmcwlog)"
    """
    _configure_logging(quiet, verbose)


_RECORD_HELP = f"""Simulate a car-like robot with an FMCW LiDAR among moving people and carts,
and write the log (MCAP, ROS 2 CDR) with ground truth.

\b
Scenarios (--scenario, default {DEFAULT_SCENARIO}):
  corridor       ring corridor around a hall, the paper's 9 labelled features, a few walkers
  static         the same floor with nothing moving
  crowd          a hall where 20-40 % of the returns come from walking people and carts
  dense-crowd    the same hall packed: about half of the returns on movers, many crossing the beams
  long-corridor  100 m bare corridor: geometry alone cannot fix the along-axis position
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
--set robot.speed=1.5. 'fmcwlog record --show-config' prints them all with their values.

\b
The same --seed gives a byte-identical log. Ctrl-C stops early and still leaves a
valid, shorter log.
"""


@cli.command("record", help=_RECORD_HELP)
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), help="Log to write (.mcap).")
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
@click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists.")
@click.option("--show-config", is_flag=True, help="Print the parameters that would be used, and exit.")
def record_cmd(output, scenario, world_file, duration, seed, speed, config_file, set_items, force, show_config):
    import json

    if scenario and world_file:
        raise UserError("give --scenario or --world, not both")
    cfg = SimConfig()
    if config_file:
        cfg = apply_overrides(cfg, read_config_file(config_file))
    flags: dict[str, dict] = {"run": {}, "robot": {}}
    if duration is not None:
        flags["run"]["duration"] = duration
    if seed is not None:
        flags["run"]["seed"] = seed
    if speed is not None:
        flags["robot"]["speed"] = speed
    cfg = apply_overrides(cfg, flags)
    cfg = apply_overrides(cfg, parse_set_option(set_items)).validate()
    world = load_world(world_file) if world_file else api.scenario(scenario or DEFAULT_SCENARIO)
    if show_config:
        click.echo(json.dumps(cfg.as_dict(), indent=2))
        return
    if output is None:
        raise UserError("missing -o/--output: the log file to write")
    if output.exists() and not force:
        raise UserError(f"{output}: exists; use --force to overwrite it")
    _record(world, cfg, output)


def _record(world, cfg: SimConfig, output: Path) -> None:
    output.parent.mkdir(parents=True, exist_ok=True)
    n = int(cfg.run.duration * cfg.sensor.scan_rate + 1e-9)
    with _progress(n, f"recording {world.name}") as bar:
        last = [0]

        def step(done: int) -> None:
            bar.update(done - last[0])
            last[0] = done

        try:
            summary = api.record(world, cfg, output, on_progress=step)
        except OSError as exc:
            raise UserError(f"{output}: cannot write ({exc.strerror or exc})") from None
    note = " (stopped early by Ctrl-C)" if summary.interrupted else ""
    console.info(
        f"wrote {summary.path}: {summary.seconds:.1f} s, {summary.sweeps} sweeps, "
        f"{summary.moving_fraction:.1%} of points on movers{note}"
    )


_PROCESS_HELP = """Estimate the robot's trajectory and map from LOG with the paper's improved
front end and the classic ICP baseline, side by side, and write them to OUT_DIR.

\b
improved  Doppler ego-motion -> DBSCAN segmentation of moving points (eq. 17-19, on
          ego-motion-compensated velocity) -> deskew -> nearest neighbours in a voxel
          map -> GMMSC rejection (eq. 20-21) -> Huber-robust Gauss-Newton ICP (eq. 22-26),
          with the Doppler velocity as a soft prior along the path
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

\b
Parameters: --config FILE (TOML/YAML/JSON with [frontend], [segmentation], [icp],
[icp.gmmsc] tables) or --set, e.g. --set segmentation.v_th=0.25 --set icp.huber_delta=0.05.
'fmcwlog process --show-config' lists them all with their defaults.
"""


@cli.command("process", help=_PROCESS_HELP)
@click.argument("log", type=click.Path(path_type=Path), required=False)
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False, path_type=Path),
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
@click.option("--force", is_flag=True, help="Replace OUT_DIR if it is not empty.")
@click.option("--show-config", is_flag=True, help="Print the parameters that would be used, and exit.")
def process_cmd(log, out_dir, method, config_file, set_items, scan_topic, ticks_topic, odom_topic, force, show_config):
    import dataclasses
    import json

    from .frontend.params import load_frontend_params

    params = load_frontend_params(read_config_file(config_file) if config_file else None, parse_set_option(set_items))
    if show_config:
        click.echo(json.dumps(dataclasses.asdict(params), indent=2))
        return
    if log is None:
        raise UserError("missing LOG: the .mcap file to process")
    if out_dir is None:
        raise UserError("missing -o/--output: the folder to write")
    methods = api.ProcessOptions().methods if method == "all" else (method,)
    _process(log, out_dir, api.ProcessOptions(methods, scan_topic, ticks_topic, odom_topic, params), force)


def _process(log: Path, out_dir: Path, opts: api.ProcessOptions, force: bool) -> None:
    import time

    bar = None
    started = time.perf_counter()

    def on_sweep(done: int, total: int | None) -> None:
        nonlocal bar
        if bar is None:
            bar = _progress(total, "processing",
                            lambda d: f"{(d or 0) / max(time.perf_counter() - started, 1e-9):.0f} sweeps/s")
            bar.__enter__()
        bar.update(1, current_item=done)

    try:
        summary = api.process(log, out_dir, opts, force=force, on_sweep=on_sweep)
    finally:
        if bar is not None:
            bar.__exit__(None, None, None)
    wall = time.perf_counter() - started
    console.info(f"processed {summary.sweeps} sweeps in {wall:.1f} s ({summary.sweeps / wall:.0f} sweeps/s); "
               f"prior: {summary.prior}; Doppler: {'on' if summary.doppler else 'off'}")
    for m, ms in summary.ms_median.items():
        console.info(f"  {m:9s} median {ms:.2f} ms per sweep")
    for w in summary.warnings:
        console.warning(w)
    console.info(f"wrote {summary.out_dir}/")


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
"""


@cli.command("report", help=_REPORT_HELP)
@click.argument("out_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--log", "log", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="The log the folder was processed from (default: the one run.json names).")
@click.option("-o", "--output", "comparison_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Where comparison.md/.json go when several folders are given.  [default: .]")
@click.option("--relations", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="A Freiburg relations file (t1 t2 x y z roll pitch yaw): the Kuemmerle et al. 2009 metric, "
                   "beside the published figures for that dataset.")
def report_cmd(out_dirs, log, comparison_dir, relations=None):
    from .evaluation.pages import comparison_rows, terminal_table

    if log is not None and len(out_dirs) > 1:
        raise UserError("--log goes with a single output folder")
    results = [_report(out_dir, log, relations) for out_dir in out_dirs]
    if len(results) > 1:
        header, rows = comparison_rows(results)
        console.info("\n" + terminal_table(header, rows))
        written = api.compare(results, comparison_dir or Path("."))
        console.info(f"wrote {written} and comparison.json")


def _report(out_dir: Path, log: Path | None, relations: Path | None) -> dict:
    from .evaluation.pages import (
        RELATIONS_HEADER,
        TRAJECTORY_HEADER,
        relations_rows,
        terminal_table,
        trajectory_rows,
    )

    ev = api.report(out_dir, log, relations)
    console.info(f"{out_dir}: {ev.result['sweeps']} sweeps of {ev.log.name}")
    console.info(terminal_table(TRAJECTORY_HEADER[:8], [r[:8] for r in trajectory_rows(ev.result)]))
    if relations_rows(ev.result):
        console.info(terminal_table(RELATIONS_HEADER, relations_rows(ev.result)))
    red = ev.result["feature_avg_rel_error_reduction_pct"]
    if red is not None:
        console.info(f"average feature error reduced by {red:.1f} % (the paper: {PAPER_FEATURE_ERROR_REDUCTION_PCT} %)")
    console.info(f"wrote {ev.out_dir / 'report.html'} (and report.md, report.json)")
    return ev.result


@cli.command("run")
@click.option("-o", "--output", "out_dir", type=click.Path(file_okay=False, path_type=Path), default=Path("fmcwlog-run"),
              show_default=True, help="Folder for the log, the results and the report.")
@click.option("--scenario", type=click.Choice(sorted(SCENARIOS)), default=DEFAULT_SCENARIO, show_default=True)
@click.option("--duration", type=float, default=120.0, show_default=True, help="Seconds to simulate.")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--force", is_flag=True, help="Replace an existing output folder.")
def run_cmd(out_dir, scenario, duration, seed, force):
    """Record a built-in scenario, process it with both front ends and report, into one folder:
    OUT/log.mcap, OUT/results/ (trajectories, maps, processed.mcap) and OUT/results/report.html."""
    import shutil

    if out_dir.exists() and any(out_dir.iterdir()):
        if not force:
            raise UserError(f"{out_dir}: exists and is not empty; use --force to replace it")
        shutil.rmtree(out_dir)
    log = out_dir / "log.mcap"
    cfg = apply_overrides(SimConfig(), {"run": {"duration": duration, "seed": seed}}).validate()
    _record(api.scenario(scenario), cfg, log)
    _process(log, out_dir / "results", api.ProcessOptions(), force=False)
    _report(out_dir / "results", None, None)
    console.info(f"\nopen {(out_dir / 'results' / 'report.html').resolve()} in a browser")


@cli.group("import")
def import_group() -> None:
    """Convert real robot logs into fmcwlog logs (LaserScan on /scan, Odometry on /odom)."""


@import_group.command("carmen")
@click.argument("source", type=click.Path(dir_okay=False, path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True, help="Log to write (.mcap).")
@click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists.")
def import_carmen_cmd(source, output, force):
    """Convert a CARMEN log (plain, .xz or .gz) into an MCAP log.

    \b
    Reads FLASER, RLASER (-> /rear_scan), ROBOTLASER1, ODOM and PARAM lines (the laser
    offset and field of view come from PARAM robot_frontlaser_offset / robot_front_laser_fov),
    and the CMU Wean Hall course format (O and L lines, centimetres), recognised by its first
    line. Stamps are the log's own ipc_timestamps, which benchmark relations refer to. Without
    ODOM lines, the odometry pose of each laser line becomes /odom. Malformed lines are
    skipped, counted and listed with their line numbers. Then: fmcwlog process OUTPUT -o DIR.
    """
    if not source.is_file():
        raise UserError(f"{source}: no such file")
    if output.exists() and not force:
        raise UserError(f"{output}: exists; use --force to overwrite it")
    try:
        summary, fmt = api.import_carmen(source, output)
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise UserError(f"{source}: cannot read ({exc})") from None
    console.info(f"wrote {output}: {summary.scans} scans, {summary.odometry} odometry poses (from "
               f"{summary.odometry_source}) over {summary.span_s:.1f} s; format {fmt}")
    if summary.bad_lines:
        shown = ", ".join(str(n) for n, _ in summary.bad_lines[:10])
        more = f" and {len(summary.bad_lines) - 10} more" if len(summary.bad_lines) > 10 else ""
        console.warning(f"skipped {len(summary.bad_lines)} malformed lines: {shown}{more} "
                   f"(first: line {summary.bad_lines[0][0]}: {summary.bad_lines[0][1]})")


def main() -> None:
    try:
        cli.main(standalone_mode=False, prog_name="fmcwlog")
    except click.exceptions.NoArgsIsHelpError as exc:  # bare 'fmcwlog' (or a bare group): its help, no error
        click.echo(exc.ctx.get_help() if exc.ctx else exc.format_message())
        sys.exit(0)
    except click.exceptions.Abort:
        click.echo("fmcwlog: aborted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        click.echo(f"fmcwlog: error: {exc.format_message()}", err=True)
        sys.exit(2 if isinstance(exc, (click.UsageError, UserError)) else exc.exit_code)
    except FmcwlogError as exc:  # bad input or parameters: the message names the file or parameter
        click.echo(f"fmcwlog: error: {exc}", err=True)
        sys.exit(2)
    except OSError as exc:  # a file system refusal no command caught: still one line
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(f"fmcwlog: error: {where}{exc.strerror or exc}", err=True)
        sys.exit(2)


if __name__ == "__main__":
    main()
