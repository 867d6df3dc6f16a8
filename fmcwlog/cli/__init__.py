"""The ``fmcwlog`` command line: the group, its commands, and :func:`main`.

Each command, in a module of its own, parses options, calls the library (the functions
:mod:`fmcwlog.api` gathers), and prints; what they share (printing, progress bars, paths) sits
below them in ``console``, ``progress`` and ``paths``. A command imports the estimation stack
inside its body, where it runs it: ``fmcwlog --help`` and ``fmcwlog record`` load none of it.
How a command ends is :mod:`.exits`: errors a user can fix (bad arguments, bad files: every
:class:`fmcwlog.errors.FmcwlogError`) end in one line on stderr, ``fmcwlog: error: ...``, and
exit status 2; no traceback, no partial output.
"""

from __future__ import annotations

import click

from .. import __version__
from .calibrate import calibrate_cmd
from .console import configure_logging
from .exits import run_command_line
from .import_carmen import import_group
from .process import process_cmd
from .record import record_cmd
from .report import report_cmd
from .run import run_cmd


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
    Logs are MCAP files of ROS 2 messages (docs/log-format.md); they open in Foxglove.
    process, calibrate and report also read rosbag2 folders and ROS 1 .bag files as recorded.
    Run 'fmcwlog COMMAND --help' for each command's options, defaults and units.

    \b
    Shell completion (bash; zsh_source, fish_source for the others):
      eval "$(_FMCWLOG_COMPLETE=bash_source fmcwlog)"
    """
    configure_logging(quiet, verbose)


cli.add_command(record_cmd)
cli.add_command(process_cmd)
cli.add_command(report_cmd)
cli.add_command(run_cmd)
cli.add_command(import_group)
cli.add_command(calibrate_cmd)


def main() -> None:
    """The ``fmcwlog`` command: ``fmcwlog.__main__`` runs this once the modules are loaded."""
    run_command_line(cli)
