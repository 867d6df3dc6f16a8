"""The MCAP writer that compresses a chunk in a thread while the next fills writes ``mcap``'s bytes."""

from __future__ import annotations

import io

import numpy as np
import pytest
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from fmcwlog.io.mcap_log import LogReader, LogWriter, _OverlappedWriter, overlapped_writer


def _write(writer_class, compression: CompressionType, seed: int, chunk_size: int) -> bytes:
    """Messages of varied sizes on three channels, with metadata and an attachment between chunks."""
    rng = np.random.default_rng(seed)
    out = io.BytesIO()
    w = writer_class(out, chunk_size=chunk_size, compression=compression)
    w.start(profile="ros2", library="test")
    schema = w.register_schema("a/msg/B", "ros2msg", b"int32 x")
    channels = [w.register_channel(f"/t{i}", "cdr", schema) for i in range(3)]
    t = 0
    for i in range(400):
        t += int(rng.integers(0, 1000))
        size = int(rng.choice([8, 200, 5000, 40000]))
        data = rng.integers(0, 4, size, dtype=np.uint8).tobytes()  # compressible, not trivially
        w.add_message(channels[int(rng.integers(0, 3))], log_time=t, data=data, publish_time=t)
        if i in (57, 300):
            w.add_metadata(f"m{i}", {"k": str(i)})
        if i == 201:
            w.add_attachment(create_time=1, log_time=t, name="a.bin", media_type="bin", data=b"xyz" * 50)
        if i == 333:
            w.flush()
    w.finish()
    return out.getvalue()


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE])
@pytest.mark.parametrize("seed, chunk_size", [(0, 1 << 16), (1, 1 << 20), (2, 1000)])
def test_same_bytes_as_mcap(compression, seed, chunk_size):
    assert _write(_OverlappedWriter, compression, seed, chunk_size) == _write(McapWriter, compression, seed, chunk_size)


def test_log_writer_uses_it_and_reads_back(tmp_path):
    w = LogWriter(tmp_path / "x.mcap", chunk_size=4096)
    assert isinstance(w._writer, _OverlappedWriter)
    for i in range(200):
        w.write_cdr("/ticks", "fmcwlog_msgs/msg/WheelTicks", bytes(range(256)) * 8, 1000 + i)
    w.add_metadata("fmcwlog.test", {"a": "b"})
    w.close()
    reader = LogReader(tmp_path / "x.mcap")
    assert [rec.log_time for _, _, rec in reader.raw_messages()] == list(range(1000, 1200))
    assert reader.metadata["fmcwlog.test"] == {"a": "b"} and not reader.contents.damage


def test_falls_back_without_mcap_state(monkeypatch):
    monkeypatch.setattr("fmcwlog.io.mcap_log._MCAP_STATE", ("no_such_state",))
    assert type(overlapped_writer(io.BytesIO())) is McapWriter
