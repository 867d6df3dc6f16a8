"""Reading named topics of an indexed MCAP log steps over the chunks its summary lists without them:
the same messages as a whole read (checked with ``mcap``'s own reader), fewer chunks decompressed."""

from __future__ import annotations

import shutil
import warnings

import pytest
from helpers import SAMPLE_LOGS
from mcap.reader import make_reader

from fmcwlog.io import mcap_scan
from fmcwlog.io.mcap_log import LogReader

LOG = SAMPLE_LOGS / "corridor_30s.mcap"


def _plain(topic: str) -> list[tuple[int, bytes]]:
    """(log_time, bytes) of every message on ``topic``, by mcap's reader."""
    with open(LOG, "rb") as fh:
        return [(m.log_time, bytes(m.data)) for _, _, m in make_reader(fh).iter_messages(topics=[topic],
                                                                                       log_time_order=False)]


def _chunks_read(monkeypatch) -> list[int]:
    read: list[int] = []
    real = mcap_scan.read_chunk
    monkeypatch.setattr(mcap_scan, "read_chunk", lambda body, *rest: read.append(len(body)) or real(body, *rest))
    return read


@pytest.mark.parametrize("topic", ["/tf_static", "/fmcw/points", "/wheel/ticks", "/tf"])
def test_a_topic_read_alone_is_every_message_on_it(topic):
    got = [(rec.log_time, bytes(rec.data)) for _, _, rec in LogReader(LOG).raw_messages([topic])]
    assert got == _plain(topic) and got


def test_the_one_tf_static_message_costs_its_chunk_not_the_log(monkeypatch):
    read = _chunks_read(monkeypatch)
    reader = LogReader(LOG)
    assert [m.topic for m in reader.messages(["/tf_static"])] == ["/tf_static"]
    with_it = [o for o, ids in reader._scan.summary.chunk_channels.items()
               if any(reader._scan.summary.channels[i].topic == "/tf_static" for i in ids)]
    assert len(read) == len(with_it) == 1
    read.clear()
    assert sum(1 for _ in reader.raw_messages()) > 6000  # every message: every chunk
    assert len(read) == len(reader._scan.summary.chunks) > 5


def test_damage_in_a_chunk_stepped_over_is_left_to_the_passes_that_read_it(tmp_path):
    log = tmp_path / "damaged.mcap"
    shutil.copyfile(LOG, log)
    summary = LogReader(log)._scan.summary
    last = max(summary.chunks)  # not the first chunk, which holds /tf_static
    data = bytearray(log.read_bytes())
    data[last + summary.chunks[last] // 2] ^= 0xFF  # inside its compressed records: its CRC fails
    log.write_bytes(bytes(data))
    reader = LogReader(log)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert len(list(reader.messages(["/tf_static"]))) == 1
        assert not caught
        n = sum(1 for _ in reader.raw_messages(["/fmcw/points"]))
    assert len(caught) == 1 and f"damaged at byte {last}" in str(caught[0].message), [str(w.message) for w in caught]
    assert 0 < n < len(_plain("/fmcw/points"))
