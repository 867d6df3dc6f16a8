"""``fmcwlog run``: record, process and report a built-in scenario into one folder."""

from __future__ import annotations

import click

from ..io.atomic import replacing_folder
from ..sim.config import simulation_config
from ..sim.scenarios import DEFAULT_SCENARIO, SCENARIOS
from ..sim.scenarios import scenario as builtin_world
from .console import console
from .paths import as_path
from .process import process_log
from .record import record_log
from .report import report_folder


@click.command("run")
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
    from ..pipeline.options import ProcessOptions  # here: --help needs none of the estimation stack

    cfg = simulation_config(duration=duration, seed=seed)
    with replacing_folder(out_dir, force, "fmcwlog run") as folder:
        log = folder / "log.mcap"
        record_log(builtin_world(scenario), cfg, log)
        many_skipped = process_log(log, folder / "results", ProcessOptions(), force=False)
        report_folder(folder / "results", None, None)
    console.info(f"\nopen {(out_dir / 'results' / 'report.html').resolve()} in a browser")
    if many_skipped:
        console.warning(many_skipped)
