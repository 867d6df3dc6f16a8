"""An MCAP file's records read so that damage costs only the bytes it touches.

``mcap``'s own readers stop at the first bad byte with whatever exception the
bytes provoke (``struct.error``, ``ZstdError``, a CRC error, ``EndOfFile``), and
its indexed reader refuses a file without an intact summary. Recordings get cut
off and disks flip bits, so :class:`McapScan` frames the records itself (opcode,
uint64 length, body; the MCAP specification, "Records") and hands each body to
``mcap``'s record parsers over exactly those bytes. Then:

- A file cut off (no footer) is read record by record up to the cut; a chunk the
  cut goes through is decompressed as far as its bytes go and its complete
  messages are kept (zstd and lz4 decode whole blocks of at most 128 KiB and
  4 MiB; an uncompressed chunk to the byte).
- A chunk that fails (its fields run past its record, its data does not
  decompress, or decompresses to another size or CRC than it declares) is
  damage. With an intact summary (footer and summary CRC check out) reading goes
  on at the next chunk the summary's chunk index lists; without one it stops
  there, since nothing says where the next record starts.
- A chunk the index lists is framed by the index's offset and length, so a
  damaged opcode or length field costs nothing when the chunk's own CRC holds.
- A damaged summary or footer costs only the index: the data section is read
  sequentially, as a file without a summary is.

Every event is reported through ``report(offset, cause, effect)``: what is wrong,
naming the byte offset, and what reading did about it. Memory stays at one chunk: records are read
one at a time and a chunk's records are dropped once yielded.
"""

from __future__ import annotations

import io
import struct
import zlib
from collections.abc import Callable, Collection, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import lz4.frame
import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)

MAGIC = b"\x89MCAP0\r\n"
_PREFIX = 9  # a record's opcode (uint8) and body length (uint64)
_FOOTER = _PREFIX + 20  # summary_start, summary_offset_start (uint64), summary_crc (uint32)
_KNOWN = {int(op) for op in Opcode}
# The specification: "0x80-0xFF are reserved for application extensions and user proposals", so a
# writer may put such records in the data section; they are skipped. An unknown opcode below is damage.
_EXTENSION = 0x80
_MESSAGE_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time
_MAX_CUT_CHUNK = 256 << 20  # bytes of a cut chunk decoded for its whole records (writers chunk at 1-4 MiB)

# What parsing damaged bytes raises: mcap's EndOfFile and friends, struct.error, UnicodeDecodeError
# and CRC mismatches (ValueError), zstandard's ZstdError, lz4's RuntimeError.
DAMAGE_ERRORS: tuple[type[BaseException], ...] = (McapError, struct.error, ValueError, OverflowError,
                                                  RuntimeError, zstandard.ZstdError)


class Damaged(Exception):
    """A record cannot be read; the message says why (no offset: the caller knows it)."""


class _Bounded(ReadDataStream):
    """A stream over exactly one record's bytes: a field that runs past them is damage, where
    ``ReadDataStream`` would return the short bytes (and ``struct`` fail later, or not at all)."""

    def read(self, length: int) -> bytes:
        try:
            data = super().read(length)
        except McapError:  # mcap's EndOfFile, raised when not a byte is left
            data = b""
        if len(data) != length:
            raise Damaged(f"a field of {length} bytes runs past the end of its record")
        return data


def parse(cls: Any, body: bytes, *args: Any) -> Any:
    """One record of the mcap record class ``cls`` parsed from exactly ``body``."""
    return cls.read(_Bounded(io.BytesIO(body)), *args)


def record_name(opcode: int) -> str:
    """An MCAP opcode in words, for messages ("chunk record")."""
    try:
        return Opcode(opcode).name.lower().replace("_", " ") + " record"
    except ValueError:
        return f"record of unknown opcode 0x{opcode:02x}"


@dataclass
class Summary:
    """What an intact summary section says about the file."""

    start: int  # byte offset of the summary section: the data section ends before it
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks: dict[int, int] = field(default_factory=dict)  # chunk record offset -> record length (prefix included)
    chunk_channels: dict[int, frozenset[int]] = field(default_factory=dict)  # chunk offset -> the channels it holds
    metadata: list[MetadataIndex] = field(default_factory=list)
    message_counts: dict[int, int] | None = None  # channel id -> messages, from the statistics


def _decompress(chunk: Chunk, partial: bool) -> bytes:
    """A chunk's records; ``partial``: its data is cut off, decode what the complete blocks hold."""
    if chunk.compression == "":
        return chunk.data
    if chunk.compression == "zstd":
        return zstandard.ZstdDecompressor().decompressobj().decompress(chunk.data)
    if chunk.compression == "lz4":
        if partial:
            return lz4.frame.LZ4FrameDecompressor().decompress(chunk.data)
        return lz4.frame.decompress(chunk.data)
    raise Damaged(f"unknown compression {chunk.compression!r}")


def _chunk_records(data: bytes, partial: bool, unwanted: Collection[int] = ()) -> list[Schema | Channel | Message]:
    """The schema, channel and message records in a chunk's decompressed bytes, but the messages on
    ``unwanted`` channel ids (checked as the others, not made into records); ``partial``: stop at
    the first record the bytes end inside, else that is damage."""
    out: list[Schema | Channel | Message] = []
    pos = 0
    while pos < len(data):
        if pos + _PREFIX > len(data):
            if partial:
                break
            raise Damaged("its last record is cut short")
        op, length = struct.unpack_from("<BQ", data, pos)
        start, end = pos + _PREFIX, pos + _PREFIX + length
        if end > len(data):
            if partial:
                break
            raise Damaged(f"a {record_name(op)} inside it runs past its end")
        if op == Opcode.MESSAGE:
            # the specification's fixed layout, unpacked here: mcap's parser reads it field by field
            # through a stream, which costs a third of the reading time
            if length < _MESSAGE_HEAD.size:
                raise Damaged("a message record shorter than its fields")
            channel_id, sequence, log_time, publish_time = _MESSAGE_HEAD.unpack_from(data, start)
            if channel_id not in unwanted:
                out.append(Message(channel_id=channel_id, log_time=log_time, publish_time=publish_time,
                                   sequence=sequence, data=data[start + _MESSAGE_HEAD.size:end]))
        elif op == Opcode.CHANNEL:
            channel = parse(Channel, data[start:end])
            if channel.id in unwanted:  # defined anew here: its messages from here on are the caller's to judge
                unwanted = set(unwanted) - {channel.id}
            out.append(channel)
        elif op == Opcode.SCHEMA:
            out.append(parse(Schema, data[start:end]))
        pos = end
    return out


def read_chunk(body: bytes, unwanted: Collection[int] = ()) -> list[Schema | Channel | Message]:
    """The records of a whole chunk record's body, but messages on ``unwanted`` channel ids;
    :class:`Damaged` if it fails its checks."""
    chunk = parse(Chunk, body)
    data = _decompress(chunk, partial=False)
    if len(data) != chunk.uncompressed_size:
        raise Damaged(f"it decompresses to {len(data)} bytes, not the {chunk.uncompressed_size} it declares")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise Damaged("its data fails its CRC")
    return _chunk_records(data, partial=False, unwanted=unwanted)


def read_partial_chunk(body: bytes) -> list[Schema | Channel | Message]:
    """The complete records of a chunk record cut off inside: none if its fields before the data are cut."""
    try:
        stream = _Bounded(io.BytesIO(body))
        start, end, size, crc = stream.read8(), stream.read8(), stream.read8(), stream.read4()
        compression = str(stream.read(stream.read4()), "utf-8")
        stream.read8()  # the data's full length, beyond the cut
        chunk = Chunk(compression, body[stream.count:], end, start, crc, size)
        return _chunk_records(_decompress(chunk, partial=True), partial=True)
    except DAMAGE_ERRORS + (Damaged,):
        return []


def read_summary(fh: IO[bytes], size: int) -> tuple[int | None, Summary | None, str | None]:
    """Where the footer is (None: no intact footer and closing magic) and the summary it points to,
    or None with why not (the problem is None where the file declares no summary)."""
    if size < len(MAGIC) + _FOOTER + len(MAGIC):
        return None, None, f"the log ends at byte {size}, too short for a footer"
    footer_at = size - _FOOTER - len(MAGIC)
    fh.seek(footer_at)
    tail = fh.read(_FOOTER + len(MAGIC))
    if tail[_FOOTER:] != MAGIC:
        return None, None, f"the log ends at byte {size} without its closing magic bytes"
    op, length = struct.unpack_from("<BQ", tail)
    if op != Opcode.FOOTER or length != _FOOTER - _PREFIX:
        return None, None, f"the log has no footer record at byte {footer_at}"
    start, _, crc = struct.unpack_from("<QQI", tail, _PREFIX)
    if start == 0:
        return footer_at, None, None
    if not len(MAGIC) < start <= footer_at:
        return None, None, f"the log's footer at byte {footer_at} points outside the file"
    fh.seek(start)
    blob = fh.read(footer_at - start)
    if crc and zlib.crc32(tail[:_FOOTER - 4], zlib.crc32(blob)) != crc:
        return footer_at, None, f"the log's summary (bytes {start} to {footer_at}) fails its CRC"
    summary = Summary(start)
    pos = 0
    try:
        while pos < len(blob):
            op, length = struct.unpack_from("<BQ", blob, pos)
            body = blob[pos + _PREFIX: pos + _PREFIX + length]
            if len(body) != length:
                raise Damaged(f"a {record_name(op)} runs past the summary")
            if op == Opcode.SCHEMA:
                schema = parse(Schema, body)
                summary.schemas[schema.id] = schema
            elif op == Opcode.CHANNEL:
                channel = parse(Channel, body)
                summary.channels[channel.id] = channel
            elif op == Opcode.CHUNK_INDEX:
                index = parse(ChunkIndex, body)
                summary.chunks[index.chunk_start_offset] = index.chunk_length
                summary.chunk_channels[index.chunk_start_offset] = frozenset(index.message_index_offsets)
            elif op == Opcode.METADATA_INDEX:
                summary.metadata.append(parse(MetadataIndex, body))
            elif op == Opcode.STATISTICS:
                summary.message_counts = dict(parse(Statistics, body).channel_message_counts)
            pos += _PREFIX + length
    except DAMAGE_ERRORS + (Damaged,) as exc:
        return footer_at, None, f"the log's summary is damaged at byte {start + pos} ({exc})"
    return footer_at, summary, None


class McapScan:
    """The records of one MCAP file, damage reported and stepped over (see the module docstring).

    ``report(offset, cause, effect)`` is called for each event of each pass; :attr:`summary` is the
    intact summary or None (then :attr:`summary_problem` says why, if the file should have one).
    """

    def __init__(self, path: Path, report: Callable[[int, str, str], None]):
        self.path = path
        self.report = report
        self.size = path.stat().st_size
        self.complete = False
        self.extensions: dict[int, int] = {}  # byte offset -> opcode of each extension record skipped
        with open(path, "rb") as fh:
            head = fh.read(len(MAGIC))
            if not head:
                raise Damaged("the file is empty")
            if len(head) < len(MAGIC) and head == MAGIC[: len(head)]:
                raise Damaged(f"the log ends at byte {len(head)}, inside its magic bytes: nothing to read")
            if head[:5] != MAGIC[:5]:
                raise Damaged("not an MCAP file (it does not start with the MCAP magic bytes)")
            self.footer_at, self.summary, self.summary_problem = read_summary(fh, self.size)

    def metadata(self) -> Iterator[Metadata]:
        """The metadata records the summary's index lists, in file order; damaged ones reported."""
        assert self.summary is not None
        with open(self.path, "rb") as fh:
            for index in sorted(self.summary.metadata, key=lambda m: m.offset):
                fh.seek(index.offset)
                raw = fh.read(index.length) if index.length <= self.summary.start else b""
                try:
                    if len(raw) < _PREFIX or raw[0] != Opcode.METADATA:
                        raise Damaged("it is not where the index says")
                    yield parse(Metadata, raw[_PREFIX:])
                except DAMAGE_ERRORS + (Damaged,) as exc:
                    self.report(index.offset, f"the metadata record {index.name!r} at byte {index.offset} "
                                              f"is damaged ({exc})", "skipped it")

    def records(self, skip_chunk: Callable[[frozenset[int]], bool] | None = None,
                unwanted: Collection[int] = ()) -> Iterator[Schema | Channel | Message | Metadata]:
        """Schema, channel, message and metadata records of the data section, in file order.

        Returns at the data section's end, at a cut, or at damage it cannot step over (reported);
        :attr:`complete` then says whether it read to the data section's end. ``skip_chunk(channels)``:
        a chunk the summary's index lists, with the ids of the channels it holds, is stepped over
        unread (not decompressed, its damage unseen by this pass) where it says True. ``unwanted``:
        channel ids whose messages inside chunks are left out (read and checked, not returned); the
        caller may add to it as it goes, for the chunks after.
        """
        self.complete = False
        if self.summary is not None:
            end = self.summary.start
        else:
            end = self.footer_at if self.footer_at is not None else self.size
        with open(self.path, "rb") as fh:
            pos: int | None = len(MAGIC)
            while pos is not None and pos < end:
                if skip_chunk is not None and self._skippable(pos, end, skip_chunk):
                    assert self.summary is not None
                    pos += self.summary.chunks[pos]
                    continue
                fh.seek(pos)
                body = None
                try:
                    op, body = self._frame(fh, pos, end)
                    if op == Opcode.DATA_END:
                        self.complete = True
                        return
                    if op >= _EXTENSION:  # said by the caller: a damaged opcode may read as one too
                        self.extensions[pos] = op
                    records = self._records(op, body, unwanted)
                except _Cut as cut:
                    yield from cut.records
                    kept = f", and the {len(cut.records)} records of that chunk that came whole" if cut.records else ""
                    self.report(pos, str(cut), f"read everything before it{kept}")
                    return
                except DAMAGE_ERRORS + (Damaged,) as exc:
                    pos = self._step_over(fh, pos, exc, None if body is None else len(body))
                    continue
                yield from records
                pos += _PREFIX + len(body)
        if pos is not None and self.footer_at is not None:
            self.complete = True  # no data-end record, but nothing is missing before the summary or footer
        elif pos is not None:
            self.report(pos, f"the log ends early, at byte {pos}, without its summary and footer "
                             "(a recording cut off)", "read everything before it")

    def _skippable(self, pos: int, end: int, skip_chunk: Callable[[frozenset[int]], bool]) -> bool:
        """Whether the summary's index lists a chunk at ``pos`` inside the data section, with the
        channels it holds (a writer may leave them out: then it is read), and ``skip_chunk`` says so."""
        if self.summary is None:
            return False
        length = self.summary.chunks.get(pos)
        channels = self.summary.chunk_channels.get(pos)
        return length is not None and length >= _PREFIX and pos + length <= end and channels is not None \
            and bool(channels) and skip_chunk(channels)

    def _frame(self, fh: IO[bytes], pos: int, end: int) -> tuple[int, bytes]:
        """The opcode and body of the record at ``pos``; a chunk the index lists is framed by it."""
        head = fh.read(_PREFIX)
        known = self.summary.chunks.get(pos) if self.summary is not None else None
        if known is not None and known >= _PREFIX and pos + known <= end:
            op, length = struct.unpack_from("<BQ", head) if len(head) == _PREFIX else (0, 0)
            body = fh.read(known - _PREFIX)
            if (op, length) != (Opcode.CHUNK, known - _PREFIX):
                # the index (whose CRC held) frames it: the chunk's own checks decide on its body
                self.report(pos, f"the chunk at byte {pos} has a damaged opcode or length field",
                            "read it as the summary's index frames it")
            return Opcode.CHUNK, body
        if len(head) < _PREFIX:
            raise _Cut(f"the log ends early, at byte {self.size}, inside the header of the record at byte {pos}")
        op, length = struct.unpack_from("<BQ", head)
        if op not in _KNOWN and op < _EXTENSION:
            raise Damaged(f"a record of unknown opcode 0x{op:02x}")
        if pos + _PREFIX + length > end:
            if self.footer_at is None:  # no footer: the file was cut off, not damaged
                rest = self.size - pos - _PREFIX  # a cut chunk holds a few MB; a damaged length may claim the file
                kept = read_partial_chunk(fh.read(rest)) if op == Opcode.CHUNK and rest <= _MAX_CUT_CHUNK else []
                raise _Cut(f"the log ends early, at byte {self.size}, inside the {record_name(op)} at byte {pos}", kept)
            raise Damaged(f"its length ({length} bytes) runs past the data section")
        return op, fh.read(length)

    @staticmethod
    def _records(op: int, body: bytes, unwanted: Collection[int] = ()) -> list[Schema | Channel | Message | Metadata]:
        if op == Opcode.CHUNK:
            return list(read_chunk(body, unwanted))
        if op == Opcode.MESSAGE:
            return [parse(Message, body, len(body))]
        if op == Opcode.CHANNEL:
            return [parse(Channel, body)]
        if op == Opcode.SCHEMA:
            return [parse(Schema, body)]
        if op == Opcode.METADATA:
            return [parse(Metadata, body)]
        if op == Opcode.MESSAGE_INDEX:  # unused, but it must frame exactly: a damaged chunk opcode may read as one
            if len(body) < 6 or struct.unpack_from("<I", body, 2)[0] != len(body) - 6 or len(body) % 16 != 6:
                raise Damaged("a message index of the wrong length")
        elif op in (Opcode.FOOTER, Opcode.SUMMARY_OFFSET, Opcode.CHUNK_INDEX, Opcode.STATISTICS,
                    Opcode.METADATA_INDEX, Opcode.ATTACHMENT_INDEX):
            raise Damaged(f"a {record_name(op)}, which belongs in the summary")
        return []

    def _step_over(self, fh: IO[bytes], pos: int, exc: BaseException, length: int | None) -> int | None:
        """Where reading goes on after damage in the record at ``pos`` (reported): the next chunk the
        index lists; without an index, the end of the damaged record if a record plausibly starts
        there (a known opcode whose length fits the file: random bytes pass that once in ~10^13)."""
        why = f"{type(exc).__name__}: {exc}" if not isinstance(exc, Damaged) else str(exc)
        later = [o for o in self.summary.chunks if o > pos] if self.summary is not None else []
        if later:
            self.report(pos, f"the log is damaged at byte {pos} ({why})",
                        f"skipped to byte {min(later)}, the next chunk the summary's index lists")
            return min(later)
        after = pos + _PREFIX + length if length is not None else None
        if after is not None and self._record_starts(fh, after):
            self.report(pos, f"the log is damaged at byte {pos} ({why})",
                        f"skipped that {self._name_at(fh, pos)}, whose frame is intact; read on from byte {after}")
            return after
        self.report(pos, f"the log is damaged at byte {pos} ({why})", "read everything before it and stopped there"
                    + ("" if self.summary is not None else " (no intact index finds later chunks)"))
        return None


    def _record_starts(self, fh: IO[bytes], at: int) -> bool:
        """Whether ``at`` is the file's end or holds a record header that fits the file."""
        if at == self.size or (self.footer_at is not None and at == self.footer_at):
            return True
        fh.seek(at)
        head = fh.read(_PREFIX)
        if len(head) < _PREFIX:
            return False
        op, length = struct.unpack_from("<BQ", head)
        return op in _KNOWN and at + _PREFIX + length <= self.size

    @staticmethod
    def _name_at(fh: IO[bytes], pos: int) -> str:
        fh.seek(pos)
        return record_name(fh.read(1)[0])


class _Cut(Exception):
    """The file ends inside a record; ``records``: what the cut chunk still held whole."""

    def __init__(self, message: str, records: list | None = None):
        super().__init__(message)
        self.records = records or []
