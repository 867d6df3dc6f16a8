"""``fmcwlog calibrate``: the LiDAR's mount and the wheels' radii estimated from a log, to a file."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..io.atomic import check_output_file
from .console import console
from .process import TIME_FIELD_OPTION_HELP

if TYPE_CHECKING:
    from ..pipeline.calibrate import CalibrateSummary

_CALIBRATE_HELP = """Estimate the LiDAR's mount (lidar_x, lidar_y, lidar_yaw) and the wheels' effective
radii and track width from LOG itself, and write them as a calibration file that
'fmcwlog process LOG --calibration FILE' takes before the log's record. It starts
from the calibration 'process' would use (the file, the record, the mount from the
log's tf: see 'fmcwlog process --help').

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
the file. Units: metres and radians, the record's keys (docs/log-format.md).
"""


@click.command("calibrate", help=_CALIBRATE_HELP)
@click.argument("log", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=Path), required=True,
              help="Calibration file to write (.yaml).")
@click.option("--calibration", "calibration_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Start from this calibration file: its values go before the log's record and its tf.")
@click.option("--base-frame", default="base_link", show_default=True,
              help="The robot's frame, for a mount read from the log's tf (as for 'process').")
@click.option("--config", "config_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Parameter file (TOML, YAML or JSON), as for 'process'.")
@click.option("--set", "set_items", multiple=True, metavar="SECTION.NAME=VALUE",
              help="Override one parameter; repeatable (e.g. --set self_calibration.min_speed=0.3).")
@click.option("--time-field", metavar="NAME:UNIT", default=None, help=TIME_FIELD_OPTION_HELP)
@click.option("--force", is_flag=True, help="Overwrite OUTPUT if it exists.")
def calibrate_cmd(log, output, calibration_file, base_frame, config_file, set_items, time_field, force):
    check_output_file(output, force, (log, calibration_file, config_file))  # --force never overwrites an input
    from ..pipeline.calibrate import calibrate  # here: --help needs none of the estimation stack
    from ..pipeline.options import ProcessOptions
    from ..pipeline.params import params_from

    params = params_from(config_file, set_items)
    summary = calibrate(log, output, ProcessOptions(methods=("improved",), params=params, calibration=calibration_file,
                                                    base_frame=base_frame, time_field=time_field), force=force)
    _print_estimates(summary)
    for w in summary.warnings:
        console.warning(w)
    console.info(f"wrote {summary.output}")


def _print_estimates(summary: CalibrateSummary) -> None:
    """A line per calibration value: written or kept, the estimate and its sigma, the value it replaces."""
    for name, c in summary.check.values.items():
        flag = "  <- disagrees" if c.disagrees else ""
        what = "written" if name in summary.adopted else "kept   "
        console.info(f"  {name:18s} {what} {c.estimate:+.5f} +- {c.sigma:.5f}   (was {c.calibration:+.5f}){flag}")
    for name, why in summary.check.not_estimated.items():
        console.info(f"  {name:18s} kept: {why}")
