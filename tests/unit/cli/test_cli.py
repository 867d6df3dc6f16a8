"""Command-line habits: help without an error, -q and -v, completion that click can produce."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest
from helpers import SAMPLE_LOGS, run_python


def _fmcwlog(*args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, timeout=300,
                          env={**os.environ, **(env or {})})


@pytest.mark.slow
def test_bare_command_prints_its_help_and_succeeds():
    for args in ((), ("import",)):
        p = _fmcwlog(*args)
        assert p.returncode == 0 and "Usage:" in p.stdout and p.stderr == "", args


@pytest.mark.slow
def test_quiet_prints_nothing_and_verbose_says_what_it_found(tmp_path):
    q = _fmcwlog("-q", "process", str(SAMPLE_LOGS / "corridor_30s.mcap"), "-o", str(tmp_path / "q"))
    assert q.returncode == 0 and q.stdout == "" and q.stderr == ""
    assert (tmp_path / "q" / "improved.tum").is_file()
    v = _fmcwlog("-v", "process", str(SAMPLE_LOGS / "corridor_30s.mcap"), "-o", str(tmp_path / "v"))
    assert v.returncode == 0 and "prior /wheel/ticks" in v.stdout and "lidar at x 0.350 m" in v.stdout
    plain = _fmcwlog("process", str(SAMPLE_LOGS / "corridor_30s.mcap"), "-o", str(tmp_path / "p"))
    assert "processed 300 sweeps" in plain.stdout and "lidar at" not in plain.stdout


@pytest.mark.slow
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
        if isinstance(cmd, click.Group):  # list_commands: the group's commands, loaded or not yet
            with click.Context(cmd) as ctx:
                for name in cmd.list_commands(ctx):
                    sub = cmd.get_command(ctx, name)
                    assert sub is not None, f"{path} lists {name} but has no such command"
                    yield from commands(sub, f"{path} {name}")

    bare = [f"{path} {'/'.join(p.opts)}" for path, cmd in commands(cli, "fmcwlog") for p in cmd.params
            if isinstance(p, click.Option) and not (p.help or "").strip()]
    assert not bare, f"options with no help text: {bare}"
    assert all((cmd.help or "").strip() for _, cmd in commands(cli, "fmcwlog")), "a command with no help"


@pytest.mark.slow
def test_a_bad_value_in_a_config_file_names_the_file(tmp_path):
    """An unknown key or a value out of range in --config FILE: one line naming FILE, the key and why,
    exit 2, nothing written. A --set value is named by the option itself, so it is left without a file."""
    bad = {"rec.toml": "[sensor]\nrange_sigma = -1\n", "rec2.toml": "[sensor]\nrange_sigmaa = 0.1\n",
           "p.toml": "[segmentation]\nv_th = -1\n", "p2.yaml": "segmentation:\n  vth: 0.2\n"}
    for name, text in bad.items():
        (tmp_path / name).write_text(text)
    log = str(SAMPLE_LOGS / "corridor_30s.mcap")
    runs = {"rec.toml": ("record", "-o", str(tmp_path / "r.mcap")), "rec2.toml": ("record", "-o", str(tmp_path / "r.mcap")),
            "p.toml": ("process", log, "-o", str(tmp_path / "o")), "p2.yaml": ("calibrate", log, "-o", str(tmp_path / "c.yaml"))}
    key = {"rec.toml": "sensor.range_sigma", "rec2.toml": "sensor.range_sigmaa", "p.toml": "segmentation.v_th",
           "p2.yaml": "segmentation.vth"}
    for name, args in runs.items():
        p = _fmcwlog(*args, "--config", str(tmp_path / name))
        assert p.returncode == 2 and p.stdout == "", p.stderr
        assert p.stderr.startswith(f"fmcwlog: error: {tmp_path / name}: ") and key[name] in p.stderr, p.stderr
        assert len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert sorted(f.name for f in tmp_path.iterdir()) == sorted(bad)  # nothing written
    p = _fmcwlog("process", log, "-o", str(tmp_path / "o"), "--set", "segmentation.v_th=-1")
    assert p.returncode == 2 and p.stderr.startswith("fmcwlog: error: segmentation.v_th = -1 is out of range")


def test_ctrl_c_while_the_command_loads_is_one_line():
    """Ctrl-C in the first second, while the CLI's modules load, once ended in an import's traceback.
    The interrupt is raised where it would land: in the import of fmcwlog.cli."""
    code, out, err = run_python(textwrap.dedent("""
        import builtins, sys
        real = builtins.__import__
        def interrupting(name, globals=None, locals=None, fromlist=(), level=0):
            if name.endswith('cli') and (globals or {}).get('__name__', '').startswith('fmcwlog'):
                raise KeyboardInterrupt
            return real(name, globals, locals, fromlist, level)
        builtins.__import__ = interrupting
        sys.argv = ['fmcwlog', '--help']
        from fmcwlog.__main__ import main
        main()
    """))
    assert (code, err, out) == (130, "fmcwlog: aborted\n", "")
