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

import importlib

import click

from .. import __version__
from .console import configure_logging
from .exits import run_command_line

# Each command's module, its click object, and the first paragraph of its help (the group's
# --help lists it without loading the module; tests/unit/cli/test_cli.py checks that they agree).
COMMANDS: dict[str, tuple[str, str, str]] = {
    "record": ("record", "record_cmd", "Simulate a car-like robot with an FMCW LiDAR among moving people and carts, "
                                       "and write the log (MCAP, ROS 2 CDR) with ground truth."),
    "process": ("process", "process_cmd", "Estimate the robot's trajectory and map from LOG with the paper's improved "
                                          "front end and the classic ICP baseline, side by side, and write them to "
                                          "OUT_DIR."),
    "report": ("report", "report_cmd", "Measure what 'fmcwlog process' wrote in OUT_DIR against the ground truth of "
                                       "the log it came from (found through run.json, or --log), and write into "
                                       "OUT_DIR:"),
    "compare": ("compare", "compare_cmd", "Compare several runs of 'fmcwlog process' (their output folders), as one "
                                          "tunes a front end: each is measured as 'fmcwlog report' measures it, and "
                                          "OUTPUT gets"),
    "run": ("run", "run_cmd", "Record a built-in scenario, process it with both front ends and report, into one "
                              "folder: OUT/log.mcap, OUT/results/ (trajectories, maps, processed.mcap) and "
                              "OUT/results/report.html. If any step fails, OUT is removed again (and what was there "
                              "before put back)."),
    "import": ("import_carmen", "import_group", "Convert real robot logs into fmcwlog logs (LaserScan on /scan, "
                                                "Odometry on /odom)."),
    "calibrate": ("calibrate", "calibrate_cmd", "Estimate the LiDAR's mount (lidar_x, lidar_y, lidar_yaw) and the "
                                                "wheels' effective radii and track width from LOG itself, and write "
                                                "them as a calibration file that 'fmcwlog process LOG --calibration "
                                                "FILE' takes before the log's record. It starts from the calibration "
                                                "'process' would use (the file, the record, the mount from the log's "
                                                "tf: see 'fmcwlog process --help')."),
}


class LazyGroup(click.Group):
    """A group whose commands' modules load when a command is asked for, not with the group:
    ``fmcwlog --help`` loads none of them, ``fmcwlog process`` only ``process``'s (a command's
    module imports only what its options need; its body, the rest)."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(self.commands) | set(COMMANDS))

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        if cmd_name not in self.commands and cmd_name in COMMANDS:
            module, attribute, _ = COMMANDS[cmd_name]
            self.add_command(getattr(importlib.import_module(f"{__name__}.{module}"), attribute), cmd_name)
        return self.commands.get(cmd_name)

    def resolve_command(self, ctx: click.Context, args: list[str]) -> tuple[str | None, click.Command | None, list[str]]:
        try:
            return super().resolve_command(ctx, args)
        except click.exceptions.NoSuchCommand:  # click's "Did you mean" looks at the loaded ones only
            raise click.exceptions.NoSuchCommand(str(args[0]), possibilities=self.list_commands(ctx), ctx=ctx) from None

    def format_commands(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        """click's own listing, a command not loaded yet standing in as the first paragraph of its help."""
        commands = [(name, self.commands.get(name) or click.Command(name, help=COMMANDS[name][2]))
                    for name in self.list_commands(ctx)]
        commands = [(name, cmd) for name, cmd in commands if not cmd.hidden]
        if commands:
            limit = formatter.width - 6 - max(len(name) for name, _ in commands)  # click's
            with formatter.section("Commands"):
                formatter.write_dl([(name, cmd.get_short_help_str(limit)) for name, cmd in commands])


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="fmcwlog")
@click.option("-q", "--quiet", is_flag=True, help="Print only warnings and errors (no progress, no tables).")
@click.option("-v", "--verbose", count=True, help="Also print what each step found (topics, calibration, counts).")
def cli(quiet: bool, verbose: int) -> None:
    """Record, process and evaluate FMCW LiDAR robot logs (MCAP, ROS 2 messages).

    \b
    fmcwlog record   simulate a robot with an FMCW LiDAR and wheel encoders -> log.mcap
    fmcwlog process  estimate trajectories and maps from a log, improved and baseline
    fmcwlog report   measure them against ground truth: a page, Markdown and JSON
    fmcwlog compare  several runs side by side: what differs, which is better, beyond the spread
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


def main() -> None:
    """The ``fmcwlog`` command: ``fmcwlog.__main__`` runs this once the modules are loaded."""
    run_command_line(cli)
