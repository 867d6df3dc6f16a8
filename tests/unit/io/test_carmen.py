"""Real-log import (CARMEN, CMU course format) and the relations metric.

Hand-written lines check the parser against the CARMEN conventions; the shared
datasets (``needs_datasets``: skipped where ../shared/datasets is absent) check it on real files.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers import shared_file
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from fmcwlog.evaluation.relations import read_relations, relations_error
from fmcwlog.geometry import compose
from fmcwlog.io.carmen import parse_log


def _write(tmp_path: Path, text: str, name: str = "log.clf") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_flaser_odom_param_and_bad_lines(tmp_path):
    ranges = " ".join(["2.0"] * 179 + ["81.9"])
    text = "\n".join([
        "# CARMEN Logfile",
        "PARAM robot_frontlaser_offset 0.2 1.0 host 1.0",
        "ODOM 1.0 2.0 0.5 0.1 0 0 100.5 host 100.5",
        f"FLASER 180 {ranges} 1.0 2.0 0.5 1.0 2.0 0.5 100.6 host 100.6",
        "FLASER 180 1 2 3",  # truncated
        "ODOM 1.1 2.0 0.5 0.1 0 0 oops host 100.7",  # not a number
        "SYNC something",
    ])
    p = parse_log(_write(tmp_path, text))
    assert p.format == "carmen" and len(p.scans) == 1 and len(p.odometry) == 1
    s = p.scans[0]
    assert s.stamp == 100.6 and s.laser_pose == (0.2, 0.0, 0.0)
    assert s.angle_min == pytest.approx(-math.pi / 2) and s.angle_increment == pytest.approx(math.pi / 180)
    assert np.isinf(s.ranges[-1]) and s.ranges[0] == 2.0  # 81.9 m is the no-return value
    assert [n for n, _ in p.bad_lines] == [5, 6]
    assert p.ignored == {"SYNC": 1}


def test_robotlaser1_takes_the_laser_pose_relative_to_the_robot(tmp_path):
    n = 180
    robot = (10.0, 5.0, math.pi / 2)
    laser = tuple(compose(np.array(robot), np.array([0.3, 0.0, 0.0])))
    fields = ["ROBOTLASER1", "0", "-1.570796", "3.141593", "0.017453", "50.0", "0.1", "0", str(n)] + ["3.0"] * n + \
        ["0"] + [f"{v:.6f}" for v in laser] + [f"{v:.6f}" for v in robot] + ["0"] * 5 + ["200.25", "host", "200.25"]
    p = parse_log(_write(tmp_path, " ".join(fields) + "\n"))
    s = p.scans[0]
    assert s.stamp == 200.25 and s.laser_pose == pytest.approx((0.3, 0.0, 0.0), abs=1e-5)
    assert s.odom_pose == pytest.approx(robot)


def test_cmu_course_format_is_centimetres(tmp_path):
    ranges = " ".join(["150"] * 180)
    text = "O -94.0 -140.0 -1.34 0.02\nL -94.0 -140.0 -1.34 -88.0 -164.0 -1.34 " + ranges + " 0.5\n"
    p = parse_log(_write(tmp_path, text, "robotdata.log"))
    assert p.format == "cmu" and p.odometry[0].pose == pytest.approx((-0.94, -1.40, -1.34))
    s = p.scans[0]
    assert s.ranges[0] == pytest.approx(1.5)
    assert math.hypot(*s.laser_pose[:2]) == pytest.approx(math.hypot(0.06, 0.24), abs=1e-6)


def test_relations_metric_on_known_motion():
    t = np.arange(0.0, 10.0, 1.0)
    poses = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])  # 1 m/s along x
    rel = np.array([[1.0, 3.0, 2.0, 0.0, 0.0],  # exact
                    [2.0, 4.0, 2.1, 0.0, 0.0],  # 10 cm off
                    [3.0, 5.0, 2.0, 0.0, math.radians(1.0)],  # 1 degree off
                    [20.0, 21.0, 1.0, 0.0, 0.0],  # outside the trajectory
                    [2.5, 4.0, 1.5, 0.0, 0.0]])  # 2.5 s is not a pose stamp
    r = relations_error(t, poses, rel)
    assert r.n == 3
    assert r.trans_mean_m == pytest.approx((0 + 0.1 + 2 * math.sin(math.radians(0.5)) * 1) / 3, rel=0.2)
    assert r.rot_mean_deg == pytest.approx(1 / 3, abs=1e-9)


@pytest.fixture(scope="module")
def intel(tmp_path_factory):
    """The Intel subset imported and processed once."""
    from fmcwlog.api import ProcessOptions
    from fmcwlog.api import process as process_log

    tmp = tmp_path_factory.mktemp("intel")
    log = tmp / "intel.mcap"
    proc = subprocess.run([sys.executable, "-m", "fmcwlog", "import", "carmen",
                           str(shared_file("datasets/intel_lab_subset910/intel_subset910_rawodom.clf.xz")),
                           "-o", str(log)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = tmp / "out"
    summary = process_log(log, out, ProcessOptions())
    return log, out, summary


@pytest.mark.slow
@pytest.mark.needs_datasets
def test_intel_subset_imports_with_its_own_stamps(intel):
    log, out, summary = intel
    with open(log, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        stamps = [m.log_time for _, c, m, _ in reader.iter_decoded_messages(topics=["/scan"])]
    assert len(stamps) == 910
    rel = read_relations(shared_file("datasets/freiburg_relations/intel.relations"))
    ours = {round(s * 1e-9, 6) for s in stamps}
    both = [(round(a, 6) in ours and round(b, 6) in ours) for a, b in rel[:, :2]]
    assert sum(both) == 90  # as SOURCE.md says (stamps equal to the microsecond)
    assert not summary.doppler and summary.prior == "odometry (/odom)"
    from helpers import replay_frames

    assert replay_frames.unresolved(log, ("/tf", "/tf_static")) == {}  # a viewer places every message
    assert replay_frames.unresolved(out / "processed.mcap") == {}


@pytest.mark.slow
@pytest.mark.needs_datasets
def test_intel_relations_report_beats_raw_odometry(intel):
    from fmcwlog.evaluation.evaluate import evaluate

    log, out, _ = intel
    r = evaluate(out, relations=shared_file("datasets/freiburg_relations/intel.relations")).result
    odo = r["methods"]["wheel_odometry"]["relations"]
    imp = r["methods"]["improved"]["relations"]
    assert odo["n"] == imp["n"] >= 85
    assert imp["trans_mean_m"] < odo["trans_mean_m"]
    # near twice what was measured (docs/real-logs.md: 0.018 m, the front end alone 0.115 m); a log of
    # uneven intervals once had nearly all of them taken for gaps: 0.675 m and 3.04 m
    assert imp["trans_mean_m"] < 0.04
    assert r["methods"]["improved_frontend"]["relations"]["trans_mean_m"] < 0.25
    assert r["relations_published"][0]["trans_mean_m"] == 0.220


@pytest.mark.needs_datasets
def test_fr079_sample_and_wean_hall_parse():
    fr = parse_log(shared_file("datasets/freiburg_relations/fr079_head_sample.clf"))
    assert len(fr.scans) == 7 and len(fr.odometry) == 15 and fr.scans[0].laser_pose == (-0.04, 0.0, 0.0)
    assert len(fr.scans[0].ranges) == 360 and fr.scans[0].angle_increment == pytest.approx(math.pi / 360)
    wean = parse_log(shared_file("datasets/cmu_wean_hall/robotdata1.log.xz"))
    assert wean.format == "cmu" and len(wean.scans) == 713 and len(wean.odometry) == 1505 and not wean.bad_lines


def test_a_file_with_nothing_usable_is_one_clear_error(tmp_path):
    p = _write(tmp_path, "# nothing\nFLASER 3 1 2\n")
    proc = subprocess.run([sys.executable, "-m", "fmcwlog", "import", "carmen", str(p), "-o", str(tmp_path / "x.mcap")],
                          capture_output=True, text=True, timeout=60)
    lines = [x for x in proc.stderr.splitlines() if x.strip()]
    assert proc.returncode == 2 and len(lines) == 1 and "no laser scans" in lines[0]
    assert not (tmp_path / "x.mcap").exists()


# ----------------------------------------------------------------------------- damaged files

def _room_clf(n: int = 12) -> str:
    """FLASER lines of a robot crossing a 10 m × 8 m room (ranges by ray casting here), 10 Hz."""
    angles = -math.pi / 2 + np.arange(180) * math.pi / 180
    lines = ["# a room", "PARAM robot_frontlaser_offset 0.1 0 host 0"]
    for k in range(n):
        x, t = -1.0 + 0.02 * k, 100.0 + 0.1 * k
        c, s = np.cos(angles), np.sin(angles)
        with np.errstate(divide="ignore"):
            r = np.minimum(np.where(c > 0, (5 - x) / c, np.where(c < 0, (-5 - x) / c, np.inf)),
                           np.where(s > 0, 4 / s, np.where(s < 0, -4 / s, np.inf)))
        lines.append(f"FLASER 180 {' '.join(f'{v:.3f}' for v in r)} {x:.3f} 0 0 {x:.3f} 0 0 {t:.3f} host {t:.3f}")
    return "\n".join(lines) + "\n"


def _import(src: Path, out: Path) -> tuple[int, list[str]]:
    """``fmcwlog import carmen`` in this process, judged: exit 0 with the log written and only warnings,
    or exit 2 with one error line naming the source and nothing written."""
    from helpers import run_cli_here

    code, _, err = run_cli_here("import", "carmen", str(src), "-o", str(out))
    lines = [x for x in err.splitlines() if x.strip()]
    assert code in (0, 2), err
    assert not [p for p in out.parent.iterdir() if ".partial" in p.name]
    if code == 2:
        assert len(lines) == 1 and lines[0].startswith("fmcwlog: error: ") and str(src) in lines[0], err
        assert not out.exists()
    else:
        assert out.exists() and all(x.startswith("fmcwlog: warning: ") for x in lines), err
    return code, lines


def _scans(log: Path) -> int:
    with open(log, "rb") as fh:
        return sum(1 for _ in make_reader(fh).iter_messages(topics=["/scan"]))


@pytest.mark.parametrize("content, words", [
    (bytes(range(256)) * 20, "binary data"),
    (b"", "no laser scans found in 0 lines"),
    (b"# only a comment\nFLASER 3 1 2\n", "first malformed: line 2"),
    (b"ODOM 1 2 0 0 0 0 10.0 h 10.0\nODOM 1 2 0 0 0 0 10.1 h 10.1\n", "in 2 lines (0 malformed, 2 of odometry)"),
])
def test_a_file_without_a_usable_scan_is_one_error(tmp_path, content, words):
    src = tmp_path / "bad.clf"
    src.write_bytes(content)
    code, lines = _import(src, tmp_path / "out.mcap")
    assert code == 2 and words in lines[0], lines


@pytest.mark.parametrize("compress", [gzip.compress, lzma.compress])
def test_a_compressed_file_cut_off_imports_the_lines_before_with_a_warning(tmp_path, compress):
    text = _room_clf(40)
    data = compress(text.encode())
    suffix = ".gz" if compress is gzip.compress else ".xz"
    src = tmp_path / f"cut.clf{suffix}"
    src.write_bytes(data[: len(data) * 3 // 4])
    code, lines = _import(src, tmp_path / "out.mcap")
    kept = _scans(tmp_path / "out.mcap")
    assert code == 0 and 0 < kept < 40 and any("ends early" in x for x in lines), lines
    # every scan imported is a whole line of the original: those before the cut
    assert kept == len(parse_log(src).scans)


@pytest.mark.parametrize("compress", [gzip.compress, lzma.compress])
def test_damaged_compressed_data_are_one_error(tmp_path, compress):
    data = bytearray(compress(_room_clf(40).encode()))
    data[len(data) // 2] ^= 0x55
    src = tmp_path / ("flip.clf.gz" if compress is gzip.compress else "flip.clf.xz")
    src.write_bytes(bytes(data))
    code, lines = _import(src, tmp_path / "out.mcap")
    assert code == 2 and "compressed data are damaged" in lines[0], lines


def test_impossible_values_are_counted_bad_lines(tmp_path):
    lines = _room_clf(12).splitlines()
    flaser = lines[5].split()
    bad = {
        4: " ".join(flaser[:2] + ["nan"] + flaser[3:]),  # a NaN range
        5: " ".join(flaser[:-3] + ["inf", "host", "inf"]),  # an infinite time
        6: " ".join(flaser[:2] + ["-3.0"] + flaser[3:]),  # a negative range
        7: " ".join(flaser[:2 + 180 + 3] + ["1e12"] + flaser[2 + 180 + 4:]),  # an odometry pose 1e9 km away
        8: " ".join(flaser[:-3] + ["1e300", "host", "1"]),  # a time after 2038
        9: lines[9][: len(lines[9]) // 2],  # a line cut in the middle
        10: "FLASER 1 2.0 0 0 0 0 0 0 101.9 host 101.9",  # one beam
    }
    for i, line in bad.items():
        lines[i] = line
    lines.insert(2, "PARAM robot_front_laser_fov nan 0 host 0")
    src = _write(tmp_path, "\n".join(lines) + "\n")
    parsed = parse_log(src)
    assert [n for n, _ in parsed.bad_lines] == [3] + [i + 2 for i in sorted(bad)], parsed.bad_lines
    assert len(parsed.scans) == 12 - len(bad) and parsed.scans[0].angle_increment == pytest.approx(math.pi / 180)
    code, out = _import(src, tmp_path / "out.mcap")
    assert code == 0 and out == [x for x in out if "skipped 8 malformed lines" in x], out


@settings(max_examples=50, deadline=None, derandomize=True, database=None)
@given(kind=st.sampled_from(["plain", "gz", "xz", "bz2"]), cut=st.floats(0.0, 1.0),
       flips=st.lists(st.tuples(st.integers(0, 2**31), st.integers(1, 255)), max_size=3),
       tokens=st.lists(st.tuples(st.integers(0, 10**6), st.sampled_from(["nan", "inf", "-inf", "1e308", "-1", "0",
                                                                       "x", "", "FLASER", "9" * 30])), max_size=3))
def test_fuzz_damaged_carmen_files(kind, cut, flips, tokens):
    """Tokens replaced, the file compressed, cut and flipped: one error line or a log with warnings."""
    import tempfile

    lines = [line.split() for line in _room_clf(6).splitlines()]
    for at, token in tokens:
        row = lines[at % len(lines)]
        row[at % len(row)] = token
    data = ("\n".join(" ".join(row) for row in lines) + "\n").encode()
    data = {"plain": bytes, "gz": gzip.compress, "xz": lzma.compress, "bz2": bz2.compress}[kind](data)
    data = bytearray(data[: int(cut * len(data))] if flips else data[: max(int(cut * len(data)), len(data) // 2)])
    for at, mask in flips:
        if data:
            data[at % len(data)] ^= mask
    with tempfile.TemporaryDirectory() as tmp:
        src = Path(tmp) / f"log.clf{'' if kind == 'plain' else '.' + kind}"
        src.write_bytes(bytes(data))
        _import(src, Path(tmp) / "out.mcap")


# ----------------------------------------------------------------------------- files as users ship them

def _stamps_and_ranges(log: Path) -> tuple[list[int], list[np.ndarray]]:
    """The /scan log times and ranges of an MCAP log, read with plain mcap/mcap_ros2."""
    stamps, ranges = [], []
    with open(log, "rb") as fh:
        for _, _, msg, ros in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(
                topics=["/scan"]):
            stamps.append(msg.log_time)
            ranges.append(np.asarray(ros.ranges))
    return stamps, ranges


@pytest.mark.parametrize("name, encode", [
    ("log.clf.GZ", lambda b: gzip.compress(b)),  # the suffix in capitals
    ("log.clf", lambda b: gzip.compress(b)),  # a gzip stream without its suffix
    ("log.clf.bz2", lambda b: bz2.compress(b)),
    ("log.clf", lambda b: "\ufeff".encode() + b.replace(b"\n", b"\r\n")),  # Windows: byte-order mark, CR LF
])
def test_a_log_as_users_ship_it_imports_like_the_plain_file(tmp_path, name, encode):
    """Known by its first bytes, not its name; a byte-order mark must not hide the first line."""
    text = "\n".join(x for x in _room_clf(12).splitlines() if x.startswith("FLASER")) + "\n"  # a scan on line 1
    plain = _write(tmp_path, text, "plain.clf")
    (tmp_path / "v").mkdir()
    src = tmp_path / "v" / name
    src.write_bytes(encode(text.encode()))
    assert _import(plain, tmp_path / "plain.mcap") == (0, [])
    assert _import(src, tmp_path / "v.mcap") == (0, [])
    want, got = _stamps_and_ranges(tmp_path / "plain.mcap"), _stamps_and_ranges(tmp_path / "v.mcap")
    assert len(want[0]) == 12 and got[0] == want[0]
    assert all(np.array_equal(a, b) for a, b in zip(got[1], want[1]))


def test_damaged_bzip2_data_are_one_error(tmp_path):
    data = bytearray(bz2.compress(_room_clf(40).encode()))
    data[len(data) // 2] ^= 0x55
    src = tmp_path / "flip.clf.bz2"
    src.write_bytes(bytes(data))
    code, lines = _import(src, tmp_path / "out.mcap")
    assert code == 2 and "compressed data are damaged" in lines[0], lines


def test_time_going_backwards_is_written_in_order_and_named_by_line(tmp_path):
    lines = _room_clf(12).splitlines()  # lines 3..14 are scans at 100.0, 100.1, ... s
    lines[6], lines[7] = lines[7], lines[6]  # file lines 7 and 8 swapped: line 8 goes back 0.1 s
    src = _write(tmp_path, "\n".join(lines) + "\n")
    code, out = _import(src, tmp_path / "out.mcap")
    assert code == 0 and len(out) == 1 and "time goes backwards at line 8 (0.100 s" in out[0], out
    stamps, _ = _stamps_and_ranges(tmp_path / "out.mcap")
    assert stamps == [round((100.0 + 0.1 * k) * 1e9) for k in range(12)]


def test_repeated_scans_are_counted_once(tmp_path):
    lines = _room_clf(6).splitlines()
    src = _write(tmp_path, "\n".join(lines + lines[2:]) + "\n")  # every scan twice
    from helpers import run_cli_here

    code, stdout, err = run_cli_here("import", "carmen", str(src), "-o", str(tmp_path / "out.mcap"))
    assert code == 0 and "skipped 6 scans whose stamp repeats" in err, err
    assert _scans(tmp_path / "out.mcap") == 6 and "wrote" in stdout and ": 6 scans, 6 odometry poses" in stdout, stdout


def _rawlaser_from_flaser(line: str, kind: str = "RAWLASER1") -> list[str]:
    """An ODOM line and a RAWLASER line carrying what a FLASER line does (180 beams from -90 deg, 1 deg apart)."""
    tok = line.split()
    ranges, odom, t = tok[2:182], tok[185:188], tok[188]
    return [" ".join(["ODOM", *odom, "0", "0", "0", t, "host", t]),
            " ".join([kind, "0", f"{-math.pi / 2:.9f}", f"{math.pi:.9f}", f"{math.pi / 180:.9f}", "81.9", "0.01", "0",
                      "180", *ranges, "0", t, "host", t])]


def test_rawlaser1_with_odom_imports_as_the_flaser_lines_do(tmp_path):
    """The same scans as RAWLASER1 + ODOM lines: the same stamps, beams and ranges on /scan, the same
    laser offset (from PARAM), the odometry from ODOM."""
    room = _room_clf(8).splitlines()
    raw = room[:2] + [x for line in room[2:] for x in _rawlaser_from_flaser(line)]
    flaser, rawlog = _write(tmp_path, "\n".join(room) + "\n", "f.clf"), _write(tmp_path, "\n".join(raw) + "\n", "r.clf")
    a, b = parse_log(flaser), parse_log(rawlog)
    assert len(b.scans) == 8 and len(b.odometry) == 8 and not b.bad_lines and not b.ignored
    for s, r in zip(a.scans, b.scans):
        assert r.stamp == s.stamp and r.laser_pose == s.laser_pose == (0.1, 0.0, 0.0) and r.topic == "/scan"
        assert r.angle_min == pytest.approx(s.angle_min) and r.angle_increment == pytest.approx(s.angle_increment)
        assert np.array_equal(r.ranges, s.ranges)
    assert [o.pose for o in b.odometry] == [s.odom_pose for s in a.scans]
    assert _import(rawlog, tmp_path / "r.mcap") == (0, []) and _scans(tmp_path / "r.mcap") == 8


def test_rawlaser1_beside_robotlaser1_is_not_a_second_scan(tmp_path):
    """The CARMEN logger writes a scan as ROBOTLASER1 and RAWLASER1: one scan each, the posed one kept."""
    n, lines = 180, []
    for k in range(5):
        t = f"{300 + 0.1 * k:.3f}"
        robot = (0.1 * k, 0.0, 0.0)
        laser = (0.1 * k + 0.25, 0.0, 0.0)
        lines.append(" ".join(["ROBOTLASER1", "0", "-1.570796", "3.141593", "0.017453", "50.0", "0.1", "0", str(n)]
                              + ["3.0"] * n + ["0"] + [f"{v:.6f}" for v in laser + robot] + ["0"] * 5 + [t, "host", t]))
        lines.append(_rawlaser_from_flaser(" ".join(["FLASER", "180"] + ["3.0"] * 180 + ["0"] * 6 + [t, "h", t]))[1])
    p = parse_log(_write(tmp_path, "\n".join(lines) + "\n"))
    assert len(p.scans) == 5 and all(s.laser_pose == pytest.approx((0.25, 0.0, 0.0)) for s in p.scans)
    assert p.ignored == {"RAWLASER1": 5}


def test_rawlaser1_without_odom_says_there_is_no_odometry(tmp_path):
    from helpers import run_cli_here

    lines = [_rawlaser_from_flaser(line)[1] for line in _room_clf(4).splitlines()[2:]]
    src = _write(tmp_path, "\n".join(lines) + "\n")
    code, stdout, err = run_cli_here("import", "carmen", str(src), "-o", str(tmp_path / "out.mcap"))
    assert code == 0 and not err and _scans(tmp_path / "out.mcap") == 4
    assert "4 scans, 0 odometry poses (from nowhere: the log has no ODOM lines" in stdout, stdout
def test_scans_with_a_repeated_stamp_are_counted_and_the_summary_says_what_was_written(tmp_path):
    """Laser lines that repeat their stamp were once dropped without a word, the summary still counting
    them ('12 scans' for a log of 1): now one warning per topic, and the counts are the log's (plain mcap)."""
    from helpers import run_cli_here

    lines = _room_clf(12).splitlines()
    stamp = lines[2].split()[-1]  # every laser line at the first line's time
    same = [" ".join(x.split()[:-3] + [stamp, "host", stamp]) if x.startswith("FLASER") else x for x in lines]
    src = tmp_path / "same.clf"
    src.write_text("\n".join(same) + "\n")
    out = tmp_path / "same.mcap"
    code, stdout, err = run_cli_here("import", "carmen", str(src), "-o", str(out))
    assert code == 0, err
    with open(out, "rb") as fh:
        summary = make_reader(fh).get_summary()
    counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
    assert counts == {"/scan": 1, "/odom": 1, "/tf": 1, "/tf_static": 1}
    assert f"{src}: skipped 11 scans whose stamp repeats the one before" in err, err
    assert "1 scans, 1 odometry poses" in stdout, stdout


def _moving_robot_clf(tmp_path: Path) -> Path:
    """A robot driving and turning, its odometry on ODOM lines from t = 100 s; front (0.2 m ahead)
    and rear (0.1 m behind, facing back) lasers, one front scan before the first ODOM line and one
    rear scan after the last."""
    r = " ".join(["2.0"] * 180)
    lines = ["PARAM robot_frontlaser_offset 0.2 1.0 host 1.0", "PARAM robot_rearlaser_offset 0.1 1.0 host 1.0",
             f"FLASER 180 {r} 0 0 0 0 0 0 99.95 host 99.95"]
    for k in range(10):
        t, (x, y, th) = 100 + 0.1 * k, (5 + 0.1 * k, 3 + 0.02 * k, 1.0 + 0.05 * k)
        lines += [f"ODOM {x} {y} {th} 0.1 0 0 {t:.3f} host {t:.3f}",
                  f"FLASER 180 {r} 0 0 0 {x} {y} {th} {t + 0.05:.3f} host {t:.3f}",
                  f"RLASER 180 {r} 0 0 0 {x} {y} {th} {t + 0.06:.3f} host {t:.3f}"]
    return _write(tmp_path, "\n".join(lines) + "\n")


def test_an_import_carries_its_tf_tree_and_every_message_resolves_to_map(tmp_path):
    """/tf_static: each laser's mount and map -> odom (map's origin where the robot is at the first
    scan); /tf: odom -> base_link from the odometry, held at the scans beyond it. Read as a viewer
    reads it (plain mcap + mcap_ros2), through /tf and /tf_static alone as RViz does."""
    from helpers import decoded, replay_frames

    from fmcwlog.geometry import between

    log = tmp_path / "robot.mcap"
    assert _import(_moving_robot_clf(tmp_path), log) == (0, [])
    rviz = ("/tf", "/tf_static")
    assert replay_frames.unresolved(log, rviz) == {}
    static = [m for _, _, _, m in decoded(log, ["/tf_static"])]
    assert len(static) == 1
    links = {(t.header.frame_id, t.child_frame_id): replay_frames._planar(t.transform) for t in static[0].transforms}
    assert set(links) == {("base_link", "laser"), ("base_link", "rear_laser"), ("map", "odom")}
    assert links[("base_link", "laser")] == pytest.approx((0.2, 0.0, 0.0))
    assert links[("base_link", "rear_laser")] == pytest.approx((-0.1, 0.0, math.pi))
    frames = {t: {m.header.frame_id for _, _, _, m in decoded(log, [t])} for t in ("/scan", "/rear_scan", "/odom")}
    assert frames == {"/scan": {"laser"}, "/rear_scan": {"rear_laser"}, "/odom": {"odom"}}
    tree = replay_frames.read_tf(log, rviz)
    first = (5.0, 3.0, 1.0)  # the first scan comes before the odometry: its first pose, held
    assert tree.resolve("base_link", round(99.95e9)) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    for _, _, message, odom in decoded(log, ["/odom"]):
        p = odom.pose.pose
        pose = (p.position.x, p.position.y, 2 * math.atan2(p.orientation.z, p.orientation.w))
        assert tree.resolve("base_link", message.log_time) == pytest.approx(
            tuple(between(np.array(first), np.array(pose))), abs=1e-9)
    last = max(m.log_time for _, _, m, _ in decoded(log, ["/rear_scan"]))
    assert tree.resolve("rear_laser", last) == pytest.approx(
        tuple(compose(between(np.array(first), np.array([5.9, 3.18, 1.45])), np.array([-0.1, 0.0, math.pi]))),
        abs=1e-9)


@pytest.mark.slow
def test_processed_import_overlays_the_import_in_map(tmp_path):
    """Processed, the import's estimates start where its map puts the robot: wheel_odometry/base_link
    in processed.mcap's map is the import's base_link in its map at every sweep, and both files resolve."""
    from helpers import replay_frames

    from fmcwlog.api import ProcessOptions, process

    log, out = tmp_path / "robot.mcap", tmp_path / "out"
    assert _import(_moving_robot_clf(tmp_path), log) == (0, [])
    process(log, out, ProcessOptions(methods=("baseline",), backend="none"))
    assert replay_frames.unresolved(out / "processed.mcap") == {}
    ours, theirs = replay_frames.read_tf(out / "processed.mcap"), replay_frames.read_tf(log)
    stamps = np.loadtxt(out / "wheel_odometry.tum")[:, 0]
    assert len(stamps) == 11  # the front scans
    for t in stamps:
        ns = round(t * 1e9)
        assert ours.resolve("wheel_odometry/base_link", ns) == pytest.approx(theirs.resolve("base_link", ns), abs=1e-6)
