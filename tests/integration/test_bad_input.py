"""Bad input through the command line: each fault is built from a short recording (rewritten with
tests/helpers.py ``copy_log``) and must end in a run that says what it dropped, or one line of
error naming the file and the problem; never a traceback, a half-written output, or a leftover
temporary.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers import assert_one_line_error, copy_log, metadata, ros_laser_log, run_cli, run_cli_here

from fmcwlog.io.calibration import CALIBRATION_KEY

ROOT = Path(__file__).resolve().parents[2]
NOT_UTF8 = os.fsdecode(b"out\xff")  # a name with a byte UTF-8 cannot decode (Python's surrogate escape)


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    """5 s of the corridor (50 sweeps), recorded by the command line."""
    out = tmp_path_factory.mktemp("bad_input") / "base.mcap"
    ran = run_cli("record", "--duration", "5", "-o", str(out))
    assert ran.returncode == 0, ran.stderr
    return out


def _set_field(msg, name: str, change) -> None:
    """Replace the float32 field ``name`` of every point of a PointCloud2 by ``change(values)``."""
    off = {f.name: f.offset for f in msg.fields}[name]
    rows = np.frombuffer(bytes(msg.data), np.uint8).reshape(-1, msg.point_step).copy()
    values = rows[:, off:off + 4].copy().view("<f4").ravel()
    rows[:, off:off + 4] = np.asarray(change(values), "<f4").reshape(-1, 1).view(np.uint8)
    msg.data = rows.tobytes()


def _no_returns(share: float):
    """An edit making ``share`` of each sweep's points no-returns: NaN x, inf y, every other one."""
    def change(values):
        out = values.copy()
        out[: int(share * len(out))] = np.nan
        return out

    def edit(topic, i, msg):
        if topic == "/fmcw/points":
            _set_field(msg, "x", change)
            _set_field(msg, "y", lambda v: np.where(np.arange(len(v)) % 97 == 1, np.inf, v))
    return edit


def _run_bytes(*args: str) -> tuple[int, str]:
    """``fmcwlog ARGS`` in a new interpreter: exit status and stderr (stdout may echo a name's raw bytes)."""
    ran = subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, timeout=600)
    return ran.returncode, ran.stderr.decode(errors="replace")


def _process(log: Path, out: Path, *more: str) -> tuple[int, str, str]:
    return run_cli_here("process", str(log), "-o", str(out), "--force", *more)


def test_a_few_nan_points_a_sweep_are_dropped_quietly(log, tmp_path):
    bad = tmp_path / "nan.mcap"
    copy_log(log, bad, edit=_no_returns(0.02))
    code, _, err = _process(bad, tmp_path / "out")
    assert code == 0, err
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run["sweeps"] == 50 and run["skipped_sweeps"] == 0
    assert not any("no-returns" in w for w in run["warnings"])
    assert (tmp_path / "out" / "improved.tum").read_text().count("\n") == 50


@pytest.mark.parametrize("share, loud", [(0.2, False), (0.7, True)])
def test_a_notable_share_of_no_returns_is_said_once(log, tmp_path, share, loud):
    bad = tmp_path / "nan.mcap"
    copy_log(log, bad, edit=_no_returns(share))
    code, _, err = _process(bad, tmp_path / "out")
    assert code == 0, err
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    said = [w for w in run["warnings"] if "no-returns" in w]
    assert len(said) == 1 and said[0].startswith("MOST POINTS ARE NO-RETURNS") == loud, said
    assert f"{round(100 * share)}." in said[0]
    assert sum("no-returns" in line for line in err.splitlines()) == 1
    assert run["sweeps"] == 50


def test_laserscan_nan_inf_and_zero_ranges_are_no_returns(log, tmp_path):
    scan = ros_laser_log(log, tmp_path / "scan.mcap")
    bad = tmp_path / "scan_bad.mcap"

    def edit(topic, i, msg):
        if topic == "/scan":
            r = np.asarray(msg.ranges, float)
            r[::7], r[1::7], r[2::7] = np.nan, np.inf, 0.0
            msg.ranges = r.tolist()
    copy_log(scan, bad, edit=edit)
    code, _, err = _process(bad, tmp_path / "out")
    assert code == 0, err
    assert json.loads((tmp_path / "out" / "run.json").read_text())["skipped_sweeps"] == 0


def test_every_point_at_the_origin_is_one_line_of_error(log, tmp_path):
    bad = tmp_path / "zero.mcap"

    def edit(topic, i, msg):
        if topic == "/fmcw/points":
            _set_field(msg, "x", lambda v: 0 * v)
            _set_field(msg, "y", lambda v: 0 * v)
    copy_log(log, bad, edit=edit)
    code, _, err = _process(bad, tmp_path / "out")
    assert_one_line_error(code, err, str(bad), "no usable sweep", "no-returns")
    assert not (tmp_path / "out").exists()


def test_every_point_within_min_range_is_one_line_of_error(log, tmp_path):
    bad = tmp_path / "near.mcap"

    def edit(topic, i, msg):
        if topic == "/fmcw/points":
            _set_field(msg, "x", lambda v: 0 * v + 0.05)
            _set_field(msg, "y", lambda v: 0 * v)
    copy_log(log, bad, edit=edit)
    code, _, err = _process(bad, tmp_path / "out")
    assert_one_line_error(code, err, str(bad), "could be mapped", "frontend.min_range")
    assert not (tmp_path / "out").exists() and [p.name for p in tmp_path.iterdir()] == ["near.mcap"]


def test_an_all_zero_carmen_log_is_one_line_of_error(tmp_path):
    lines = []
    for i in range(40):
        t = 1000 + 0.1 * i
        lines.append(f"ODOM {0.05 * i} 0 0 0.5 0 0 {t} host {t}")
        lines.append(f"FLASER 180 {' '.join(['0'] * 180)} {0.05 * i} 0 0 {0.05 * i} 0 0 {t + 0.01} host {t + 0.01}")
    (tmp_path / "zero.log").write_text("\n".join(lines) + "\n")
    code, _, err = run_cli_here("import", "carmen", str(tmp_path / "zero.log"), "-o", str(tmp_path / "zero.mcap"))
    assert code == 0, err
    code, _, err = _process(tmp_path / "zero.mcap", tmp_path / "out")
    assert_one_line_error(code, err, "zero.mcap", "no usable sweep on /scan", "none of its 180 ranges is a return")


def test_a_doppler_bias_on_every_point_processes(log, tmp_path):
    bad = tmp_path / "bias.mcap"
    copy_log(log, bad, edit=lambda topic, i, msg: _set_field(msg, "velocity", lambda v: v + 0.3)
             if topic == "/fmcw/points" else None)
    code, _, err = _process(bad, tmp_path / "out")
    assert code == 0 and "Traceback" not in err, err


@pytest.mark.parametrize("command", ["process", "record"])
def test_an_output_name_that_is_not_utf8(log, tmp_path, command):
    out = tmp_path / (NOT_UTF8 + (".mcap" if command == "record" else ""))
    args = ["--duration", "2"] if command == "record" else [str(log)]
    code, err = _run_bytes(command, *args, "-o", str(out))
    assert code == 0 and "Traceback" not in err, err
    assert os.fsencode(out.name) in os.listdir(os.fsencode(tmp_path))
    assert not [n for n in os.listdir(tmp_path) if ".partial-" in n]


@pytest.mark.slow  # records, processes and reports: ~8 s
def test_run_into_a_folder_whose_name_is_not_utf8(tmp_path):
    out = tmp_path / NOT_UTF8
    code, err = _run_bytes("run", "--duration", "3", "-o", str(out))
    assert code == 0 and "Traceback" not in err, err
    assert (out / "results" / "report.html").is_file()


def test_a_killed_runs_temporary_folder_goes_with_the_next_run(log, tmp_path):
    out = tmp_path / "out"
    slow = ROOT / "sample_logs" / "crowd_30s.mcap"
    child = subprocess.Popen([sys.executable, "-m", "fmcwlog", "process", str(slow), "-o", str(out), "--jobs", "1"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    partial = tmp_path / f".out.partial-{child.pid}"
    deadline = time.monotonic() + 60
    while not partial.is_dir() and child.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.5)  # killed mid-run: its temporary folder made, its sweeps under way
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert partial.is_dir()
    code, _, err = _process(log, out)
    assert code == 0, err
    assert not partial.exists()
    assert (out / "run.json").is_file()


def test_a_live_runs_temporary_folder_is_left_alone(log, tmp_path):
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        partial = tmp_path / f".out.partial-{other.pid}"
        partial.mkdir()
        code, _, err = _process(log, tmp_path / "out")
        assert code == 0, err
        assert partial.is_dir()
    finally:
        other.kill()
        other.wait()


def test_an_error_quotes_a_short_excerpt_of_a_huge_line(tmp_path):
    (tmp_path / "big.log").write_text("1" * 4_000_000 + "\n")
    code, _, err = run_cli_here("import", "carmen", str(tmp_path / "big.log"), "-o", str(tmp_path / "big.mcap"))
    line = assert_one_line_error(code, err, "big.log", "111…", "(4000000 characters)")
    assert len(line) < 300


def test_a_huge_set_option_is_quoted_short():
    code, _, err = run_cli_here("record", "-o", "x.mcap", "--set", "a" * 5000 + "=1")
    assert len(assert_one_line_error(code, err, "--set", "(5004 characters)")) < 200


def test_report_with_an_output_under_a_file_writes_nothing(log, tmp_path):
    folders = [tmp_path / "a", tmp_path / "b"]
    for folder in folders:
        assert _process(log, folder)[0] == 0
    before = {f: sorted(p.name for p in f.iterdir()) for f in folders}
    (tmp_path / "file").write_text("")
    code, _, err = run_cli_here("report", *map(str, folders), "-o", str(tmp_path / "file" / "x"))
    assert_one_line_error(code, err, str(tmp_path / "file"), "is a file")
    assert {f: sorted(p.name for p in f.iterdir()) for f in folders} == before


@pytest.mark.parametrize("args", [["process", "{log}", "-o", "{out}"], ["process", "--show-config"]])
def test_a_reader_of_stdout_that_goes_away(log, tmp_path, args):
    args = [a.format(log=log, out=tmp_path / "out") for a in args]
    child = subprocess.Popen([sys.executable, "-m", "fmcwlog", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert child.stdout is not None and child.stderr is not None
    child.stdout.close()  # as `| head -0`: every write to stdout finds the pipe broken
    err = child.stderr.read().decode()
    assert child.wait() == 0 and err.strip() == "", err
    if "-o" in args:
        assert (tmp_path / "out" / "run.json").is_file()


def test_point_times_beyond_the_scan_rate_name_it(log, tmp_path):
    cal = dict(metadata(log)[CALIBRATION_KEY], scan_rate="50")
    bad = tmp_path / "rate.mcap"
    copy_log(log, bad, drop_metadata=(CALIBRATION_KEY,), extra_metadata={CALIBRATION_KEY: cal})
    code, _, err = _process(bad, tmp_path / "out")
    assert_one_line_error(code, err, str(bad), "beyond a sweep's 0.02 s (1 / the calibration's scan_rate, 50 Hz)")
