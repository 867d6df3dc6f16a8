"""Reading rosbag2 folders (sqlite3 or MCAP storage) and ROS 1 bags, through rosbags.

:class:`BagReader` has the interface of :class:`~fmcwlog.io.mcap_log.LogReader` that the rest of
the package uses (:class:`~fmcwlog.io.logs.Log`), so a bag is processed, calibrated and reported
as an MCAP log is, without converting it:

- A topic's type is its ROS 2 name: rosbags names a ROS 1 ``sensor_msgs/PointCloud2``
  ``sensor_msgs/msg/PointCloud2``.
- Messages decode with the definitions the bag holds (a ROS 1 bag holds every type's; a rosbag2
  bag recorded from ROS 2 Iron on, or with MCAP storage, holds them too); a type the bag does not define
  decodes as ROS 2 Humble's (ROS 1 Noetic's in a ROS 1 bag) or as the log format's own
  (``fmcwlog_msgs``). Decoded messages have mcap_ros2's field names (``header.stamp.sec`` and
  ``nanosec`` in a ROS 1 bag too, whose header also has its ``seq``); a ``uint8[]`` or numeric
  array is a numpy array where mcap_ros2 gives bytes or a list.
- A message's ``log_time`` is the bag's timestamp: when the recorder received it
  (:attr:`BagReader.receive_times`), not its ``header.stamp`` as the log format has it. Messages
  are merged across topics by it, as :meth:`LogReader.raw_messages_by_time` merges.
- A bag holds no fmcwlog metadata records (``fmcwlog.calibration`` and the like): its
  calibration comes from ``--calibration FILE``.
- A bag that cannot be read, when opened or part way through, is one :class:`LogError` naming it.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NamedTuple

from rosbags.interfaces import MessageDefinitionFormat
from rosbags.rosbag1 import Reader as Ros1Reader
from rosbags.rosbag2 import Reader as Ros2Reader
from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

from ..errors import LogError
from .mcap_log import ContentsReader, LogContents, LogMessage, UndecodableMessage
from .schemas import SCHEMA_DIR, message_definition

# The log format's own types, for a bag that does not define them.
OWN_TYPES = tuple(f"fmcwlog_msgs/msg/{p.stem}" for p in sorted((SCHEMA_DIR / "fmcwlog_msgs" / "msg").glob("*.msg")))
_IDL_SEPARATOR = "=" * 80 + "\n"


class BagChannel(NamedTuple):
    """A topic of a bag (what :meth:`BagReader.raw_messages_by_time` gives as the channel)."""

    topic: str


class BagRecord(NamedTuple):
    """One undecoded message: the bag's timestamp (ns), its bytes, and its type's name."""

    log_time: int
    data: bytes
    msgtype: str


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return text.splitlines()[0].rstrip(".")


class BagReader(ContentsReader):
    """A rosbag2 folder (or one of its storage files alone) or, with ``ros1``, a ROS 1 bag.

    Each pass over the messages opens the bag afresh, so passes may run side by side (one per
    topic in :meth:`raw_messages_by_time`).
    """

    receive_times = True  # log_time is the bag's receive time, not header.stamp

    def __init__(self, path: str | Path, ros1: bool = False):
        self.path = Path(path)
        self.ros1 = ros1
        self.kind = "ROS 1 bag" if ros1 else ("rosbag2 folder" if self.path.is_dir() else "rosbag2 storage file")
        self.contents = LogContents()
        self._stores: dict[str, Any] = {}  # type name -> the typestore that decodes it
        self._fallback: Any = None
        with self._opened() as reader:
            connections = list(reader.connections)
        for c in connections:
            self.contents.topics.setdefault(c.topic, c.msgtype)
            self.contents.counts[c.topic] = self.contents.counts.get(c.topic, 0) + max(int(c.msgcount), 0)
        self._embedded = self._embedded_types(connections)

    # ------------------------------------------------------------------ the interface of LogReader

    def damage_note(self) -> str:
        """'': a bag that cannot be read is refused at once, not read around."""
        return ""

    def raw_messages_by_time(self, topics: Sequence[str]) -> Iterator[tuple[None, BagChannel, BagRecord]]:
        """Undecoded messages on ``topics`` merged by ``log_time``, ties in the order of ``topics``
        (a pass per topic, each in the bag's order), as :meth:`LogReader.raw_messages_by_time`."""
        passes = [self._records({topic}) for topic in topics]
        yield from heapq.merge(*passes, key=lambda record: record[2].log_time)

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
        """Decoded messages on ``topics`` (all when None), in the bag's order."""
        for schema, channel, record in self._records(None if topics is None else set(topics)):
            yield self.decode(schema, channel, record)

    def log_times(self, topic: str) -> Iterator[int]:
        """The bag's timestamp (ns) of every message on ``topic``, without decoding them."""
        for _, _, record in self._records({topic}):
            yield record.log_time

    def decode(self, schema: Any, channel: BagChannel, message: BagRecord) -> LogMessage:
        """One message decoded (``schema`` is unused: the types are the bag's); :class:`LogError`
        where its type has no definition, :class:`UndecodableMessage` where its bytes are at fault."""
        store = self._store(channel.topic, message.msgtype)
        try:
            msg = (store.deserialize_ros1(message.data, message.msgtype) if self.ros1
                   else store.deserialize_cdr(message.data, message.msgtype))
        except Exception as exc:  # noqa: BLE001 (the deserialisers raise several unrelated types)
            raise UndecodableMessage(f"{self.path}: cannot decode a message on {channel.topic} "
                                     f"({_first_line(exc)})") from exc
        return LogMessage(channel.topic, message.msgtype, message.log_time, msg)

    # ------------------------------------------------------------------ the bag

    def _unreadable(self, exc: BaseException, when: str = "") -> LogError:
        detail = _first_line(exc)
        if self.ros1 and not when and ("not indexed" in detail or "index looks damaged" in detail):
            return LogError(f"{self.path}: a ROS 1 bag whose index is missing or damaged (a recording cut off "
                            "before it was closed?): 'rosbag reindex' rebuilds it")
        return LogError(f"{self.path}: cannot read this {self.kind}{when}: {detail}")

    @contextmanager
    def _opened(self) -> Iterator[Any]:
        """The bag opened by rosbags; whatever it raises is one :class:`LogError`."""
        try:
            reader = Ros1Reader(self.path) if self.ros1 else Ros2Reader(self.path)
            reader.open()
        except Exception as exc:  # noqa: BLE001 (rosbags, sqlite, YAML and decompressors raise their own types)
            raise self._unreadable(exc) from None
        try:
            yield reader
        finally:
            reader.close()

    def _records(self, topics: set[str] | None) -> Iterator[tuple[None, BagChannel, BagRecord]]:
        """One pass over the messages on ``topics`` (all when None)."""
        channels = {topic: BagChannel(topic) for topic in self.topics}
        with self._opened() as reader:
            wanted = [c for c in reader.connections if topics is None or c.topic in topics]
            if not wanted:
                return
            stream = reader.messages(connections=wanted)
            done = 0
            while True:
                try:
                    connection, log_time, data = next(stream)
                except StopIteration:
                    return
                except Exception as exc:  # noqa: BLE001 (damage: rosbags, sqlite and decompressors raise their own)
                    raise self._unreadable(exc, f" after reading {done} messages") from None
                done += 1
                yield None, channels[connection.topic], BagRecord(log_time, data, connection.msgtype)

    def _embedded_types(self, connections: Iterable[Any]) -> Any:
        """A typestore of the definitions the bag holds (None if it holds none)."""
        types: dict[str, Any] = {}
        try:
            for c in connections:
                if c.msgdef.format == MessageDefinitionFormat.MSG:
                    types.update(get_types_from_msg(c.msgdef.data, c.msgtype))
                elif c.msgdef.format == MessageDefinitionFormat.IDL:
                    text = c.msgdef.data
                    parts = [p.split("\n", 1)[1] for p in text.split(_IDL_SEPARATOR)[1:]] \
                        if text.startswith(f"{_IDL_SEPARATOR}IDL: ") else [text]
                    for part in parts:
                        types.update(get_types_from_idl(part))
            if not types:
                return None
            store = get_typestore(Stores.EMPTY)
            store.register(types)
        except Exception as exc:  # noqa: BLE001 (the parsers raise several types)
            raise LogError(f"{self.path}: the message definitions this {self.kind} holds cannot be parsed "
                           f"({_first_line(exc)})") from None
        return store

    def _fallback_types(self) -> Any:
        """ROS 2 Humble's types (ROS 1 Noetic's for a ROS 1 bag) and the log format's own."""
        if self._fallback is None:
            store = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
            own: dict[str, Any] = {}
            for name in OWN_TYPES:
                own.update(get_types_from_msg(message_definition(name), name))
            store.register({k: v for k, v in own.items() if k not in store.fielddefs})  # the store's Header
            self._fallback = store
        return self._fallback

    def _store(self, topic: str, msgtype: str) -> Any:
        store = self._stores.get(msgtype)
        if store is None:
            if self._embedded is not None and msgtype in self._embedded.fielddefs:
                store = self._embedded
            elif msgtype in self._fallback_types().fielddefs:
                store = self._fallback
            else:
                raise LogError(f"{self.path}: topic {topic}: its type {msgtype} has no definition in this "
                               f"{self.kind} and is not a standard ROS type")
            self._stores[msgtype] = store
        return store
