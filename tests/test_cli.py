"""Command-line habits: help without an error, -q and -v, completion that click can produce."""

from __future__ import annotations

import os
import subprocess
import sys

from conftest import SAMPLE_LOGS


def _fmcwlog(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **(env or {})})


def test_bare_command_prints_its_help_and_succeeds():
    for args in ((), ("import",)):
        p = _fmcwlog(*args)
        assert p.returncode == 0 and "Usage:" in p.stdout and p.stderr == "", args


def test_quiet_prints_nothing_and_verbose_says_what_it_found(tmp_path):
    q = _fmcwlog("-q", "process", str(SAMPLE_LOGS / "corridor_30s.mcap"), "-o", str(tmp_path / "q"))
    assert q.returncode == 0 and q.stdout == "" and q.stderr == ""
    assert (tmp_path / "q" / "improved.tum").is_file()
    v = _fmcwlog("-v", "process", str(SAMPLE_LOGS / "corridor_30s.mcap"), "-o", str(tmp_path / "v"))
    assert v.returncode == 0 and "prior /wheel/ticks" in v.stdout and "lidar at x 0.350 m" in v.stdout
    plain = _fmcwlog("process", str(SAMPLE_LOGS / "corridor_30s.mcap"), "-o", str(tmp_path / "p"))
    assert "processed 300 sweeps" in plain.stdout and "lidar at" not in plain.stdout


def test_shell_completion_script_is_generated():
    p = _fmcwlog(env={"_FMCWLOG_COMPLETE": "bash_source"})
    # 'python -m fmcwlog' is not the 'fmcwlog' script click expects, so ask the installed one if present
    script = subprocess.run(["fmcwlog"], capture_output=True, text=True, env={**os.environ, "_FMCWLOG_COMPLETE": "bash_source"}) \
        if _which("fmcwlog") else p
    assert script.returncode == 0 and "complete" in script.stdout and "_FMCWLOG_COMPLETE" in script.stdout


def _which(name: str) -> bool:
    from shutil import which

    return which(name) is not None


def test_every_option_of_every_command_says_what_it_is():
    """--help teaches: an option listed with no text beside it (run's --scenario and --seed were) says
    nothing of its unit or meaning. Walked over click's own command tree, so a new command is covered."""
    import click

    from fmcwlog.cli import cli

    def commands(cmd: click.Command, path: str):
        yield path, cmd
        if isinstance(cmd, click.Group):
            for name, sub in cmd.commands.items():
                yield from commands(sub, f"{path} {name}")

    bare = [f"{path} {'/'.join(p.opts)}" for path, cmd in commands(cli, "fmcwlog") for p in cmd.params
            if isinstance(p, click.Option) and not (p.help or "").strip()]
    assert not bare, f"options with no help text: {bare}"
    assert all((cmd.help or "").strip() for _, cmd in commands(cli, "fmcwlog")), "a command with no help"
