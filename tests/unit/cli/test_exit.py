"""How the ``fmcwlog`` command exits: its objects frozen out of the exit's garbage collections, the
``atexit`` handlers still run, the exit status the command's."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]

PROBE = textwrap.dedent("""
    import atexit, gc, sys
    atexit.register(lambda: print("frozen at exit:", gc.get_freeze_count() > 0))
    sys.argv = ["fmcwlog", *sys.argv[1:]]
    from fmcwlog.__main__ import main
    main()
""")


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", PROBE, *args], capture_output=True, text=True, cwd=REPO)


def test_a_command_that_succeeds_exits_frozen_with_its_handlers_run():
    p = _run("--help")
    assert p.returncode == 0 and "Commands:" in p.stdout, p.stderr
    assert p.stdout.rstrip().endswith("frozen at exit: True")


def test_a_command_that_fails_keeps_its_one_line_and_its_status():
    p = _run("process", "no-such.mcap", "-o", "out")
    assert p.returncode == 2 and p.stderr.startswith("fmcwlog: error: ") and len(p.stderr.splitlines()) == 1, p.stderr
    assert p.stdout.strip() == "frozen at exit: True"


def test_modules_load_without_collections_and_stay_out_of_later_ones():
    code = textwrap.dedent("""
        import gc
        from fmcwlog.cli.loading import loading_modules
        before = gc.get_freeze_count()
        with loading_modules():
            inside = gc.isenabled()
            import fmcwlog.io.mcap_log
        print(inside, gc.isenabled(), gc.get_freeze_count() > before)
        gc.disable()
        with loading_modules():
            pass
        print(gc.isenabled())  # left as it was found
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True)
    assert p.stdout.split() == ["False", "True", "True", "False"]
