"""``fmcwlog import carmen``: CARMEN (and CMU course format) laser logs into MCAP logs, one or many."""

from __future__ import annotations

from pathlib import Path

import click

from ..fleet.imports import import_carmen_many
from ..io.atomic import check_output_file
from ..io.carmen_import import import_carmen
from .console import console
from .exits import SomeFailed, UserError
from .paths import as_path, as_paths


@click.group("import")
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
    else:
        _import_one(sources[0], output, force)


def _import_one(source: Path, output: Path, force: bool) -> None:
    """One file into one log: its counts, and the malformed lines skipped (the first ten's numbers)."""
    if not source.is_file():
        raise UserError(f"{source}: {'no such file' if not source.exists() else 'not a regular file (a pipe or a device)'}")
    check_output_file(output, force, (source,))
    summary, fmt = import_carmen(source, output)
    console.info(f"wrote {output}: {summary.scans} scans, {summary.odometry} odometry poses (from "
                 f"{summary.odometry_source}) over {summary.span_s:.1f} s; format {fmt}")
    if summary.bad_lines:
        shown = ", ".join(str(n) for n, _ in summary.bad_lines[:10])
        more = f" and {len(summary.bad_lines) - 10} more" if len(summary.bad_lines) > 10 else ""
        console.warning(f"skipped {len(summary.bad_lines)} malformed lines: {shown}{more} "
                        f"(first: line {summary.bad_lines[0][0]}: {summary.bad_lines[0][1]})")


def _import_many(sources: list[Path], out_dir: Path, force: bool) -> None:
    """Many files (or folders of them) into a folder of logs, a line each; some failed: exit status 1."""
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"{out_dir}: exists and is not a folder (several sources go into a folder)")
    outcomes = import_carmen_many(sources, out_dir, force=force)
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
