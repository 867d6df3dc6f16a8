"""Opening a log as it was recorded: an MCAP file (the log format), a rosbag2 folder (sqlite3 or
MCAP storage; or one of its ``.db3`` files), or a ROS 1 ``.bag``.

:func:`open_log` tells them apart by their first bytes (and a folder by its ``metadata.yaml``) and
returns a :class:`~fmcwlog.io.mcap_log.LogReader` or a :class:`~fmcwlog.io.bag_log.BagReader`;
:class:`Log` is what both offer. rosbags is imported only when a bag is opened.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any, Protocol

from ..errors import LogError
from .mcap_log import LogContents, LogMessage, LogReader
from .mcap_scan import MAGIC as MCAP_MAGIC

ACCEPTED = "fmcwlog reads MCAP logs, rosbag2 folders (or their .db3 file) and ROS 1 .bag files"
ROSBAG2_METADATA = "metadata.yaml"  # what makes a folder a rosbag2 bag
_ROS1_MAGIC = b"#ROSBAG V"
_SQLITE_MAGIC = b"SQLite format 3\0"


class Log(Protocol):
    """A log being read: what :class:`LogReader` and :class:`~fmcwlog.io.bag_log.BagReader` both offer.

    ``receive_times``: a message's ``log_time`` is when the recorder received it (a bag), not its
    ``header.stamp`` (the log format, which has them equal).
    """

    path: Path
    contents: LogContents
    receive_times: bool

    @property
    def metadata(self) -> dict[str, dict[str, str]]: ...

    @property
    def topics(self) -> dict[str, str]: ...

    def metadata_all(self, name: str) -> list[dict[str, str]]: ...

    def message_count(self, topic: str) -> int | None: ...

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]: ...

    def raw_messages_by_time(self, topics: Sequence[str]) -> Iterator[tuple[Any, Any, Any]]: ...

    def decode(self, schema: Any, channel: Any, message: Any) -> LogMessage: ...

    def log_times(self, topic: str) -> Iterator[int]: ...

    def damage_note(self) -> str: ...


def is_rosbag2_folder(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a folder holding a rosbag2 ``metadata.yaml``."""
    return Path(path).is_dir() and (Path(path) / ROSBAG2_METADATA).is_file()


def log_location(path: str | os.PathLike) -> Path:
    """The path a log is read from: a rosbag2 folder for its ``metadata.yaml`` or a ``.db3`` file in
    it; else ``path`` itself."""
    path = Path(path)
    if (path.name == ROSBAG2_METADATA or path.suffix.lower() == ".db3") and path.is_file() \
            and is_rosbag2_folder(path.parent):
        return path.parent
    return path


def _head(path: Path) -> bytes | None:
    try:
        with open(path, "rb") as fh:
            return fh.read(len(_SQLITE_MAGIC))
    except OSError:
        return None


def open_log(path: str | os.PathLike) -> Log:
    """The reader of the log at ``path``: :class:`LogReader` for an MCAP file, a
    :class:`~fmcwlog.io.bag_log.BagReader` for a bag. Raises :class:`LogError` (one line) for what is
    none of them, and for a log that cannot be read."""
    path = log_location(path)
    if path.is_dir():
        if is_rosbag2_folder(path):
            from .bag_log import BagReader

            return BagReader(path)
        raise LogError(f"{path}: is a folder without a {ROSBAG2_METADATA}, so not a rosbag2 folder; {ACCEPTED}")
    head = _head(path) if path.is_file() else None
    if head is None:  # absent, not a regular file, unreadable: said as for any log file
        return LogReader(path)
    if head.startswith(_ROS1_MAGIC) or head.startswith(_SQLITE_MAGIC):
        from .bag_log import BagReader

        return BagReader(path, ros1=head.startswith(_ROS1_MAGIC))  # a .db3: without its folder's metadata.yaml
    if not head or head.startswith(MCAP_MAGIC[:5]) or MCAP_MAGIC.startswith(head):
        return LogReader(path)  # an MCAP log, or one cut off or damaged: LogReader says how
    named = {".bag": "a ROS 1 bag (it does not start with '#ROSBAG V')",
             ".db3": "a rosbag2 sqlite3 database (it does not start with 'SQLite format 3')"}.get(path.suffix.lower())
    what = f"{named}, nor an MCAP file" if named else \
        "an MCAP file (it does not start with the MCAP magic bytes), nor a ROS 1 bag or a rosbag2 sqlite3 database"
    raise LogError(f"{path}: not {what}; {ACCEPTED}")
