"""Scanners of every shape, and logs that lost many of their sweeps.

- A 360° LaserScan at 0.5° and 10 Hz whose first and last beams coincide (721 beams, -π to +π),
  written by plain ``mcap_ros2`` with its float32 times: its last beam lies at 0.1000000024 s of a
  0.1 s period. Every sweep is used and the trajectory is as good as with 720 beams.
- A log with more than half of its sweeps damaged is one error line and no output folder (a failed
  log, with that line as its reason, in a batch), unless ``--keep-going``; with 10 % damaged it is
  processed, and the share skipped is the last line, in run.json and in the report's header.

The LaserScans are re-sampled from a recording of fmcwlog's simulator, beam by beam (each point's
time gives its beam), and written with ``mcap_ros2``'s ``Writer``, not fmcwlog's.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import ROOT, ate_rmse, copy_log, decoded, ground_truth, metadata, record_small_ring, tum
from mcap.reader import make_reader
from mcap_ros2.writer import Writer

from fmcwlog.api import ProcessOptions, process

pytestmark = pytest.mark.slow  # end to end: logs recorded, rewritten and processed

PERIOD = 0.1  # s: 10 Hz
TURN = 720  # beams in a full turn at 0.5°
_HEADER = ("=" * 80 + "\nMSG: std_msgs/msg/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
           + "=" * 80 + "\nMSG: builtin_interfaces/msg/Time\nint32 sec\nuint32 nanosec\n")


@pytest.fixture(scope="module")
def full_turn_log(tmp_path_factory) -> Path:
    """14 s of the small ring (a straight, a corner, the next straight) by a 360° scanner at 0.5°: 721
    beams from -180° to +180°, the last one at t = 0.1 s (float32: 0.10000000149 s)."""
    return record_small_ring(tmp_path_factory.mktemp("turn") / "turn.mcap", fov_deg=360.0, resolution_deg=0.5)


def as_laserscan(src: Path, dst: Path, beams: int) -> Path:
    """``src`` with /fmcw/points replaced by a LaserScan on /scan of ``beams`` beams at 0.5° from -π,
    time_increment 0.1 s / 720 (float32, as LaserScan holds it); every other topic and record kept."""
    inc = 2 * math.pi / TURN
    with open(src, "rb") as fh:
        texts = {sc.name: sc.data.decode() for sc in make_reader(fh).get_summary().schemas.values()}
    with open(dst, "wb") as out:
        w = Writer(out)
        for name, values in metadata(src).items():
            w.add_metadata(name, values)
        scan = w.register_msgdef("sensor_msgs/msg/LaserScan",
                                 (ROOT / "schemas/sensor_msgs/msg/LaserScan.msg").read_text() + _HEADER)
        schemas = {}
        for schema, channel, message, msg in decoded(src):
            if channel.topic != "/fmcw/points":
                if schema.name not in schemas:
                    schemas[schema.name] = w.register_msgdef(schema.name, texts[schema.name])
                w.write_message(channel.topic, schemas[schema.name], msg, log_time=message.log_time,
                                publish_time=message.publish_time)
                continue
            pts = np.frombuffer(bytes(msg.data), np.float32).reshape(-1, 6)  # x y z intensity velocity t
            beam = np.rint(pts[:, 5] / PERIOD * TURN).astype(int)
            ranges = np.full(beams, np.inf, np.float32)  # no return
            ranges[beam[beam < beams]] = np.hypot(pts[beam < beams, 0], pts[beam < beams, 1])
            w.write_message("/scan", scan, {
                "header": {"stamp": {"sec": msg.header.stamp.sec, "nanosec": msg.header.stamp.nanosec},
                           "frame_id": "laser"},
                "angle_min": -math.pi, "angle_max": -math.pi + (beams - 1) * inc, "angle_increment": inc,
                "time_increment": PERIOD / TURN, "scan_time": PERIOD, "range_min": 0.1, "range_max": 30.0,
                "ranges": ranges.tolist(), "intensities": []},
                log_time=message.log_time, publish_time=message.publish_time)
        w.finish()
    return dst


def test_a_full_turn_laserscan_with_float32_times_uses_every_sweep(full_turn_log, tmp_path):
    """721 beams, -π to +π: every one of the 140 sweeps is used (before, all but those whose last beam
    gave no return were skipped), the improved ATE is 5.5 mm, and 720 beams give the same
    trajectories to the byte. fmcwlog's own 360° log (float32 t, the last at the period) too."""
    gt = ground_truth(full_turn_log)
    errors = {}
    for beams in (721, 720):
        log = as_laserscan(full_turn_log, tmp_path / f"scan{beams}.mcap", beams)
        if beams == 721:  # the case: the last beam's time, as LaserScan stores it, lies past the period
            assert 720 * next(m for _, _, _, m in decoded(log, ["/scan"])).time_increment > PERIOD
        s = process(log, tmp_path / f"out{beams}", ProcessOptions())
        assert (s.sweeps, s.skipped_sweeps, s.many_skipped) == (140, 0, None), s.warnings
        errors[beams] = {m: ate_rmse(tum(tmp_path / f"out{beams}" / f"{m}.tum"), gt) for m in ("improved", "baseline")}
    assert errors[721]["improved"] < 0.011, errors  # measured 5.5 mm (baseline 6.2 cm, wheel odometry 3.3 cm)
    for name in ("improved.tum", "baseline.tum"):
        assert (tmp_path / "out721" / name).read_bytes() == (tmp_path / "out720" / name).read_bytes(), name
    own = process(full_turn_log, tmp_path / "own", ProcessOptions(methods=("baseline",), backend="none"))
    assert (own.sweeps, own.skipped_sweeps) == (140, 0), own.warnings


# ----------------------------------------------------------------------------- logs that lost sweeps


@pytest.fixture(scope="module")
def ring_6s(tmp_path_factory) -> Path:
    """6 s of the small ring: 60 sweeps."""
    return record_small_ring(tmp_path_factory.mktemp("ring") / "ring.mcap", duration=6.0)


def damaged(src: Path, dst: Path, which) -> Path:
    """``src`` with the first point of sweep ``i`` timed 1e6 s after its stamp where ``which(i)``."""
    def edit(topic, i, msg):
        if topic == "/fmcw/points" and which(i):
            f = next(f for f in msg.fields if f.name == "t")
            data = bytearray(msg.data)
            data[f.offset:f.offset + 4] = np.float32(1e6).tobytes()
            msg.data = bytes(data)
    copy_log(src, dst, edit=edit)
    return dst


def fmcwlog(*args: str) -> tuple[int, list[str]]:
    """``fmcwlog ARGS`` in a fresh interpreter: its exit status and its output's lines, stdout and
    stderr as a terminal shows them (one stream, in order)."""
    ran = subprocess.run([sys.executable, "-m", "fmcwlog", *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                         text=True, timeout=600, cwd=ROOT)
    return ran.returncode, [line for line in ran.stdout.splitlines() if line.strip()]


def test_most_sweeps_damaged_is_one_error_and_no_output_unless_asked_to_go_on(ring_6s, tmp_path):
    log = damaged(ring_6s, tmp_path / "most.mcap", lambda i: i % 10 != 3)  # 54 of 60
    out = tmp_path / "out"
    code, lines = fmcwlog("process", str(log), "-o", str(out))
    assert code == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"fmcwlog: error: {log}: 54 of 60 sweeps on /fmcw/points skipped (90.0 %, more than "
                               "half"), lines
    assert "the main reason: 54 sweeps on /fmcw/points whose point times lie outside [0, 0.1 s]" in lines[0]
    assert "--keep-going" in lines[0] and not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["most.mcap"]

    code, lines = fmcwlog("process", str(log), "-o", str(out), "--keep-going")
    assert code == 0, lines
    assert lines[-1].startswith("fmcwlog: warning: 54 of 60 sweeps on /fmcw/points skipped (90.0 %, more than half, "
                                "processed as --keep-going asks: the results stand on the 6 left); the main reason: "
                                "54 sweeps"), lines[-1]
    run = json.loads((out / "run.json").read_text())
    assert run["sweeps"] == 6 and run["many_skipped_sweeps"]["kept_going"] is True
    assert {k: run["many_skipped_sweeps"][k] for k in ("skipped", "read", "share", "main_kind")} == \
        {"skipped": 54, "read": 60, "share": 0.9, "main_kind": "times"}
    assert fmcwlog("report", str(out))[0] == 0
    md = (out / "report.md").read_text().splitlines()
    assert md[3].startswith("- sweeps skipped: 54 of 60 (90.0 %), processed on past half as asked (--keep-going)"), md[:5]
    assert "point times lie outside [0, 0.1 s]" in md[3]
    assert json.loads((out / "report.json").read_text())["header"]["many_skipped_sweeps"]["skipped"] == 54
    assert "<td>sweeps skipped</td><td>54 of 60 (90.0 %)" in (out / "report.html").read_text()


def test_a_tenth_damaged_is_processed_and_says_so_last(ring_6s, tmp_path):
    log = damaged(ring_6s, tmp_path / "tenth.mcap", lambda i: i % 10 == 3)  # 6 of 60
    out = tmp_path / "out"
    code, lines = fmcwlog("process", str(log), "-o", str(out))
    assert code == 0, lines
    assert lines[-2] == f"wrote {out}/", lines
    assert lines[-1].startswith("fmcwlog: warning: 6 of 60 sweeps on /fmcw/points skipped (10.0 %, more than 5 %: the "
                                "results stand on the 54 left); the main reason: 6 sweeps on /fmcw/points whose point "
                                "times lie outside [0, 0.1 s] (first: at "), lines[-1]
    run = json.loads((out / "run.json").read_text())
    assert run["many_skipped_sweeps"]["share"] == 0.1 and run["many_skipped_sweeps"]["kept_going"] is False
    assert run["warnings"][-1] == lines[-1].removeprefix("fmcwlog: warning: ")


def test_a_batch_fails_the_log_that_lost_most_sweeps_with_its_reason(ring_6s, tmp_path):
    """In a batch, the log that lost most of its sweeps fails alone, its reason the same line; the one
    that lost a tenth is done, flagged on the fleet page. With --keep-going both are done."""
    logs = tmp_path / "logs"
    logs.mkdir()
    damaged(ring_6s, logs / "most.mcap", lambda i: i % 10 != 3)
    damaged(ring_6s, logs / "tenth.mcap", lambda i: i % 10 == 3)
    code, lines = fmcwlog("process", str(logs), "-o", str(tmp_path / "fleet"), "--method", "baseline", "-j", "2")
    assert code == 1, lines
    batch = json.loads((tmp_path / "fleet" / "batch.json").read_text())["logs"]
    assert batch["most"]["status"] == "failed" and batch["tenth"]["status"] == "done", batch
    assert batch["most"]["reason"].startswith(f"{logs / 'most.mcap'}: 54 of 60 sweeps on /fmcw/points skipped")
    assert fmcwlog("report", str(tmp_path / "fleet"))[0] == 0
    fleet = {r["name"]: r for r in json.loads((tmp_path / "fleet" / "fleet.json").read_text())["logs"]}
    assert fleet["tenth"]["skipped_sweeps_share"] == 0.1
    assert any(f.startswith("10.0 % of its sweeps skipped") for f in fleet["tenth"]["flags"]), fleet["tenth"]
    code, lines = fmcwlog("process", str(logs), "-o", str(tmp_path / "fleet"), "--method", "baseline", "-j", "2",
                          "--keep-going")
    assert code == 0, lines
    batch = json.loads((tmp_path / "fleet" / "batch.json").read_text())["logs"]
    assert batch["most"]["status"] == "done" and batch["tenth"]["status"] == "skipped", batch
