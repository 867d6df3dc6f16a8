"""``--force`` replaces only what fmcwlog made: never a folder holding anything else, never an input.

Each refusal is checked the way a user would find out: the command's exit status and its one
line, then every file of theirs still there with the same bytes.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from helpers import SAMPLE_LOGS, assert_one_line_error, copy_log, record_scenario, run_cli_here

from fmcwlog.io.atomic import MARKER

pytestmark = pytest.mark.slow  # end to end: the command line on logs


def _short_log(path: Path, sweeps: int = 10) -> Path:
    def edit(topic, i, msg):
        return False if i >= (sweeps if topic == "/fmcw/points" else 5 * sweeps) else None

    path.parent.mkdir(parents=True, exist_ok=True)
    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", path, edit=edit)
    return path


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    return _short_log(tmp_path_factory.mktemp("force") / "s.mcap")


def test_process_refuses_a_folder_that_holds_its_input_log(tmp_path, log):
    work = tmp_path / "DIR"
    work.mkdir()
    inside = work / "log.mcap"
    shutil.copy(log, inside)
    (work / "notes.txt").write_text("mine")
    before = _snapshot(work)
    for force in ([], ["--force"]):
        code, _, err = run_cli_here("process", str(inside), "-o", str(work), *force)
        assert_one_line_error(code, err, str(work), "an input")
        assert _snapshot(work) == before
    nested = work / "sub" / "log.mcap"  # the log deeper inside the folder: the same
    nested.parent.mkdir()
    shutil.copy(log, nested)
    code, _, err = run_cli_here("process", str(nested), "-o", str(work), "--force")
    assert_one_line_error(code, err, "an input")
    assert (work / "log.mcap").read_bytes() == log.read_bytes()


def test_process_refuses_the_input_even_in_a_folder_fmcwlog_made(tmp_path, log):
    out = tmp_path / "out"
    code, _, err = run_cli_here("-q", "process", str(log), "-o", str(out))
    assert code == 0, err
    moved = out / "s.mcap"
    shutil.copy(log, moved)
    code, _, err = run_cli_here("process", str(moved), "-o", str(out), "--force")
    assert_one_line_error(code, err, "an input")
    assert moved.read_bytes() == log.read_bytes()


def test_process_dot_force_in_a_folder_of_other_work_removes_nothing(tmp_path, log, monkeypatch):
    work = tmp_path / "work"
    (work / "thesis").mkdir(parents=True)
    (work / "thesis" / "chapter1.tex").write_text("\\chapter{One}")
    (work / "data.csv").write_text("1,2,3\n")
    before = _snapshot(work)
    monkeypatch.chdir(work)
    code, _, err = run_cli_here("process", str(log), "-o", ".", "--force")
    assert_one_line_error(code, err)
    assert _snapshot(work) == before and sorted(p.name for p in work.iterdir()) == ["data.csv", "thesis"]


def test_force_replaces_a_folder_fmcwlog_made_and_nothing_else(tmp_path, log):
    out = tmp_path / "out"
    code, _, err = run_cli_here("-q", "process", str(log), "-o", str(out))
    assert code == 0, err
    marker = json.loads((out / MARKER).read_text())
    assert set(marker["entries"]) == {p.name for p in out.iterdir()} - {MARKER}
    code, _, err = run_cli_here("-q", "report", str(out))  # the report's files join the marker's list
    assert code == 0, err
    assert {"report.html", "report.json", "report.md", "gt.tum"} <= set(json.loads((out / MARKER).read_text())["entries"])

    code, _, err = run_cli_here("process", str(log), "-o", str(out))
    assert_one_line_error(code, err, "--force")  # without --force: refused
    code, _, err = run_cli_here("-q", "process", str(log), "-o", str(out), "--force")
    assert code == 0, err
    assert not (out / "report.html").exists() and (out / "improved.tum").is_file()  # replaced as a whole
    assert not list(tmp_path.glob(".out.*"))  # the old folder set aside is gone too

    (out / "my_analysis.ipynb").write_text("{}")
    before = _snapshot(out)
    code, _, err = run_cli_here("process", str(log), "-o", str(out), "--force")
    assert_one_line_error(code, err, "my_analysis.ipynb", "did not write")
    assert _snapshot(out) == before


def test_force_refuses_a_folder_whose_marker_is_forged_or_broken(tmp_path, log):
    out = tmp_path / "out"
    out.mkdir()
    (out / "precious.dat").write_bytes(b"\x00\x01")
    for text in ("not json", json.dumps({"entries": ["precious.dat"]}), json.dumps([1, 2])):
        (out / MARKER).write_text(text)  # no fmcwlog_version, or not a marker at all
        code, _, err = run_cli_here("process", str(log), "-o", str(out), "--force")
        assert_one_line_error(code, err, "not made by fmcwlog")
        assert (out / "precious.dat").read_bytes() == b"\x00\x01"


def test_process_into_a_file_or_a_link_is_refused(tmp_path, log):
    f = tmp_path / "out.txt"
    f.write_text("mine")
    code, _, err = run_cli_here("process", str(log), "-o", str(f), "--force")
    assert_one_line_error(code, err, "is a file")  # click's own check of the option
    assert f.read_text() == "mine"
    link = tmp_path / "link"
    link.symlink_to(log.parent, target_is_directory=True)  # the folder the log is in, under another name
    code, _, err = run_cli_here("process", str(log), "-o", str(link), "--force")
    assert_one_line_error(code, err)
    assert log.is_file() and link.is_symlink()


def test_run_force_refuses_a_folder_it_did_not_make_and_replaces_one_it_did(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "log.mcap").write_bytes(b"my own recording")
    code, _, err = run_cli_here("run", "-o", str(mine), "--force", "--duration", "1")
    assert_one_line_error(code, err, "not made by fmcwlog")
    assert _snapshot(mine) == {"log.mcap": b"my own recording"}

    out = tmp_path / "run"
    code, _, err = run_cli_here("-q", "run", "-o", str(out), "--duration", "1")
    assert code == 0, err
    assert set(json.loads((out / MARKER).read_text())["entries"]) == {"log.mcap", "results"}
    (out / "results" / "plot.svg").write_text("<svg/>")  # the user's file inside the results
    code, _, err = run_cli_here("run", "-o", str(out), "--force", "--duration", "1")
    assert_one_line_error(code, err, "results")
    assert (out / "results" / "plot.svg").read_text() == "<svg/>"
    (out / "results" / "plot.svg").unlink()
    first = (out / "log.mcap").read_bytes()
    code, _, err = run_cli_here("-q", "run", "-o", str(out), "--force", "--duration", "1", "--seed", "1")
    assert code == 0, err
    assert (out / "log.mcap").read_bytes() != first and (out / "results" / "report.html").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine", "run"]  # nothing set aside is left


@pytest.mark.parametrize("which", ["world", "config"])
def test_record_force_overwrites_an_output_file_but_never_its_input(tmp_path, which):
    world = tmp_path / "w.yaml"
    world.write_text("walls: [[0, 0, 10, 0], [10, 0, 10, 5], [10, 5, 0, 5], [0, 5, 0, 0]]\n"
                     "route: {waypoints: [[1, 1], [9, 1], [9, 4]], loop: false}\n")
    config = tmp_path / "c.toml"
    config.write_text("[run]\nduration = 0.5\n")
    before = _snapshot(tmp_path)
    target = world if which == "world" else config
    code, _, err = run_cli_here("record", "--world", str(world), "--config", str(config), "-o", str(target), "--force")
    assert_one_line_error(code, err, str(target), "input")
    assert _snapshot(tmp_path) == before
    other = tmp_path / "old.mcap"
    other.write_text("an old output")
    code, _, err = run_cli_here("-q", "record", "--world", str(world), "--config", str(config), "-o", str(other),
                                "--force")
    assert code == 0, err
    assert other.read_bytes()[:5] == b"\x89MCAP"


def test_import_force_never_overwrites_its_source(tmp_path):
    src = tmp_path / "log.clf"
    ranges = " ".join(["2.0"] * 180)
    src.write_text(f"ODOM 1.0 2.0 0.5 0.1 0 0 100.5 host 100.5\nFLASER 180 {ranges} 1.0 2.0 0.5 1.0 2.0 0.5 100.6 h 100.6\n")
    text = src.read_text()
    for force in ([], ["--force"]):
        code, _, err = run_cli_here("import", "carmen", str(src), "-o", str(src), *force)
        assert_one_line_error(code, err, "input")
        assert src.read_text() == text
    link = tmp_path / "alias.mcap"
    link.symlink_to(src)
    code, _, err = run_cli_here("import", "carmen", str(src), "-o", str(link), "--force")
    assert_one_line_error(code, err, "input")
    assert src.read_text() == text


def test_calibrate_force_never_overwrites_its_inputs(tmp_path, log):
    """``calibrate LOG -o LOG --force`` once replaced the log with a 1 kB YAML file; nor may it overwrite
    the calibration file or the parameter file it reads, under any of their names."""
    work = tmp_path / "w"
    work.mkdir()
    src = work / "s.mcap"
    shutil.copyfile(log, src)
    cal = work / "cal.yaml"
    cal.write_text("lidar_x: 0.35\n")
    cfg = work / "p.toml"
    cfg.write_text("")
    (work / "alias.mcap").symlink_to(src)
    before = _snapshot(work)
    for target in (src, work / "alias.mcap", cal, cfg):
        code, _, err = run_cli_here("calibrate", str(src), "-o", str(target), "--calibration", str(cal),
                                    "--config", str(cfg), "--force")
        assert_one_line_error(code, err, str(target), "input")
        assert _snapshot(work) == before


def test_sigterm_mid_process_leaves_the_earlier_output_and_no_temporary(tmp_path_factory, tmp_path, log):
    """``kill`` (or ``timeout``, a job scheduler) mid-run: as Ctrl-C, exit status 143 with one line, the
    earlier output as it was and no ``.out.partial-PID`` folder. Python's default SIGTERM once ended the
    process on the spot, leaving the temporary folder behind."""
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    code, _, err = run_cli_here("-q", "process", str(log), "-o", str(out), "--jobs", "1")
    assert code == 0, err
    before = _snapshot(out)
    long_log = record_scenario(tmp_path_factory, "corridor", 120.0)  # seconds of processing, not one
    proc = subprocess.Popen([sys.executable, "-m", "fmcwlog", "process", str(long_log),
                             "-o", str(out), "--force"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while not list(tmp_path.glob(".out.partial-*")) and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)  # into the sweeps (1,200 of them: a few seconds)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, stderr
    assert [x for x in stderr.splitlines() if x.strip()] == ["fmcwlog: terminated"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert _snapshot(out) == before


@pytest.mark.parametrize("command", ["record", "calibrate", "import"])
def test_force_never_replaces_a_pipe_or_a_device(tmp_path, log, command):
    """``-o /dev/null --force`` renamed a regular file over the device node (as root: the system's
    /dev/null gone); a pipe stands in for it here (mkfifo needs no privileges)."""
    import os
    import stat

    target = tmp_path / "pipe"
    os.mkfifo(target)
    clf = tmp_path / "l.clf"
    clf.write_text(f"FLASER 180 {' '.join(['2.0'] * 180)} 1.0 2.0 0.5 1.0 2.0 0.5 100.6 h 100.6\n")
    args = {"record": ["record", "--duration", "0.5"], "calibrate": ["calibrate", str(log)],
            "import": ["import", "carmen", str(clf)]}[command]
    code, _, err = run_cli_here(*args, "-o", str(target), "--force")
    assert_one_line_error(code, err, str(target), "not a regular file")
    assert stat.S_ISFIFO(target.lstat().st_mode)


def test_a_read_only_file_system_is_named_on_the_output_not_its_temporary(tmp_path, monkeypatch):
    """On a read-only file system even removing a file that is not there fails (EROFS before the
    lookup); the clean-up once raised that, and the line named '.run1.partial-PID' instead of run1.
    Simulated as the kernel does: under tmp_path, a new folder or any unlink refused with EROFS."""
    import errno
    import os

    real_mkdir, real_unlink = Path.mkdir, Path.unlink

    def refuse(real):
        def call(self, *args, **kwargs):
            if str(self).startswith(str(tmp_path)) and not (real is real_mkdir and self.exists()):
                raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
            return real(self, *args, **kwargs)
        return call

    monkeypatch.setattr(Path, "mkdir", refuse(real_mkdir))
    monkeypatch.setattr(Path, "unlink", refuse(real_unlink))
    code, _, err = run_cli_here("run", "--duration", "1", "-o", str(tmp_path / "run1"))
    line = assert_one_line_error(code, err, str(tmp_path / "run1"), "read-only file system")
    assert ".partial-" not in line


def test_an_interrupt_swallowed_where_it_landed_is_delivered_again():
    """A signal handler's exception raised inside a callback Python cannot raise from (an import
    lock's, a weakref's) is 'ignored', and SIGTERM mid-import once let a --force run finish and
    replace the output (exit 0). The CLI's hook sends the signal again once the callback is left."""
    import textwrap

    from helpers import run_python

    assert run_python(textwrap.dedent("""
        import time, weakref
        from fmcwlog.cli import interrupts
        class X: pass
        try:
            with interrupts.sigterm_as_interrupt():
                x = X()
                ref = weakref.ref(x, lambda r: interrupts.terminate(15, None))  # the handler, run in the callback
                del x
                t = time.time()
                while time.time() - t < 30:
                    pass
            print('went on')
        except interrupts.Terminated:
            print('terminated')
    """)) == (0, "terminated\n", "")
