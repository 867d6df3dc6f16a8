"""Reading and writing MCAP logs: the one module that knows the MCAP container.

The log format is the contract in ``LOG_FORMAT.md`` (kept beside the project
in ``shared/``): MCAP with the ``ros2`` profile, CDR-encoded messages whose
``ros2msg`` schemas are the ``.msg`` texts in ``schemas/``
(:mod:`fmcwlog.io.schemas`).

Writing goes through ``mcap``'s writer with ``mcap_ros2``'s CDR encoders;
reading through ``mcap`` and ``mcap_ros2.decoder``. Readers accept compressed or uncompressed chunks, and
fall back to a sequential scan when a file has no summary (a recording cut off
before it finished).
"""

from __future__ import annotations

import os
import struct
import warnings
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.well_known import SchemaEncoding
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from mcap_ros2._dynamic import serialize_dynamic  # the CDR encoder mcap_ros2's own Writer uses
from mcap_ros2.decoder import DecoderFactory

from .. import __version__
from ..errors import LogError
from .atomic import partial_path
from .schemas import message_definition

# Types whose last field is a large primitive array given as a numpy array: written as raw
# bytes after the rest is CDR-encoded, because mcap_ros2 encodes non-uint8 arrays element by
# element (0.13 s for a 280k-cell occupancy grid, against 0.1 ms this way; identical bytes).
_RAW_TAIL = {"nav_msgs/msg/OccupancyGrid": "data"}


class LogWriter:
    """Writes an MCAP log (``ros2`` profile, CDR) to ``path`` via a temporary file renamed on :meth:`close`.

    Use as a context manager: on an exception the temporary file is removed and
    nothing is left at ``path``. Schemas and channels are registered on first use.
    """

    def __init__(self, path: str | os.PathLike, compression: str = "zstd", chunk_size: int = 1 << 20):
        self.path = Path(path)
        self._tmp = partial_path(self.path)
        self._file: IO[bytes] = open(self._tmp, "wb")
        self._writer = McapWriter(self._file, chunk_size=chunk_size,
                                  compression=CompressionType[compression.upper() or "NONE"])
        self._writer.start(profile="ros2", library=f"fmcwlog {__version__}")
        self._schemas: dict[str, tuple[int, Callable[[Any], bytes]]] = {}
        self._channels: dict[str, int] = {}

    def _schema(self, datatype: str) -> tuple[int, Callable[[Any], bytes]]:
        if datatype not in self._schemas:
            text = message_definition(datatype)
            schema_id = self._writer.register_schema(datatype, SchemaEncoding.ROS2, text.encode())
            self._schemas[datatype] = (schema_id, serialize_dynamic(datatype, text)[datatype])
        return self._schemas[datatype]

    def encode(self, datatype: str, message: dict) -> bytes:
        """CDR bytes of ``message`` (a dict of the type's fields)."""
        encoder = self._schema(datatype)[1]
        tail = _RAW_TAIL.get(datatype)
        if tail is not None and isinstance(message.get(tail), np.ndarray):
            raw = np.ascontiguousarray(message[tail]).tobytes()
            head = encoder({**message, tail: []})  # ends with the empty array's uint32 length
            return head[:-4] + struct.pack("<I", message[tail].size) + raw
        return encoder(message)

    def write(self, topic: str, datatype: str, message: dict, log_time_ns: int) -> None:
        """Write one message; ``log_time`` is the message's ``header.stamp`` (LOG_FORMAT.md)."""
        data = self.encode(datatype, message)
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._writer.register_channel(topic, "cdr", self._schema(datatype)[0])
            self._channels[topic] = channel
        self._writer.add_message(channel, log_time=log_time_ns, data=data, publish_time=log_time_ns)

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        self._writer.add_metadata(name, values)

    def close(self) -> Path:
        """Finish the MCAP (summary and footer) and move it into place; on failure nothing is left."""
        try:
            self._writer.finish()
            self._file.close()
            os.replace(self._tmp, self.path)
        except BaseException:
            self.abort()
            raise
        return self.path

    def abort(self) -> None:
        """Drop the partial file."""
        try:
            self._file.close()
        finally:
            self._tmp.unlink(missing_ok=True)

    def __enter__(self) -> LogWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


# --------------------------------------------------------------------------- reading


@dataclass
class LogMessage:
    """One decoded message: its topic, schema name, ``log_time`` (ns) and decoded object."""

    topic: str
    datatype: str
    log_time_ns: int
    msg: Any


@dataclass
class LogContents:
    """What a scan of a log found besides its messages."""

    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)  # topic -> schema name
    counts: dict[str, int] = field(default_factory=dict)  # topic -> messages, when the summary says
    truncated: bool = False


def _check_magic(path: Path, fh: IO[bytes]) -> None:
    head = fh.read(8)
    fh.seek(0)
    if head[:5] != b"\x89MCAP":
        raise LogError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")


class LogReader:
    """Streams decoded messages of a log in file order, whoever wrote it.

    An indexed file is read through its summary; a file without one (cut off
    before the footer) is scanned record by record up to where it ends, and
    :attr:`contents.truncated` is set.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if self.path.is_dir():
            raise LogError(f"{self.path}: is a folder, not a log file")
        if not self.path.is_file():
            raise LogError(f"{self.path}: no such file")
        self.contents = LogContents()
        self._decoders: dict[int, Any] = {}
        self._factory = DecoderFactory()
        with open(self.path, "rb") as fh:
            _check_magic(self.path, fh)
            self._indexed = self._read_summary(fh)
        if not self._indexed:
            self._scan_headers()

    def _read_summary(self, fh: IO[bytes]) -> bool:
        try:
            reader = make_reader(fh)
            summary = reader.get_summary()
            if summary is None:
                return False
            for ch in summary.channels.values():
                self.contents.topics[ch.topic] = summary.schemas[ch.schema_id].name
            if summary.statistics is not None:
                self.contents.counts = {summary.channels[c].topic: n
                                        for c, n in summary.statistics.channel_message_counts.items()}
            for md in reader.iter_metadata():
                self.contents.metadata[md.name] = dict(md.metadata)
            return True
        except (McapError, ValueError, AssertionError, EOFError, OSError):
            return False

    def _stream_records(self, fh: IO[bytes]) -> Iterator[Any]:
        reader = StreamReader(fh, skip_magic=False, emit_chunks=False)
        try:
            yield from reader.records
        except (McapError, EOFError, ValueError, AssertionError) as exc:
            if not self.contents.truncated:
                self.contents.truncated = True
                warnings.warn(f"{self.path}: log ends early ({type(exc).__name__}); reading up to where it ends",
                              stacklevel=2)

    def _scan_headers(self) -> None:
        """Collect metadata and topics of an unindexed file with one sequential pass."""
        for _ in self._raw_messages(set()):
            pass

    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        return self.contents.metadata

    @property
    def topics(self) -> dict[str, str]:
        return self.contents.topics

    def message_count(self, topic: str) -> int | None:
        """Messages on ``topic`` by the summary's statistics; None for an unindexed file."""
        return self.contents.counts.get(topic)

    def _raw_messages(self, wanted: set[str] | None) -> Iterator[tuple[Schema | None, Channel, Message]]:
        """Undecoded messages on the ``wanted`` topics (all when None), in file order; topics and
        metadata met on the way are noted in :attr:`contents` (an unindexed file has no summary).

        Always a sequential scan, chunk by chunk: memory stays at one chunk. (mcap's
        indexed reader held ~87 MB at its peak over a 5-minute log, growing with length.)
        """
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        with open(self.path, "rb") as fh:
            for rec in self._stream_records(fh):
                if isinstance(rec, Schema):
                    schemas[rec.id] = rec
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec
                    self.contents.topics.setdefault(rec.topic, schemas[rec.schema_id].name if rec.schema_id in schemas else "")
                elif isinstance(rec, Metadata):
                    self.contents.metadata.setdefault(rec.name, dict(rec.metadata))
                elif isinstance(rec, Message):
                    ch = channels.get(rec.channel_id)
                    if ch is not None and (wanted is None or ch.topic in wanted):
                        yield schemas.get(ch.schema_id), ch, rec

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
        """Decoded messages on ``topics`` (all when None), in file order."""
        for schema, channel, rec in self._raw_messages(None if topics is None else set(topics)):
            yield self._decode(schema, channel, rec)

    def log_times(self, topic: str) -> Iterator[int]:
        """``log_time`` (ns) of every message on ``topic``, without decoding them."""
        for _, _, rec in self._raw_messages({topic}):
            yield rec.log_time

    def _decode(self, schema: Schema | None, channel: Channel, message: Message) -> LogMessage:
        if schema is None:
            raise LogError(f"{self.path}: topic {channel.topic} has no schema")
        dec = self._decoders.get(channel.id)
        if dec is None:
            dec = self._factory.decoder_for(channel.message_encoding, schema)
            if dec is None:
                raise LogError(
                    f"{self.path}: topic {channel.topic} is encoded as {channel.message_encoding!r}, expected 'cdr'"
                )
            self._decoders[channel.id] = dec
        try:
            msg = dec(message.data)
        except Exception as exc:  # the CDR decoder raises several unrelated types
            raise LogError(f"{self.path}: cannot decode a message on {channel.topic} ({exc})") from exc
        return LogMessage(channel.topic, schema.name, message.log_time, msg)


