"""Writing outputs so that none is ever seen half-written: a temporary name, then a rename.

Every writer of fmcwlog goes through here. A file is written as
``.NAME.partial-PID`` beside its final place and renamed over it only once it is
complete (``os.replace`` is atomic on one file system); on any failure — a full
disk, Ctrl-C, a bug — the temporary file is removed and the final name is left
as it was. A folder of outputs is built the same way (:func:`atomic_folder`).
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import OutputError


def partial_path(path: str | os.PathLike) -> Path:
    """The temporary name ``path`` is written under: hidden, beside it, unique to this process."""
    path = Path(path)
    return path.with_name(f".{path.name}.partial-{os.getpid()}")


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write; renamed to ``path`` on success, removed on failure."""
    path = Path(path)
    tmp = partial_path(path)
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def to_jsonable(x: Any) -> Any:
    """``json.dumps``'s ``default``: numpy scalars and arrays, paths."""
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def json_text(obj: Any, sort_keys: bool = False) -> str:
    return json.dumps(obj, indent=2, sort_keys=sort_keys, default=to_jsonable) + "\n"


def write_json(path: str | os.PathLike, obj: Any, sort_keys: bool = False) -> None:
    write_text(path, json_text(obj, sort_keys))


def check_output_folder(out_dir: str | os.PathLike, force: bool) -> None:
    """Refuse an output folder that exists as a file, or holds anything, unless ``force``."""
    out_dir = Path(out_dir)
    if out_dir.exists():
        if not out_dir.is_dir():
            raise OutputError(f"{out_dir}: exists and is not a folder")
        if any(out_dir.iterdir()) and not force:
            raise OutputError(f"{out_dir}: exists and is not empty; use --force to replace it")


@contextmanager
def atomic_folder(out_dir: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary folder beside ``out_dir``; on success it replaces ``out_dir``.

    The caller has already decided that ``out_dir`` may be replaced
    (:func:`check_output_folder`). On failure the temporary folder is removed
    and ``out_dir`` is left untouched.
    """
    out_dir = Path(out_dir)
    tmp = partial_path(out_dir)
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
    except OSError as exc:
        raise OutputError(f"{out_dir}: cannot create it ({exc.strerror})") from None
    try:
        yield tmp
        if out_dir.exists():
            shutil.rmtree(out_dir)
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
