"""The estimator's inputs read straight from their CDR bytes give mcap_ros2's values, or leave the
message to mcap_ros2 (with its errors)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fmcwlog.errors import LogError
from fmcwlog.io.mcap_log import _FAST_DECODERS, LogReader, pointcloud2_cdr, wheel_ticks_cdr

SAMPLES = sorted((Path(__file__).resolve().parents[3] / "sample_logs").glob("*.mcap"))
TYPES = tuple(_FAST_DECODERS)


def _plain(value):
    """A decoded message as nested dicts and lists, whichever decoder made it."""
    if isinstance(value, list):
        return [_plain(v) for v in value]
    names = getattr(value, "__slots__", None) or getattr(value, "__dict__", None)
    if names is not None and not isinstance(value, (bytes, str)):
        return {n: _plain(getattr(value, n)) for n in names if not n.startswith("_")}
    return value


@lru_cache(maxsize=4)
def _records(path: Path):
    reader = LogReader(path)
    wanted = [t for t, kind in reader.topics.items() if kind in TYPES]
    return reader, list(reader.raw_messages(wanted))


def _same(reader, schema, channel, rec) -> None:
    """decode_input gives what decode gives, or raises what it raises."""
    try:
        want = reader.decode(schema, channel, rec)
    except LogError as exc:
        with pytest.raises(type(exc), match="cannot decode"):
            reader.decode_input(schema, channel, rec)
        return
    got = reader.decode_input(schema, channel, rec)
    assert (got.topic, got.datatype, got.log_time_ns) == (want.topic, want.datatype, want.log_time_ns)
    assert _plain(got.msg) == _plain(want.msg)


@pytest.mark.parametrize("path", SAMPLES, ids=[p.stem for p in SAMPLES])
def test_sample_logs(path):
    reader, records = _records(path)
    assert {s.name for s, _, _ in records} == set(TYPES)
    first = _plain(reader.decode_input(*records[0]).msg)
    assert first["header"]["frame_id"] and first["header"]["stamp"]["sec"] > 0
    for schema, channel, rec in records:
        _same(reader, schema, channel, rec)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_damaged_bytes(data):
    """Cut, flipped or grown bytes of real messages: the same values or the same error."""
    reader, records = _records(SAMPLES[0])
    by_type = {s.name: (s, c, r) for s, c, r in records}
    schema, channel, rec = by_type[data.draw(st.sampled_from(TYPES))]
    raw = bytearray(rec.data)
    how = data.draw(st.sampled_from(["cut", "flip", "grow"]))
    if how == "cut":
        raw = raw[:data.draw(st.integers(0, len(raw)))]
    elif how == "flip":
        for _ in range(data.draw(st.integers(1, 4))):
            raw[data.draw(st.integers(0, min(len(raw), 120) - 1))] ^= data.draw(st.integers(1, 255))
    else:
        raw += data.draw(st.binary(min_size=1, max_size=8))
    _same(reader, schema, channel, type(rec)(channel_id=rec.channel_id, sequence=rec.sequence, log_time=rec.log_time,
                                             publish_time=rec.publish_time, data=bytes(raw)))


@given(frame=st.text(max_size=12), left=st.integers(-2**63, 2**63 - 1), right=st.integers(-2**63, 2**63 - 1),
       width=st.integers(0, 5), names=st.lists(st.text(min_size=0, max_size=6), max_size=4))
@settings(max_examples=200, deadline=None)
def test_generated_messages(frame, left, right, width, names):
    reader, records = _records(SAMPLES[0])
    by_type = {s.name: (s, c, r) for s, c, r in records}
    ticks = wheel_ticks_cdr((5, 7), frame, left, right)
    fields = tuple((n, 4 * i, 7, 1) for i, n in enumerate(names))
    cloud = pointcloud2_cdr((1, 2), frame, 1, width, fields, False, 4 * len(names), 4 * len(names) * width,
                            np.arange(width * len(names), dtype="<f4").tobytes(), True)
    for kind, raw in (("fmcwlog_msgs/msg/WheelTicks", ticks), ("sensor_msgs/msg/PointCloud2", cloud)):
        schema, channel, rec = by_type[kind]
        _same(reader, schema, channel, type(rec)(channel_id=rec.channel_id, sequence=0, log_time=1, publish_time=1,
                                                 data=raw))


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.text(max_size=5), st.lists(st.sampled_from(["x", "y", "t", "xy", ""]), max_size=3),
                          st.integers(0, 3)), min_size=1, max_size=6))
def test_clouds_in_turn(clouds):
    """Clouds of different fields and frames read one after another (each reads the fields the
    cloud before it left known, or its own): each decodes as mcap_ros2 decodes it."""
    reader, records = _records(SAMPLES[0])
    schema, channel, rec = {s.name: (s, c, r) for s, c, r in records}["sensor_msgs/msg/PointCloud2"]
    for frame, names, width in clouds + clouds[::-1]:
        fields = tuple((n, 4 * i, 7, 1) for i, n in enumerate(names))
        raw = pointcloud2_cdr((1, 2), frame, 1, width, fields, False, 4 * len(names), 4 * len(names) * width,
                              np.arange(width * len(names), dtype="<f4").tobytes(), True)
        _same(reader, schema, channel, type(rec)(channel_id=rec.channel_id, sequence=0, log_time=1, publish_time=1,
                                                 data=raw))
