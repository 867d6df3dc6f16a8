"""``fmcwlog run`` ends, as ``process`` does, on the share of sweeps skipped where more than 5 %
(``process`` itself: tests/integration/test_scanner_shapes.py)."""

from __future__ import annotations

import contextlib
import io
import sys

from fmcwlog import cli
from fmcwlog.cli import run as run_module

LINE = "6 of 60 sweeps on /fmcw/points skipped (10.0 %, more than 5 %: the results stand on the 54 left); ..."


def _output(*args: str) -> tuple[int, list[str]]:
    """``fmcwlog ARGS`` here: its exit status and its lines, stdout and stderr in one stream, in order."""
    both = io.StringIO()
    argv, sys.argv = sys.argv, ["fmcwlog", *args]
    code = 0
    try:
        with contextlib.redirect_stdout(both), contextlib.redirect_stderr(both):
            cli.main()
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    finally:
        sys.argv = argv
    return code, [line for line in both.getvalue().splitlines() if line.strip()]


def test_run_ends_on_the_share_of_sweeps_skipped(monkeypatch, tmp_path):
    """Recording, processing and reporting stood in for: what run prints after them, and in what order."""
    monkeypatch.setattr(run_module, "record_log", lambda world, cfg, log: log.write_bytes(b""))
    monkeypatch.setattr(run_module, "process_log", lambda log, out, opts, force: LINE)
    monkeypatch.setattr(run_module, "report_folder", lambda *args: None)
    code, lines = _output("run", "-o", str(tmp_path / "run"), "--duration", "1")
    assert code == 0 and lines[-2].startswith("open ") and lines[-1] == f"fmcwlog: warning: {LINE}", lines
    monkeypatch.setattr(run_module, "process_log", lambda log, out, opts, force: None)
    code, lines = _output("run", "-o", str(tmp_path / "run"), "--duration", "1", "--force")
    assert code == 0 and lines[-1].startswith("open "), lines
