"""``fmcwlog report`` on damaged or mismatched inputs: one line naming the file and what is wrong.

Damaged: run.json, trajectories.parquet, a TUM file, a relations file with a NaN, a log whose
``fmcwlog.world`` record breaks the log format (docs/log-format.md). Mismatched: a ``--log`` of another seed whose
sweep stamps are the very same (checked here with the plain ``mcap`` reader), which only the
log's digest recorded in run.json can tell apart.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from helpers import SAMPLE_LOGS, assert_one_line_error, copy_log, decoded, run_cli_here

from fmcwlog.io.atomic import MARKER

pytestmark = pytest.mark.slow  # end to end: report on processed logs


def _short_log(path: Path, sweeps: int = 8, **kw) -> Path:
    def edit(topic, i, msg):
        return False if i >= (sweeps if topic == "/fmcw/points" else 5 * sweeps) else None

    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", path, edit=edit, **kw)
    return path


def _process(log: Path, out: Path) -> Path:
    code, _, err = run_cli_here("-q", "process", str(log), "-o", str(out))
    assert code == 0, err
    return out


@pytest.fixture(scope="module")
def made(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("report_inputs")
    return _process(_short_log(root / "s.mcap"), root / "out")


@pytest.fixture
def out(made, tmp_path) -> Path:
    dst = tmp_path / "out"
    shutil.copytree(made, dst)
    return dst


def _report_fails(out: Path, *words: str, args=()) -> None:
    before = sorted(p.name for p in out.iterdir())
    code, _, err = run_cli_here("report", str(out), *args)
    assert_one_line_error(code, err, *words)
    assert sorted(p.name for p in out.iterdir()) == before  # no report, nothing half-written


@pytest.mark.parametrize("content, words", [
    (b"\xff\xfe\x00garbage", ["run.json"]),
    (b'{"log": "x.mcap", "sweeps": ', ["run.json", "malformed"]),
    (b"[1, 2, 3]", ["run.json", "JSON object"]),
    (b'{"log": 5}', ["run.json", "'log'"]),
    (b'{"log": "x", "stamp_shift_s": "half"}', ["run.json", "stamp_shift_s"]),
    (b'{"log": "x", "stamp_shift_s": 1e300}', ["run.json", "stamp_shift_s"]),
    (b'{"log": "x", "sweeps": -4}', ["run.json", "sweeps"]),
    (b'{"log": "x", "params": [1]}', ["run.json", "params"]),
])
def test_damaged_run_json(out, content, words):
    (out / "run.json").write_bytes(content)
    _report_fails(out, *words)


def test_damaged_trajectories_parquet(out):
    path = out / "trajectories.parquet"
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])  # cut off: the footer is gone
    _report_fails(out, "trajectories.parquet", "damaged")
    path.write_bytes(whole[:4] + b"\x00" * (len(whole) - 8) + whole[-4:])  # magic intact, contents zeroed
    _report_fails(out, "trajectories.parquet")
    pq.write_table(pa.table({"method": ["improved"], "t": [1.0]}), path)  # readable, but not ours
    _report_fails(out, "trajectories.parquet", "stamp_ns")


@pytest.mark.parametrize("edit, words", [
    (lambda lines: lines[:3] + ["this is not a pose"] + lines[3:], ["improved.tum", "not a TUM trajectory"]),
    (lambda lines: [" ".join(line.split()[:3]) for line in lines], ["improved.tum", "8"]),
    (lambda lines: lines[:2] + [" ".join([lines[2].split()[0], "nan", *lines[2].split()[2:]])] + lines[3:],
     ["improved.tum", "pose 3", "finite"]),
    (lambda lines: [lines[1], lines[0]] + lines[2:], ["improved.tum", "increase"]),
    (lambda lines: [" ".join(line.split()[:4] + ["0", "0", "0", "0"]) for line in lines], ["improved.tum", "quaternion"]),
])
def test_damaged_tum(out, edit, words):
    path = out / "improved.tum"
    path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")
    _report_fails(out, *words)


def test_relations_with_a_nan(out, tmp_path):
    rel = tmp_path / "r.relations"
    rel.write_text("1.0 2.0 0.1 0.0 0 0 0 0.01\n2.0 3.0 nan 0.0 0 0 0 0.0\n")
    _report_fails(out, "r.relations", "line 2", "not finite", args=("--relations", str(rel)))


def test_relations_of_another_log_are_said_to_score_nothing(out, tmp_path):
    # stamps a day past the log's: a well-formed file for some other run
    rel = tmp_path / "other.relations"
    rel.write_text("86400.0 86401.0 0.1 0.0 0 0 0 0.01\n86401.0 86402.0 0.1 0.0 0 0 0 0.0\n")
    code, _, err = run_cli_here("report", str(out), "--relations", str(rel))
    assert code == 0
    warning = [line for line in err.splitlines() if "other.relations" in line]
    assert len(warning) == 1 and "none of its relations" in warning[0] and "Traceback" not in err


@pytest.mark.parametrize("world, words", [
    ({"walls": "[[0, 0, 1, 0]]"}, ["fmcwlog.world", "'features'"]),
    ({"features": "[]"}, ["fmcwlog.world", "'walls'"]),
    ({"features": '[{"id": 1, "name": "x", "a": [0, 0]}]', "walls": "[]"}, ["features[0]", "a and b"]),
    ({"features": '[{"id": 1, "name": "x", "a": [0, 0], "b": [1, NaN]}]', "walls": "[]"}, ["features[0].b", "finite"]),
    ({"features": "[{", "walls": "[]"}, ["fmcwlog.world", "not JSON"]),
    ({"features": "[]", "walls": "[[0, 0, 1]]"}, ["walls", "shape"]),
    # once a traceback (ValueError: true lengths must be positive) from the feature errors
    ({"features": '[{"id": 1, "name": "x", "a": [2, 3], "b": [2, 3]}]', "walls": "[]"}, ["features[0]", "same point"]),
])
def test_world_record_that_breaks_the_format(tmp_path, world, words):
    log = _short_log(tmp_path / "w.mcap", drop_metadata=("fmcwlog.world",), extra_metadata={"fmcwlog.world": world})
    _report_fails(_process(log, tmp_path / "out"), "w.mcap", *words)


def _stamps(log: Path) -> list[int]:
    return [m.log_time for _, _, m, _ in decoded(log, ["/fmcw/points"])]


def test_a_log_of_another_seed_with_the_same_stamps_is_refused_naming_both(tmp_path):
    logs = {}
    for seed in (0, 1):
        logs[seed] = tmp_path / f"seed{seed}.mcap"
        code, _, err = run_cli_here("-q", "record", "--duration", "1.5", "--seed", str(seed), "-o", str(logs[seed]))
        assert code == 0, err
    assert _stamps(logs[0]) == _stamps(logs[1]) and logs[0].read_bytes() != logs[1].read_bytes()
    out = _process(logs[0], tmp_path / "out")
    _report_fails(out, "seed1.mcap", "seed0.mcap", "sha256", args=("--log", str(logs[1])))

    shutil.copy(logs[1], logs[0])  # the log named in run.json, recorded over since
    _report_fails(out, "seed0.mcap", "sha256")

    shutil.copy(logs[1], tmp_path / "moved.mcap")  # the right bytes under another name are the right log
    code, _, err = run_cli_here("-q", "process", str(logs[1]), "-o", str(out), "--force")
    assert code == 0, err
    code, _, err = run_cli_here("-q", "report", str(out), "--log", str(tmp_path / "moved.mcap"))
    assert code == 0, err
    assert "report.html" in json.loads((out / MARKER).read_text())["entries"]


def _edit_odom(change):
    def edit(topic, i, msg):
        if topic == "/ground_truth/odom" and i < 40:  # ground truth is 50 Hz: the first 8 sweeps' span
            return change(i, msg)
        return False if i >= (8 if topic == "/fmcw/points" else 40) else None
    return edit


def _nan(i, msg):
    if i == 3:
        msg.pose.pose.position.x = float("nan")


def _repeat(i, msg):
    if i == 1:
        msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000, 0  # the first message's stamp


def _zero_quaternion(i, msg):
    q = msg.pose.pose.orientation
    q.x = q.y = q.z = q.w = 0.0


@pytest.mark.parametrize("change, words", [
    (_nan, ["message 4 at 1700000000.060000000 s", "pose is not finite"]),  # was: LinAlgError: SVD did not converge
    (_repeat, ["message 2", "stamp does not increase"]),  # was: ValueError: t_ref must hold ... increasing stamps
    (_zero_quaternion, ["message 1", "zero quaternion"]),  # was: scored, the truth's heading taken as 0
])
def test_damaged_ground_truth_is_one_line_naming_the_message(tmp_path, change, words):
    log = tmp_path / "g.mcap"
    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", log, edit=_edit_odom(change))
    _report_fails(_process(log, tmp_path / "out"), "g.mcap", "/ground_truth/odom", *words)


def test_ground_truth_of_another_time_span_leaves_the_errors_empty_with_the_reason(tmp_path):
    """The ground truth 100 s after the scans (a clock offset): a traceback once ('no estimate stamp inside
    the reference's time span'); now the report is written, the errors empty, the reason beside them."""
    def shift(i, msg):
        msg.header.stamp.sec += 100
    log = tmp_path / "g.mcap"
    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", log, edit=_edit_odom(shift))
    out = _process(log, tmp_path / "out")
    code, _, err = run_cli_here("-q", "report", str(out))
    assert code == 0, err
    improved = json.loads((out / "report.json").read_text())["methods"]["improved"]
    assert improved["ate_rmse_m"] is None
    assert any("no pose falls within the ground truth's time span" in n for n in improved["notes"]), improved["notes"]


def test_point_labels_that_do_not_fit_the_sweeps_are_said_not_blamed_on_doppler(tmp_path):
    """Labels cut to 10 per sweep: the note blamed Doppler ('Doppler was off'), which was on."""
    def cut(topic, i, msg):
        if topic == "/ground_truth/point_labels":
            msg.moving = bytes(msg.moving)[:10]
        return False if i >= (8 if topic in ("/fmcw/points", "/ground_truth/point_labels") else 40) else None
    log = tmp_path / "l.mcap"
    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", log, edit=cut)
    out = _process(log, tmp_path / "out")
    code, _, err = run_cli_here("-q", "report", str(out))
    assert code == 0, err
    notes = json.loads((out / "report.json").read_text())["methods"]["improved"]["notes"]
    assert "8 of 8 sweeps not scored for segmentation: 0 without a /ground_truth/point_labels message at their " \
           "stamp, 8 whose labels are not one per point" in notes, notes
    assert not [n for n in notes if "Doppler was off" in n], notes
