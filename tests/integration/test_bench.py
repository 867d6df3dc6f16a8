"""The benchmark scripts' per-sweep figures come from the method measured, not from every row.

`trajectories.parquet` holds a row per sweep for each method and for `wheel_odometry`, whose `ms`
is null: a median over every row was NaN and counted each sweep twice. The independent fact is the
log itself: a recording of D seconds at the LiDAR's 10 Hz has 10·D sweeps.
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import ROOT

pytestmark = pytest.mark.slow  # end to end: the bench scripts in a subprocess

SCAN_RATE_HZ = 10.0  # the simulated LiDAR's default (README, "What is simulated")


def _bench(script: str, *args: str, cwd: Path = ROOT) -> str:
    res = subprocess.run([sys.executable, str(ROOT / "bench" / script), *args], cwd=cwd, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return res.stdout


def test_bench_process_counts_and_times_the_methods_sweeps_only():
    seconds = 3.0
    out = _bench("bench_process.py", "--minutes", str(seconds / 60), "--methods", "baseline")
    row = re.search(r"^\| corridor \| [\d.]+ \| baseline \| (\d+) \| ([^|]+) \| ([^|]+) \|", out, re.M)
    assert row, out
    assert int(row.group(1)) == round(seconds * SCAN_RATE_HZ)
    median, p95 = float(row.group(2)), float(row.group(3))
    assert math.isfinite(median) and math.isfinite(p95) and 0 < median <= p95


def test_suite_scaling_counts_and_times_the_improved_sweeps_only(tmp_path):
    seconds = 3.0
    out = _bench("suite.py", "--scenarios", "static", "--seeds", "0", "--duration", "2", "--no-kiss",
                 "--scaling", str(seconds / 60), "--out", str(tmp_path))
    md = (tmp_path / "suite.md").read_text()
    row = re.search(r"^\| [\d.]+ \| (\d+) \| ([^|]+) \| ([^|]+) \|", md.split("Scaling")[-1], re.M)
    assert row, out
    assert int(row.group(1)) == round(seconds * SCAN_RATE_HZ)
    median, p95 = float(row.group(2)), float(row.group(3))
    assert math.isfinite(median) and math.isfinite(p95) and 0 < median <= p95


def test_backend_targets_without_the_shared_datasets_is_one_line(tmp_path):
    # a checkout with no ../shared beside it: the script's own copy in such a tree
    bench = tmp_path / "checkout" / "bench"
    bench.mkdir(parents=True)
    (bench / "backend_targets.py").write_text((ROOT / "bench" / "backend_targets.py").read_text())
    res = subprocess.run([sys.executable, str(bench / "backend_targets.py"), "--only", "intel"], capture_output=True,
                         text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and str(tmp_path / "shared" / "datasets") in lines[0], res.stderr


@pytest.mark.parametrize("script, args", [("feature_floor.py", ()), ("killian_log.py", ("--help",))])
def test_bench_scripts_measure_their_own_checkout(tmp_path, script, args):
    # an installed fmcwlog other than this checkout's (a venv's editable install of another tree)
    fake = tmp_path / "elsewhere" / "fmcwlog"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('the installed fmcwlog, not this checkout')\n")
    res = subprocess.run([sys.executable, str(ROOT / "bench" / script), *args], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(fake.parent)})
    assert "not this checkout" not in res.stderr
    assert "Traceback" not in res.stderr, res.stderr
