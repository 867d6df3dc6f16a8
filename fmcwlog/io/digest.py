"""A log's content digest: what ties an output folder to the very log it was processed from."""

from __future__ import annotations

import hashlib
import os
from pathlib import Path


def file_sha256(path: str | os.PathLike) -> str:
    """sha256 of the file's bytes (hex), read in chunks (logs can be gigabytes)."""
    with open(path, "rb") as fh:
        return hashlib.file_digest(fh, "sha256").hexdigest()


def _folder_files(folder: Path) -> list[Path]:
    """The files a log folder (a rosbag2 folder) is made of: every regular file directly in it that is
    not hidden, by name."""
    return sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))


def log_sha256(path: str | os.PathLike) -> str:
    """sha256 of a log: a file's bytes (:func:`file_sha256`); for a folder (a rosbag2 folder), of a line
    ``name size sha256`` per file in it (:func:`_folder_files`), so that a file renamed, added,
    removed or changed changes it."""
    path = Path(path)
    if not path.is_dir():
        return file_sha256(path)
    lines = "".join(f"{p.name}\0{p.stat().st_size}\0{file_sha256(p)}\n" for p in _folder_files(path))
    return hashlib.sha256(lines.encode()).hexdigest()


def log_size(path: str | os.PathLike) -> int:
    """Bytes of a log: a file's size, or the sum of a log folder's files."""
    path = Path(path)
    if not path.is_dir():
        return path.stat().st_size
    return sum(p.stat().st_size for p in _folder_files(path))
