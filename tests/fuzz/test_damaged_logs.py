"""Damaged and impossible logs: each ends in one clear error line or is processed with a counted warning.

Logs are damaged here byte by byte (cut off, bits flipped) or re-encoded with impossible fields by
plain ``mcap`` / ``mcap_ros2`` (``helpers.copy_log``), never through fmcwlog's writer. What survives is
judged against the intact log processed the same way and against the container's own index read by
``mcap``'s reader: a cut keeps the sweeps before it, a skipped chunk costs exactly its own sweeps.
The command line runs in this process (``helpers.run_cli_here``: an exception that escapes it is the
traceback a user would see), which keeps the fuzz tests at about a second a case; one case also runs
as ``python -m fmcwlog``.
"""

from __future__ import annotations

import io
import json
import math
import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest
from helpers import copy_log, run_cli, run_cli_here, shared_file
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from fmcwlog.api import SimConfig, record, scenario
from fmcwlog.sim.config import apply_overrides

pytestmark = pytest.mark.slow  # end to end: damaged logs processed through the command line

TRAJECTORIES = ("improved.tum", "baseline.tum", "wheel_odometry.tum")
FUZZ = settings(max_examples=15, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


def cli(*args: str) -> tuple[int, str]:
    """The exit status and stderr of ``fmcwlog ARGS`` run in this process."""
    code, _, err = run_cli_here(*args)
    return code, err


# ----------------------------------------------------------------------------- the command line, judged


def _no_leftovers(out: Path) -> None:
    assert not [p for p in out.parent.iterdir() if ".partial" in p.name], list(out.parent.iterdir())


def judged(code: int, err: str, log: Path, out: Path) -> dict[str, str] | None:
    """The contract for any input: exit 0 with only warnings and complete outputs, or exit 2 with one
    line ``fmcwlog: error: ...`` naming the log and nothing left behind. The estimates, or None."""
    lines = [x for x in err.splitlines() if x.strip()]
    assert code in (0, 2), err
    _no_leftovers(out)
    if code == 2:
        assert len(lines) == 1 and lines[0].startswith("fmcwlog: error: "), err
        assert str(log) in lines[0], lines[0]
        assert not out.exists()
        return None
    assert all(x.startswith("fmcwlog: warning: ") for x in lines), err
    assert json.loads((out / "run.json").read_text())["sweeps"] > 0
    return {name: (out / name).read_text() for name in TRAJECTORIES if (out / name).exists()}


def process(log: Path, out: Path, method: str = "all") -> tuple[dict[str, str] | None, list[str]]:
    """Process through the CLI and judge it; the estimates (None on an error) and the warning lines."""
    code, err = cli("process", str(log), "-o", str(out), "--method", method)
    est = judged(code, err, log, out)
    return est, [x[len("fmcwlog: warning: "):] for x in err.splitlines() if x.startswith("fmcwlog: warning: ")]


def stamp_ns_of(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def stamps(est: dict[str, str], name: str = "wheel_odometry.tum") -> list[str]:
    return [line.split()[0] for line in est[name].splitlines()]


# ----------------------------------------------------------------------------- logs


def rewrite(src: Path, dst: Path, compression: str = "zstd", chunk_size: int = 64 * 1024,
            chunking: bool = True, metadata=None, data=None) -> Path:
    """The same records re-containered by plain ``mcap``: small chunks (several per log), a compression;
    ``metadata(records)`` may replace the list of (name, values) metadata records and
    ``data(topic, index, bytes)`` a message's bytes."""
    counts: dict[str, int] = {}
    with open(src, "rb") as fh:
        reader = make_reader(fh)
        meta = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        with open(dst, "wb") as out:
            w = McapWriter(out, chunk_size=chunk_size, compression=CompressionType[compression.upper() or "NONE"],
                           use_chunking=chunking)
            w.start(profile="ros2", library="test rewrite")
            for name, values in metadata(meta) if metadata else meta:
                w.add_metadata(name, values)
            schemas: dict[int, int] = {}
            channels: dict[int, int] = {}
            for schema, channel, message in reader.iter_messages(log_time_order=False):
                if schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
                if channel.id not in channels:
                    channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                              schemas[schema.id], channel.metadata)
                i = counts[channel.topic] = counts.get(channel.topic, -1) + 1
                w.add_message(channels[channel.id], message.log_time,
                              data(channel.topic, i, message.data) if data else message.data,
                              message.publish_time, message.sequence)
            w.finish()
    return dst


def chunk_spans(log: Path) -> list[tuple[int, int, int, int]]:
    """(offset, length, first and last log_time) of each chunk, from the summary by ``mcap``'s reader."""
    with open(log, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    return sorted((c.chunk_start_offset, c.chunk_length, c.message_start_time, c.message_end_time)
                  for c in summary.chunk_indexes)


def metadata_spans(log: Path) -> list[tuple[int, int]]:
    with open(log, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    return [(m.offset, m.offset + m.length) for m in summary.metadata_indexes]


@pytest.fixture(scope="module")
def short_logs(tmp_path_factory) -> dict[str, Path]:
    """3 s of the corridor (30 sweeps) recorded once, re-containered four ways: zstd, lz4 and
    uncompressed chunks of 64 KiB (about 15 chunks), and no chunks at all."""
    tmp = tmp_path_factory.mktemp("short")
    src = tmp / "recorded.mcap"
    record(scenario("corridor"), apply_overrides(SimConfig(), {"run": {"duration": 3.0}}), src)
    return {"zstd": rewrite(src, tmp / "zstd.mcap"), "lz4": rewrite(src, tmp / "lz4.mcap", "lz4"),
            "none": rewrite(src, tmp / "none.mcap", ""), "unchunked": rewrite(src, tmp / "unchunked.mcap", "", chunking=False)}


@pytest.fixture(scope="module")
def intact(short_logs, tmp_path_factory) -> dict[str, dict[str, str]]:
    """Each short log processed as it is."""
    out = {}
    for kind, log in short_logs.items():
        est, warnings = process(log, tmp_path_factory.mktemp(f"intact-{kind}") / "out")
        assert est is not None and not warnings, warnings
        out[kind] = est
    return out


def test_the_four_containers_give_the_same_estimates(intact):
    assert intact["zstd"] == intact["lz4"] == intact["none"] == intact["unchunked"]
    assert len(stamps(intact["zstd"])) == 30


def cut(log: Path, at: int, tmp: Path) -> Path:
    dst = tmp / f"cut{at}.mcap"
    dst.write_bytes(log.read_bytes()[:at])
    return dst


def flip(log: Path, flips: list[tuple[int, int]], tmp: Path, name: str = "flipped.mcap") -> Path:
    data = bytearray(log.read_bytes())
    for at, mask in flips:
        data[at % len(data)] ^= mask
    dst = tmp / name
    dst.write_bytes(bytes(data))
    return dst


# ----------------------------------------------------------------------------- the container: named cases


@pytest.mark.parametrize("at, words", [(0, "empty"), (5, "inside its magic bytes"), (8, "nothing readable"),
                                       (30, "inside the header record at byte 8")])
def test_a_log_cut_in_its_header_is_one_clear_error(short_logs, tmp_path, at, words):
    log = cut(short_logs["zstd"], at, tmp_path)
    code, err = cli("process", str(log), "-o", str(tmp_path / "out"))
    judged(code, err, log, tmp_path / "out")
    assert code == 2 and words in err, err


def test_a_cut_keeps_every_sweep_before_it(short_logs, intact, tmp_path):
    """Cut inside the third chunk's header fields, then inside its compressed data: the sweeps of the
    first two chunks (and of the cut chunk's whole blocks) are processed, with one warning naming the cut."""
    log = short_logs["zstd"]
    spans = chunk_spans(log)
    third = spans[2][0]
    full = stamps(intact["zstd"])
    before = sum(1 for t in full if float(t) * 1e9 < spans[2][2])  # the sweeps of the first two chunks
    for at in (third + 20, third + spans[2][1] // 2):
        est, warnings = process(cut(log, at, tmp_path), tmp_path / f"out{at}", "baseline")
        assert est is not None and len(warnings) == 1 and f"at byte {at}" in warnings[0], warnings
        got = stamps(est)
        assert before <= len(got) < len(full) and got == full[: len(got)]


@pytest.mark.parametrize("back", [1, 5, 20, 60])
def test_a_cut_in_the_summary_or_footer_loses_nothing(short_logs, intact, tmp_path, back):
    log = short_logs["zstd"]
    size = log.stat().st_size
    est, warnings = process(cut(log, size - back, tmp_path), tmp_path / "out")
    assert est == intact["zstd"]
    assert len(warnings) == 1 and f"byte {size - back}" in warnings[0], warnings


@pytest.mark.parametrize("kind", ["zstd", "lz4", "none"])
def test_a_damaged_middle_chunk_is_skipped_and_later_chunks_are_read(short_logs, intact, tmp_path, kind):
    """A flipped byte in the compressed data (zstd, lz4) or the records (CRC) of the fourth chunk: that
    chunk's sweeps are lost, those of every other chunk are processed, one warning names its offset
    (and the gap the lost sweeps leave is reported as a gap, bridged)."""
    log = short_logs[kind]
    offset, length, t0, t1 = chunk_spans(log)[3]
    est, warnings = process(flip(log, [(offset + length // 2, 0x20)], tmp_path), tmp_path / "out", "baseline")
    damage = [w for w in warnings if "gap" not in w]
    assert est is not None and len(damage) == 1 and f"damaged at byte {offset}" in damage[0], warnings
    assert len(warnings) - len(damage) <= 1 and all("bridged" in w for w in warnings if w not in damage), warnings
    full, got = stamps(intact[kind]), stamps(est)
    lost = [t for t in full if t not in got]
    assert lost and got[-1] == full[-1] and got == [t for t in full if t not in lost]
    # exactly the sweeps stamped within the damaged chunk's span are lost (mcap's own index says which)
    assert lost == [t for t in full if t0 <= round(float(t) * 1e9, -3) <= t1], (lost, t0, t1)


def test_a_damaged_chunk_length_field_costs_nothing_where_the_index_frames_it(short_logs, intact, tmp_path):
    log = short_logs["zstd"]
    offset = chunk_spans(log)[2][0]
    est, warnings = process(flip(log, [(offset + 3, 0x01)], tmp_path), tmp_path / "out")
    assert est == intact["zstd"] and len(warnings) == 1 and "length field" in warnings[0], warnings


def test_a_damaged_summary_costs_only_the_index(short_logs, intact, tmp_path):
    log = short_logs["zstd"]
    size = log.stat().st_size
    est, warnings = process(flip(log, [(size - 300, 0x04)], tmp_path), tmp_path / "out")
    assert est == intact["zstd"] and len(warnings) == 1 and "summary" in warnings[0], warnings


def test_a_damaged_calibration_record_is_named_in_the_error(short_logs, tmp_path):
    log = short_logs["zstd"]
    start = next(a for a, b in metadata_spans(log) if b - a < 600)  # the calibration record
    damaged = flip(log, [(start + 12, 0x40)], tmp_path)  # its name's length: the record no longer frames
    code, err = cli("process", str(damaged), "-o", str(tmp_path / "out"))
    judged(code, err, damaged, tmp_path / "out")
    assert code == 2 and "calibration" in err and f"at byte {start}" in err, err


def test_an_undecodable_message_is_skipped_and_counted(short_logs, intact, tmp_path):
    log = rewrite(short_logs["zstd"], tmp_path / "cdr.mcap",
                  data=lambda topic, i, data: data[:40] if topic == "/fmcw/points" and i == 7 else data)
    est, warnings = process(log, tmp_path / "out", "baseline")
    full = stamps(intact["zstd"])
    assert stamps(est) == full[:7] + full[8:]
    assert [w for w in warnings if w.startswith("skipped 1 messages on /fmcw/points that do not decode")], warnings


def test_a_pipe_named_like_a_log_is_one_line_saying_what_it_is(tmp_path):
    """A FIFO named ``log.mcap`` exists, yet the line once said 'no such file'."""
    import os

    fifo = tmp_path / "log.mcap"
    os.mkfifo(fifo)
    code, err = cli("process", str(fifo), "-o", str(tmp_path / "out"))
    judged(code, err, fifo, tmp_path / "out")
    assert code == 2 and "not a regular file" in err, err


@pytest.mark.parametrize("option, topic, words", [
    ("--odom-topic", "/wheel/ticks", "/wheel/ticks is fmcwlog_msgs/msg/WheelTicks, not a nav_msgs/msg/Odometry"),
    ("--ticks-topic", "/fmcw/points", "/fmcw/points is sensor_msgs/msg/PointCloud2, not a fmcwlog_msgs/msg/WheelTicks"),
    ("--odom-topic", "/ground_truth/odom", "/ground_truth/odom is ground truth, which estimation never reads"),
])
def test_a_motion_prior_topic_of_the_wrong_type_or_ground_truth_is_one_line(short_logs, tmp_path, option, topic, words):
    """``--odom-topic /wheel/ticks`` was a traceback (AttributeError: no 'pose'); ``--ticks-topic /fmcw/points``
    said 'no usable message'; ``--odom-topic /ground_truth/odom`` processed with the truth as the prior."""
    log = short_logs["zstd"]
    code, err = cli("process", str(log), "-o", str(tmp_path / "out"), option, topic)
    judged(code, err, log, tmp_path / "out")
    assert code == 2 and words in err, err


def test_a_topic_whose_schema_is_not_ros2msg_is_one_line_saying_so(short_logs, tmp_path):
    """A 'ros2idl' schema once gave 'is encoded as 'cdr', expected 'cdr'' (the message encoding named,
    not the schema's that was at fault)."""
    log = tmp_path / "idl.mcap"
    with open(short_logs["zstd"], "rb") as fh, open(log, "wb") as out:
        reader = make_reader(fh)
        w = McapWriter(out)
        w.start(profile="ros2", library="test")
        for m in reader.iter_metadata():
            w.add_metadata(m.name, dict(m.metadata))
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if schema.id not in schemas:
                schemas[schema.id] = w.register_schema(schema.name, "ros2idl", schema.data)
            if channel.id not in channels:
                channels[channel.id] = w.register_channel(channel.topic, "cdr", schemas[schema.id])
            w.add_message(channels[channel.id], message.log_time, message.data, message.publish_time)
        w.finish()
    code, err = cli("process", str(log), "-o", str(tmp_path / "out"))
    judged(code, err, log, tmp_path / "out")
    assert code == 2 and "as 'ros2idl', expected 'ros2msg'" in err, err


def test_the_real_entry_point_gives_one_line_for_a_damaged_log(short_logs, tmp_path):
    log = cut(short_logs["zstd"], 8 + 4, tmp_path)
    proc = run_cli("process", str(log), "-o", str(tmp_path / "out"))
    assert judged(proc.returncode, proc.stderr, log, tmp_path / "out") is None and "Traceback" not in proc.stderr


# ----------------------------------------------------------------------------- messages: named cases


def edited(short_logs, tmp: Path, edit, name: str = "edited.mcap", **kw) -> Path:
    dst = tmp / name
    copy_log(short_logs["zstd"], dst, edit=edit, **kw)
    return dst


def _cloud(i_bad: set[int], change):
    def edit(topic, i, msg):
        if topic == "/fmcw/points" and i in i_bad:
            change(msg)
    return edit


def _set_floats(field: str, value: float):
    """Write ``value`` into ``field`` of the first point of the cloud."""
    def change(msg):
        f = next(f for f in msg.fields if f.name == field)
        data = bytearray(msg.data)
        data[f.offset:f.offset + 4] = np.float32(value).tobytes()
        msg.data = bytes(data)
    return change


def _attr(**values):
    def change(msg):
        for k, v in values.items():
            setattr(msg, k, v)
    return change


def _field_offset(name: str, offset: int):
    def change(msg):
        next(f for f in msg.fields if f.name == name).offset = offset
    return change


# sweep index -> (what is made impossible, the kind run.json counts, words of its warning)
_IMPOSSIBLE = {
    1: (_attr(point_step=0), "layout", "point_step 0"),
    3: (_attr(point_step=12), "layout", "smaller than its fields"),
    5: (_field_offset("y", 2), "layout", "overlap"),
    7: (_field_offset("t", 40), "layout", "smaller than its fields"),
    9: (_attr(width=100_000), "layout", "data holds"),
    11: (_attr(is_bigendian=True), "layout", "big-endian"),
    13: (_set_floats("t", -0.5), "times", "outside [0, 0.1 s]"),
    15: (_set_floats("t", 1e6), "times", "outside [0, 0.1 s]"),
    17: (_set_floats("x", 1e9), "range", "farther than 60 m"),
    19: (_set_floats("t", np.nan), "nonfinite", "NaN or infinite"),  # a NaN x, y or velocity is a no-return
    21: (_set_floats("velocity", 1e30), "velocity", "beyond ±200 m/s"),
    23: (_attr(width=0, row_step=0, data=b""), "empty", "no points"),
}


def test_impossible_sweeps_are_skipped_and_counted_by_kind(short_logs, intact, tmp_path):
    """Twelve of 30 sweeps made impossible, each its own way: the other 18 are processed, run.json
    counts each kind, one warning per kind gives its count and the first case."""
    def edit(topic, i, msg):
        if topic == "/fmcw/points" and i in _IMPOSSIBLE:
            _IMPOSSIBLE[i][0](msg)
    est, warnings = process(edited(short_logs, tmp_path, edit), tmp_path / "out", "baseline")
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    kinds = [kind for _, kind, _ in _IMPOSSIBLE.values()]
    assert run["skipped_inputs"] == {k: kinds.count(k) for k in kinds} and run["sweeps"] == 18
    for kind in set(kinds):  # its warning gives the count and the first case
        words = _IMPOSSIBLE[min(i for i, (_, k, _) in _IMPOSSIBLE.items() if k == kind)][2]
        assert [w for w in warnings if w.startswith(f"skipped {kinds.count(kind)} sweeps on /fmcw/points")
                and words in w], (kind, warnings)
    full = stamps(intact["zstd"])
    assert stamps(est) == [t for i, t in enumerate(full) if i not in _IMPOSSIBLE]


def test_a_log_whose_every_sweep_is_impossible_is_one_error_saying_why(short_logs, tmp_path):
    log = edited(short_logs, tmp_path, _cloud(set(range(30)), _attr(point_step=4)))
    code, err = cli("process", str(log), "-o", str(tmp_path / "out"))
    judged(code, err, log, tmp_path / "out")
    assert code == 2 and "no usable sweep on /fmcw/points" in err and "30 layout" in err and "point_step 4" in err


def _ticks(change):
    def edit(topic, i, msg):
        if topic == "/wheel/ticks":
            change(i, msg)
    return edit


def test_a_32_bit_tick_counter_wrap_is_unwrapped(short_logs, intact, tmp_path):
    """Counts read by a 32-bit counter that wraps at message 100: the estimates equal the intact log's."""
    def wrap(i, msg):
        if i >= 100:
            msg.left -= 2**32
            msg.right -= 2**32
    est, warnings = process(edited(short_logs, tmp_path, _ticks(wrap)), tmp_path / "out")
    assert est == intact["zstd"]
    assert warnings == ["unwrapped 2 32-bit wheel-tick counter wraps on /wheel/ticks"], warnings


def test_counters_that_start_near_the_int64_limit_give_the_intact_estimates(short_logs, intact, tmp_path):
    """Counts offset by 2**62: the estimates equal the intact log's (the prior holds counts from the
    first reading on). Offset by 2**63 - 1000, the counter overflows to -2**63 and is a reset: once,
    the rebased counts passed int64 and numpy's 'invalid value encountered in cast' reached the user
    as warnings."""
    def start_at(base):
        def shift(i, msg):
            msg.left = (msg.left + base + 2**63) % 2**64 - 2**63
            msg.right = (msg.right + base + 2**63) % 2**64 - 2**63
        return _ticks(shift)

    est, warnings = process(edited(short_logs, tmp_path, start_at(2**62), "big.mcap"), tmp_path / "big")
    assert est == intact["zstd"] and not warnings, warnings
    est, warnings = process(edited(short_logs, tmp_path, start_at(2**63 - 1000), "over.mcap"), tmp_path / "over")
    assert est is not None and not [w for w in warnings if "encountered" in w], warnings
    assert any("taken as a new origin" in w for w in warnings), warnings


def test_a_lone_tick_jump_is_skipped_and_a_counter_reset_is_a_new_origin(short_logs, intact, tmp_path):
    def jump(i, msg):
        if i == 60:
            msg.left += 2_000_000_000  # a wheel of 0.1 m would roll 300 km in 20 ms
    est, warnings = process(edited(short_logs, tmp_path, _ticks(jump), "jump.mcap"), tmp_path / "jump", "baseline")
    assert any(w.startswith("skipped 1 wheel-tick messages on /wheel/ticks whose counts jump") for w in warnings)
    _close_to(est, intact["zstd"], 0.01)

    def reset(i, msg):
        if i >= 120:
            msg.left, msg.right = msg.left - 5_000_000, msg.right - 5_000_000
    est, warnings = process(edited(short_logs, tmp_path, _ticks(reset), "reset.mcap"), tmp_path / "reset", "baseline")
    assert any("taken as a new origin" in w for w in warnings), warnings
    _close_to(est, intact["zstd"], 0.05)


def _close_to(est: dict[str, str], ref: dict[str, str], tol: float, name: str = "baseline.tum") -> None:
    a = np.loadtxt(io.StringIO(est[name]))
    b = np.loadtxt(io.StringIO(ref[name]))
    assert a.shape == b.shape and np.max(np.hypot(*(a[:, 1:3] - b[:, 1:3]).T)) < tol


@pytest.mark.parametrize("shift_s", [86_400, -86_400])
def test_a_motion_prior_a_day_from_the_scans_is_refused_naming_both_clocks(short_logs, tmp_path, shift_s):
    def shift(i, msg):
        msg.header.stamp.sec += shift_s
    log = edited(short_logs, tmp_path, _ticks(shift))
    code, err = cli("process", str(log), "-o", str(tmp_path / "out"))
    judged(code, err, log, tmp_path / "out")
    assert code == 2 and "clocks of /fmcw/points and /wheel/ticks are 8640" in err, err


def test_a_lone_stamp_a_day_ahead_is_skipped_and_a_gap_the_next_message_confirms_is_kept(short_logs, intact,
                                                                                        tmp_path):
    def ahead(topic, i, msg):
        if (topic, i) in (("/fmcw/points", 12), ("/wheel/ticks", 40)):
            msg.header.stamp.sec += 86_400
    est, warnings = process(edited(short_logs, tmp_path, ahead, "ahead.mcap"), tmp_path / "ahead", "baseline")
    run = json.loads((tmp_path / "ahead" / "run.json").read_text())
    assert run["skipped_inputs"] == {"stamp_jump": 1, "prior_stamp_jump": 1}, run["skipped_inputs"]
    full = stamps(intact["zstd"])
    assert stamps(est) == full[:12] + full[13:]
    assert [w for w in warnings if w.startswith("skipped 1 messages on /fmcw/points whose stamps jump")], warnings

    def paused(topic, i, msg):  # the recording paused for 100 s after sweep 15 (and tick 75)
        if (topic == "/fmcw/points" and i >= 15) or (topic == "/wheel/ticks" and i >= 75):
            msg.header.stamp.sec += 100
    est, warnings = process(edited(short_logs, tmp_path, paused, "paused.mcap"), tmp_path / "paused", "baseline")
    assert len(stamps(est)) == 30 and not [w for w in warnings if "skipped" in w], warnings


def test_sweeps_wait_for_a_motion_prior_that_stopped_at_most_the_clock_gap(short_logs, tmp_path, monkeypatch):
    """Ticks stop after 1 s of 3: the later sweeps are processed with the prior held at its last pose
    once they have waited the gap (0.5 s here, 60 s by default), not all at the end of the log, and
    the estimates are those of waiting to the end."""
    import fmcwlog.pipeline.runner as runner

    log = edited(short_logs, tmp_path, lambda topic, i, msg: False if topic == "/wheel/ticks" and i >= 50 else None)
    waited, warnings = process(log, tmp_path / "waited", "baseline")
    held = "20 sweeps on /fmcw/points began after the last message on /wheel/ticks"  # sweeps 10 to 29
    assert [w for w in warnings if w.startswith(held)], warnings
    queued: list[int] = []
    ready = runner.LogRunner._ready

    def watched(self, sweep):
        queued.append(len(self._pending))
        return ready(self, sweep)

    monkeypatch.setattr(runner.LogRunner, "_ready", watched)
    process(log, tmp_path / "unbounded", "baseline")
    assert max(queued) == 20  # every sweep after the ticks stop waits to the end
    queued.clear()
    monkeypatch.setattr(runner, "MAX_CLOCK_GAP_S", 0.5)
    est, warnings = process(log, tmp_path / "out", "baseline")
    assert max(queued) <= 7  # 0.5 s of sweeps at 10 Hz, and the one that arrived
    assert [w for w in warnings if w.startswith(held)], warnings
    assert est == waited and len(stamps(est)) == 30


def test_sweeps_before_the_first_prior_message_are_counted(short_logs, tmp_path):
    """Ticks start 1 s into the log (or their clock is a few seconds off): the sweeps before the first
    tick were once processed silently with the prior held; now one warning counts them."""
    from helpers import decoded

    log = edited(short_logs, tmp_path, lambda topic, i, msg: False if topic == "/wheel/ticks" and i < 50 else None)
    first_tick = min(stamp_ns_of(m) for _, _, _, m in decoded(log, ["/wheel/ticks"]))
    before = sum(stamp_ns_of(m) < first_tick for _, _, _, m in decoded(log, ["/fmcw/points"]))
    assert before == 10
    _, warnings = process(log, tmp_path / "out", "baseline")
    said = f"{before} sweeps on /fmcw/points began before the first message on /wheel/ticks"
    assert [w for w in warnings if w.startswith(said)], warnings


def test_a_cloud_without_point_times_gets_the_priors_motion_over_its_window(short_logs, tmp_path):
    """A cloud with no ``t`` field (all points at the stamp) was processed as soon as the ticks reached
    its stamp, so the prior over its 1 ms window was extrapolated to standstill and gated the Doppler
    fit: the improved method's speed was 0 on 51 of 60 sweeps of a 6 s log. Now its speed follows the
    simulator's true speed (measured within 0.013 m/s)."""
    import pandas as pd
    from helpers import decoded

    def drop_t(msg):
        keep = [f for f in msg.fields if f.name != "t"]
        cols = np.frombuffer(bytes(msg.data), "<f4").reshape(-1, len(msg.fields))
        msg.data = np.ascontiguousarray(cols[:, [msg.fields.index(f) for f in keep]]).tobytes()
        for k, f in enumerate(keep):
            f.offset = 4 * k
        msg.fields, msg.point_step = keep, 4 * len(keep)
        msg.row_step = msg.point_step * msg.width

    log = edited(short_logs, tmp_path, _cloud(set(range(30)), drop_t))
    est, warnings = process(log, tmp_path / "out", "improved")
    untimed = "30 sweeps on /fmcw/points have no field 't'"  # said (test_contract); nothing else is
    assert est is not None and [w for w in warnings if not w.startswith(untimed)] == [] and len(warnings) == 1, warnings
    truth = np.array([(m.log_time * 1e-9, msg.twist.twist.linear.x) for _, _, m, msg in decoded(log, ["/ground_truth/odom"])])
    rows = pd.read_parquet(tmp_path / "out" / "trajectories.parquet").query("method == 'improved'")
    assert len(rows) == 30
    true_v = np.interp(rows.t.to_numpy(), truth[:, 0], truth[:, 1])
    assert np.max(np.abs(rows.v.to_numpy() - true_v)) < 0.05


# ----------------------------------------------------------------------------- LaserScan and Odometry


def _room_ranges(x: float, y: float, angles: np.ndarray) -> np.ndarray:
    """Ranges from (x, y) along ``angles`` to the walls of the room [-5, 5] × [-4, 4] m."""
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (5 - x) / c, np.where(c < 0, (-5 - x) / c, np.inf))
        ty = np.where(s > 0, (4 - y) / s, np.where(s < 0, (-4 - y) / s, np.inf))
    return np.minimum(tx, ty)


@pytest.fixture(scope="module")
def laser_log(tmp_path_factory) -> Path:
    """A CARMEN log written here (a robot at 0.2 m/s along a 10 m × 8 m room, 30 scans of 180 beams, the
    odometry pose on each line), imported: LaserScan on /scan, Odometry on /odom."""
    tmp = tmp_path_factory.mktemp("laser")
    angles = -np.pi / 2 + np.arange(180) * np.pi / 180
    lines = []
    for k in range(30):
        x, t = -1.0 + 0.02 * k, 100.0 + 0.1 * k
        r = " ".join(f"{v:.3f}" for v in _room_ranges(x, 0.0, angles))
        lines.append(f"FLASER 180 {r} {x:.3f} 0 0 {x:.3f} 0 0 {t:.3f} host {t:.3f}")
    clf = tmp / "room.clf"
    clf.write_text("\n".join(lines) + "\n")
    log = tmp / "room.mcap"
    assert cli("import", "carmen", str(clf), "-o", str(log))[0] == 0
    return log


def _odom_x(value):
    def change(msg):
        msg.pose.pose.position.x = value
    return change


def test_impossible_laserscans_and_odometry_poses_are_skipped_and_counted(laser_log, tmp_path):
    intact, _ = process(laser_log, tmp_path / "intact", "baseline")
    scans = {3: _attr(angle_increment=0.0), 7: _attr(angle_min=math.nan), 11: _attr(angle_max=3.0),
             15: _attr(ranges=[math.inf] * 180)}
    poses = {5: _odom_x(math.nan), 12: _odom_x(1e12), 20: _odom_x(500.0)}

    def edit(topic, i, msg):
        change = (scans if topic == "/scan" else poses if topic == "/odom" else {}).get(i)
        if change is not None:
            change(msg)
    log = tmp_path / "edited.mcap"
    copy_log(laser_log, log, edit=edit)
    est, warnings = process(log, tmp_path / "out", "baseline")
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run["skipped_inputs"] == {"angles": 3, "empty": 1, "odom_invalid": 2, "odom_jump": 1}
    for words in ("skipped 3 sweeps on /scan whose beam angles are unusable (first: at 100.300 s: angle_min -1.5",
                  "skipped 1 sweeps on /scan with no points",
                  "skipped 2 odometry messages on /odom with a NaN, infinite or absurd pose",
                  "skipped 1 odometry messages on /odom whose pose jumps farther than 100 m/s allows"):
        assert [w for w in warnings if w.startswith(words)], (words, warnings)
    assert stamps(est) == [t for i, t in enumerate(stamps(intact)) if i not in scans]


# ----------------------------------------------------------------------------- calibration


def _calibration(short_logs, tmp, second: dict[str, str] | None = None, **changes: str) -> Path:
    """The log with its calibration record changed, and a ``second`` record's changes after it."""
    def meta(records):
        out = []
        for name, values in records:
            if name == "fmcwlog.calibration":
                out.append((name, {**values, **changes}))
                if second is not None:
                    out.append((name, {**values, **changes, **second}))
            else:
                out.append((name, values))
        return out
    return rewrite(short_logs["zstd"], tmp / "cal.mcap", metadata=meta)


@pytest.mark.parametrize("key, value, words", [
    ("lidar_x", "1e9", "'lidar_x' = 1e9 m is outside its valid range [-10, 10] m"),
    ("wheel_radius_left", "10", "[0.005, 2] m"),
    ("wheel_radius_right", "1e-9", "[0.005, 2] m"),
    ("ticks_per_revolution", "0", "'ticks_per_revolution' = 0 is outside its valid range [1, 1e+08]"),
    ("ticks_per_revolution", "4096.5", "not a whole number"),
    ("track_width", "nan", "not finite"),
    ("scan_rate", "-10", "'scan_rate'"),
])
def test_a_calibration_value_out_of_physical_range_is_refused_naming_key_and_range(short_logs, tmp_path, key,
                                                                                    value, words):
    log = _calibration(short_logs, tmp_path, **{key: value})
    code, err = cli("process", str(log), "-o", str(tmp_path / "out"))
    judged(code, err, log, tmp_path / "out")
    assert code == 2 and words in err, err


def test_a_calibration_without_lidar_x_is_warned_of_and_taken_as_0(short_logs, tmp_path):
    """A record with the wheels but no ``lidar_x`` once went silently with the LiDAR over the axle (the
    log's is 0.35 m ahead). Now one warning names the key; the estimates are those of a record saying 0."""
    def drop(records):
        return [(n, {k: v for k, v in values.items() if k != "lidar_x"} if n == "fmcwlog.calibration" else values)
                for n, values in records]
    log = rewrite(short_logs["zstd"], tmp_path / "no_x.mcap", metadata=drop)
    est, warnings = process(log, tmp_path / "out", "baseline")
    said = f"{log}: fmcwlog.calibration has no lidar_x: taken as 0"
    assert [w for w in warnings if w.startswith(said)], warnings
    zero = _calibration(short_logs, tmp_path, lidar_x="0")
    assert est == process(zero, tmp_path / "zero", "baseline")[0]


def test_two_calibration_records_that_disagree_are_refused_naming_the_keys(short_logs, tmp_path):
    log = _calibration(short_logs, tmp_path, second={"wheel_radius_left": "0.12", "lidar_x": "0.4"})
    code, err = cli("process", str(log), "-o", str(tmp_path / "out"))
    judged(code, err, log, tmp_path / "out")
    assert code == 2 and "disagree on lidar_x (0.35 against 0.4), wheel_radius_left (0.1 against 0.12)" in err, err


def test_identical_calibration_records_are_one_with_a_note(short_logs, intact, tmp_path):
    log = _calibration(short_logs, tmp_path, second={"lidar_x": "0.350"})  # the same number, written otherwise
    est, warnings = process(log, tmp_path / "out")
    assert est == intact["zstd"] and warnings == [f"{log}: 2 identical fmcwlog.calibration records; used them as one"]


# ----------------------------------------------------------------------------- fuzz
# Each case runs one front end (drawn), so a case costs about a second; both are covered across cases.

METHODS = st.sampled_from(["improved", "baseline"])


def _fuzz_case(damaged: Path, out: Path, method: str, ref: dict[str, str] | None = None) -> dict[str, str] | None:
    """Judge one damaged log, processed twice: the same outcome and the same estimates; where nothing
    warned and ``ref`` is given, the estimates are the intact log's."""
    code, err = cli("process", str(damaged), "-o", str(out / "a"), "--method", method)
    est = judged(code, err, damaged, out / "a")
    if est is None:
        return None
    again, err2 = cli("process", str(damaged), "-o", str(out / "b"), "--method", method)
    assert judged(again, err2, damaged, out / "b") == est and err2 == err
    if ref is not None and "warning" not in err:
        assert all(est[name] == ref[name] for name in est), "damage changed the estimates without a warning"
    return est


@FUZZ
@given(kind=st.sampled_from(["zstd", "lz4", "none", "unchunked"]), fraction=st.floats(0.0, 1.0), method=METHODS)
def test_fuzz_a_log_cut_anywhere(short_logs, intact, kind, fraction, method):
    """A cut keeps a prefix of the intact log's sweeps, with a warning; or nothing, with one error line."""
    log = short_logs[kind]
    with tempfile.TemporaryDirectory() as tmp:
        damaged = cut(log, int(fraction * (log.stat().st_size - 1)), Path(tmp))
        code, err = cli("process", str(damaged), "-o", str(Path(tmp) / "out"), "--method", method)
        est = judged(code, err, damaged, Path(tmp) / "out")
        if est is not None:
            got, full = stamps(est), stamps(intact[kind])
            assert got == full[: len(got)] and "warning" in err


@FUZZ
@given(kind=st.sampled_from(["zstd", "lz4", "none", "unchunked"]), method=METHODS,
       flips=st.lists(st.tuples(st.integers(0, 2**31), st.integers(1, 255)), min_size=1, max_size=3))
def test_fuzz_bytes_flipped_anywhere(short_logs, intact, kind, method, flips):
    """Flipped bytes: an error line, or estimates with a warning, or the intact estimates (flips in
    bytes that carry nothing used). MCAP protects metadata and messages outside chunks by no CRC, so a
    flipped value there may pass unnoticed: those cases are judged without the last clause."""
    log = short_logs[kind]
    size = log.stat().st_size
    unprotected = kind == "unchunked" or any(a <= at % size < b for at, _ in flips for a, b in metadata_spans(log))
    with tempfile.TemporaryDirectory() as tmp:
        _fuzz_case(flip(log, flips, Path(tmp)), Path(tmp), method, None if unprotected else intact[kind])


@pytest.mark.needs_conformance
@settings(FUZZ, max_examples=6)
@given(name=st.sampled_from(["other-writer-lz4.mcap", "other-writer-cut-off.mcap"]), fraction=st.floats(0.0, 0.3),
       method=METHODS, flips=st.lists(st.tuples(st.integers(0, 2**31), st.integers(1, 255)), max_size=2))
def test_fuzz_the_other_writers_logs_cut_and_flipped(name, fraction, method, flips):
    """Cut to its first 30 % at most (what is left takes a second to process), then flipped."""
    log = shared_file(f"conformance/{name}")
    with tempfile.TemporaryDirectory() as tmp:
        part = cut(log, int(fraction * log.stat().st_size), Path(tmp))
        _fuzz_case(flip(part, flips, Path(tmp)) if flips and part.stat().st_size else part, Path(tmp), method)


_FIELDS = ("x", "y", "z", "intensity", "velocity", "t")
_VALUES = st.sampled_from([math.nan, math.inf, -math.inf, 1e30, -1e9, -1.0, 0.0, 1e6])


@st.composite
def message_damage(draw):
    """A change to one sweep or tick message: layout fields, values, stamps, emptiness, counts."""
    what = draw(st.sampled_from(["point_step", "offset", "width", "value", "empty", "stamp", "ticks"]))
    index = draw(st.integers(0, 29))
    if what == "point_step":
        return what, index, draw(st.integers(0, 40))
    if what == "offset":
        return what, index, (draw(st.sampled_from(_FIELDS)), draw(st.integers(0, 60)))
    if what == "width":
        return what, index, draw(st.integers(0, 2**32 - 1))
    if what == "value":
        return what, index, (draw(st.sampled_from(("x", "y", "velocity", "t"))), draw(_VALUES), draw(st.integers(0, 500)))
    if what == "stamp":
        return what, index, draw(st.sampled_from([-10**9, -1, 1, 10**9 * 86_400, 10**15]))
    if what == "ticks":
        return what, index * 5, (draw(st.integers(-2**40, 2**40)), draw(st.booleans()))
    return what, index, None


def _apply(damage):
    what, index, arg = damage

    def edit(topic, i, msg):
        if what == "ticks" and topic == "/wheel/ticks" and i == index:
            msg.left += arg[0]
            if arg[1]:
                msg.right += arg[0]
        if topic != "/fmcw/points" or i != index:
            return
        if what == "point_step":
            msg.point_step = arg
        elif what == "offset":
            next(f for f in msg.fields if f.name == arg[0]).offset = arg[1]
        elif what == "width":
            msg.width = arg
        elif what == "value":
            f = next(f for f in msg.fields if f.name == arg[0])
            at = (arg[2] % max(msg.width, 1)) * msg.point_step + f.offset
            data = bytearray(msg.data)
            data[at:at + 4] = struct.pack("<f", arg[1])
            msg.data = bytes(data)
        elif what == "empty":
            msg.width, msg.row_step, msg.data = 0, 0, b""
        elif what == "stamp":
            ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec + arg
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(max(ns, 0), 10**9)
    return edit


@settings(FUZZ, max_examples=10)
@given(damage=st.lists(message_damage(), min_size=1, max_size=2), method=METHODS)
def test_fuzz_damaged_messages(short_logs, damage, method):
    edits = [_apply(d) for d in damage]

    def edit(topic, i, msg):
        for e in edits:
            e(topic, i, msg)
    with tempfile.TemporaryDirectory() as tmp:
        log = edited(short_logs, Path(tmp), edit, drop_topics=("/ground_truth/odom", "/ground_truth/point_labels"))
        _fuzz_case(log, Path(tmp), method)
