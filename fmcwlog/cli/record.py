"""``fmcwlog record``: simulate a robot among movers and write the log, or print its parameters."""

from __future__ import annotations

from pathlib import Path

import click

from ..io.atomic import check_output_file
from ..sim.config import SimConfig, simulation_config
from ..sim.recorder import record
from ..sim.scenarios import DEFAULT_SCENARIO, SCENARIOS
from ..sim.scenarios import scenario as builtin_world
from ..sim.world import load_world
from .console import console, echo_out
from .exits import UserError
from .paths import as_path
from .progress import progress

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
  warehouse      60 x 30 m, six shelf rows 50 m long, forklifts in the aisles; a 343 m open
                 route through six aisles (120 s at --speed 3), no loop to close
Or --world FILE: your own walls, features, movers and route (YAML/JSON; docs/commands/record.md).

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


@click.command("record", help=_RECORD_HELP)
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
    world = load_world(world_file) if world_file else builtin_world(scenario or DEFAULT_SCENARIO)
    if show_config:
        echo_out(cfg.toml(), nl=False)
        return
    if output is None:
        raise UserError("missing -o/--output: the log file to write")
    check_output_file(output, force, (world_file, config_file))
    record_log(world, cfg, output)


def record_log(world, cfg: SimConfig, output: Path) -> None:
    """``world`` recorded into ``output`` (``record`` and ``run``): a progress bar, then what was written."""
    n = int(cfg.run.duration * cfg.sensor.scan_rate + 1e-9)
    with progress(n, f"recording {world.name}") as bar:
        last = [0]

        def step(done: int) -> None:
            bar.update(done - last[0])
            last[0] = done

        summary = record(world, cfg, output, on_progress=step)
    note = " (stopped early by Ctrl-C)" if summary.interrupted else ""
    console.info(
        f"wrote {summary.path}: {summary.seconds:.1f} s, {summary.sweeps} sweeps, "
        f"{summary.moving_fraction:.1%} of points on movers{note}"
    )
