"""Writing outputs so that none is ever seen half-written, and replacing only what fmcwlog made.

Every writer of fmcwlog goes through here. A file is written as
``.NAME.partial-PID`` beside its final place and renamed over it only once it is
complete (``os.replace`` is atomic on one file system); on any failure — a full
disk, Ctrl-C, a bug — the temporary file is removed and the final name is left
as it was. Several files that belong together (a report's pages) are renamed
together at the end of an :func:`atomic_batch`, or not at all.

A folder of outputs is built the same way (:func:`atomic_folder`), or in place with a
roll-back (:func:`replacing_folder`, for ``fmcwlog run``, whose log must be recorded at
its final path). Every such folder holds a marker, :data:`MARKER`, listing what fmcwlog
wrote in it; ``--force`` replaces a folder only if it is empty or everything in it is
listed there, and never a folder that holds one of the command's inputs
(:func:`check_output_folder`). An output file is never one of the inputs
(:func:`check_output_file`).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Any

import numpy as np

from .. import __version__
from ..errors import OutputError, os_reason

MARKER = ".fmcwlog-output"  # JSON: {"made_by", "fmcwlog_version", "entries": [names fmcwlog wrote here]}


# a write refused for want of room or permission to grow: the output, not the input, is at fault
WRITE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


@contextmanager
def reported_write_errors(target: str | os.PathLike) -> Iterator[None]:
    """Turn a full disk (or quota, or read-only file system) inside the block into one line naming ``target``."""
    try:
        yield
    except OSError as exc:
        if exc.errno in WRITE_ERRNOS:
            raise OutputError(f"{target}: cannot write: {os_reason(exc)}") from None
        raise


def _named(path: str | os.PathLike) -> Path:
    """``path`` with a last component to name a temporary beside it (``.`` and ``..`` are resolved)."""
    p = Path(path)
    if not str(path).strip():
        raise OutputError("the output path is empty")
    if p.name in ("", ".", ".."):
        p = p.resolve()
    if not p.name:
        raise OutputError(f"{path}: cannot write an output in place of the file system's root")
    size = len(os.fsencode(p.name))  # the name's bytes on disk, undecodable ones (surrogates) included
    room = _NAME_MAX - len(f"..partial-{_PID_MAX}".encode())
    if size > room:  # else a valid name fails on its temporary's
        raise OutputError(f"{path}: the name is too long: it is written first as .NAME.partial-PID, which must "
                          f"fit the file system's {_NAME_MAX}-byte limit; use a name of at most {room} bytes")
    return p


_NAME_MAX = 255  # bytes in one path component (ext4, xfs, btrfs, tmpfs, NTFS, APFS)
_PID_MAX = 4194304  # Linux's largest process id: the longest .partial-PID / .old-PID suffix


def partial_path(path: str | os.PathLike) -> Path:
    """The temporary name ``path`` is written under: hidden, beside it, unique to this process."""
    path = _named(path)
    return path.with_name(f".{path.name}.partial-{os.getpid()}")


_PARTIAL = re.compile(r"^\.(?P<name>.+)\.partial-(?P<pid>\d+)$")
_batch: ContextVar[list[tuple[Path, Path]] | None] = ContextVar("fmcwlog_atomic_batch", default=None)


def remove_stale_partials(out_root: Path, names: set[str]) -> list[Path]:
    """The temporaries (``.NAME.partial-PID``, :func:`partial_path`) of outputs ``names`` in ``out_root``
    whose writer no longer runs (killed earlier), removed; returns them. A PID that is alive, whoever
    runs it, keeps its temporary."""
    removed: list[Path] = []
    if not out_root.is_dir():
        return removed
    for p in out_root.iterdir():
        m = _PARTIAL.match(p.name)
        if m and m["name"] in names and not _alive(int(m["pid"])):
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                with contextlib.suppress(OSError):
                    p.unlink()
            removed.append(p)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):  # someone else's process; a number beyond any PID
        return True
    return True


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write; renamed to ``path`` on success (at the end of the
    enclosing :func:`atomic_batch`, if any), removed on failure."""
    path = _named(path)
    tmp = partial_path(path)
    pending = _batch.get()
    try:
        yield tmp
        if pending is None:
            os.replace(tmp, path)
        else:
            pending.append((tmp, path))
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def atomic_batch() -> Iterator[None]:
    """Every :func:`atomic_path` inside is renamed into place only when the block succeeds;
    on a failure none is, and their temporary files are removed."""
    pending: list[tuple[Path, Path]] = []
    token = _batch.set(pending)
    try:
        try:
            yield
        finally:
            _batch.reset(token)
        for tmp, path in pending:
            os.replace(tmp, path)
    except BaseException:
        for tmp, _ in pending:
            tmp.unlink(missing_ok=True)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    """``text`` as UTF-8; a character UTF-8 cannot hold (a file name's undecodable byte, read by Python as
    a lone surrogate) is written as its escape (``\\udcff``), so that a page naming such a file is written."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8", errors="backslashreplace")


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


def check_folder_can_be_made(folder: str | os.PathLike) -> None:
    """Raise :class:`OutputError` where ``folder`` is not a folder and cannot be made one: it, or the
    nearest of its parents that exists, is a file, or that parent cannot be written. For a command
    that writes other outputs first, so that it refuses before it writes any."""
    path = Path(folder).absolute()
    existing = next((p for p in (path, *path.parents) if os.path.lexists(p)), None)
    if existing is None:
        return
    if not existing.is_dir():
        where = "it is a file" if existing == path else f"{existing} is a file"
        raise OutputError(f"{folder}: cannot create it ({where})")
    if not os.access(existing, os.W_OK | os.X_OK):
        where = "permission denied" if existing == path else f"{existing} cannot be written"
        raise OutputError(f"{folder}: cannot write in it ({where})")


@contextmanager
def created_parents(path: str | os.PathLike) -> Iterator[None]:
    """Create ``path``'s missing parent folders; if the block fails, remove ``path``'s temporary
    file (:func:`partial_path`, whatever stage its writer failed at) and the folders made here."""
    parent = _named(path).parent
    missing = [p for p in (parent, *parent.parents) if not p.exists()]
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{parent}: cannot create it ({os_reason(exc)})") from None
    try:
        yield
    except BaseException:
        # a writer that fails while it opens (an MCAP header on a full disk) never gets to remove its file
        with contextlib.suppress(OSError):  # a read-only file system refuses even this: keep the first error
            partial_path(path).unlink(missing_ok=True)
        for p in missing:  # deepest first; each is empty unless someone else wrote there meanwhile
            try:
                p.rmdir()
            except OSError:
                break
        raise


# --------------------------------------------------------------------------- what --force may replace


def _same_or_inside(inner: Path, outer: Path) -> bool:
    try:
        inner, outer = inner.resolve(), outer.resolve()
    except (OSError, RuntimeError):
        return False
    return inner == outer or outer in inner.parents


def check_output_file(path: str | os.PathLike, force: bool, inputs: Iterable[str | os.PathLike | None] = ()) -> None:
    """Refuse an output file that is one of ``inputs``, is a folder, or exists (unless ``force``)."""
    path = _named(path)
    for source in inputs:
        if source is not None and (_same_file(path, Path(source)) or _same_or_inside(path, Path(source))):
            raise OutputError(f"{path}: is an input of this command; write the output elsewhere")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; name the file to write")
    if path.exists() and not path.is_file():  # the rename would put a file in place of /dev/null, for root
        raise OutputError(f"{path}: is not a regular file (a device, a pipe or a socket); name a file to write")
    if (path.exists() or path.is_symlink()) and not force:
        raise OutputError(f"{path}: exists; use --force to overwrite it")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return False


def read_marker(folder: Path) -> dict[str, Any] | None:
    """The marker of an output folder fmcwlog made, or None (absent or not fmcwlog's)."""
    try:
        marker = json.loads((folder / MARKER).read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    ok = isinstance(marker, dict) and isinstance(marker.get("entries"), list) and "fmcwlog_version" in marker
    return marker if ok and all(isinstance(e, str) for e in marker["entries"]) else None


def _foreign_entry(folder: Path) -> str | None:
    """The first thing in ``folder`` that fmcwlog did not write there (by its marker), or None."""
    marker = read_marker(folder)
    if marker is None:
        return MARKER
    listed = set(marker["entries"]) | {MARKER}
    for entry in sorted(folder.iterdir()):
        partial = _PARTIAL.match(entry.name)
        name = partial.group("name") if partial else entry.name
        if name not in listed or entry.is_symlink():
            return entry.name
        if entry.is_dir() and not partial and read_marker(entry) is not None and _foreign_entry(entry) is not None:
            return entry.name  # an output folder fmcwlog made inside this one (run's results/) holds something else
    return None


def check_output_folder(out_dir: str | os.PathLike, force: bool,
                        inputs: Iterable[str | os.PathLike | None] = ()) -> None:
    """Refuse an output folder that is a file, holds an input, or holds anything unless ``force``;
    with ``force``, refuse one holding anything fmcwlog did not write there."""
    out_dir = _named(out_dir)
    for source in inputs:
        if source is not None and _same_or_inside(Path(source), out_dir):
            raise OutputError(f"{out_dir}: holds {source}, an input of this command; write the outputs elsewhere")
    if out_dir.is_symlink():
        raise OutputError(f"{out_dir}: is a symbolic link; name the folder itself")
    if not out_dir.exists():
        return
    if not out_dir.is_dir():
        raise OutputError(f"{out_dir}: exists and is not a folder")
    if out_dir.resolve() == Path.cwd().resolve():
        raise OutputError(f"{out_dir}: is the current folder; name a folder for the outputs (e.g. -o out)")
    if not any(out_dir.iterdir()):
        return
    if not force:
        raise OutputError(f"{out_dir}: exists and is not empty; use --force to replace it "
                          "(only an output folder fmcwlog made is replaced)")
    foreign = _foreign_entry(out_dir)
    if foreign == MARKER:
        raise OutputError(f"{out_dir}: was not made by fmcwlog (it has no {MARKER}); --force replaces only "
                          "an output folder fmcwlog made: remove it yourself or choose another")
    if foreign is not None:
        raise OutputError(f"{out_dir}: holds {foreign}, which fmcwlog did not write there; --force replaces only "
                          "what fmcwlog made: move it away or choose another folder")


def write_marker(folder: Path, made_by: str, entries: Iterable[str] | None = None) -> None:
    """List what fmcwlog wrote in ``folder`` (default: everything in it now) in its marker."""
    names = sorted(set(entries if entries is not None else (p.name for p in folder.iterdir())) - {MARKER})
    write_json(folder / MARKER, {"made_by": made_by, "fmcwlog_version": __version__, "entries": names})


def add_to_marker(folder: Path, paths: Iterable[str | os.PathLike]) -> None:
    """Add files fmcwlog wrote into an output folder it made (e.g. a report) to its marker."""
    marker = read_marker(folder)
    if marker is not None:
        names = {Path(p).resolve().relative_to(folder.resolve()).parts[0] for p in paths}
        write_marker(folder, marker.get("made_by", "fmcwlog"), set(marker["entries"]) | names)


def _swap_in(new: Path, out_dir: Path) -> None:
    """Put folder ``new`` at ``out_dir``; an existing ``out_dir`` is set aside first and removed last."""
    old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
    if not out_dir.exists():
        os.replace(new, out_dir)
        return
    shutil.rmtree(old, ignore_errors=True)
    os.replace(out_dir, old)
    try:
        os.replace(new, out_dir)
    except BaseException:
        os.replace(old, out_dir)
        raise
    shutil.rmtree(old, ignore_errors=True)


@contextmanager
def atomic_folder(out_dir: str | os.PathLike, force: bool = False, inputs: Iterable[str | os.PathLike | None] = (),
                  made_by: str = "fmcwlog") -> Iterator[Path]:
    """Yield an empty temporary folder beside ``out_dir``; on success it replaces ``out_dir``.

    ``out_dir`` is checked first (:func:`check_output_folder`) and again just before it is
    replaced, in case something was put in it meanwhile. The new folder gets a marker listing
    what the block wrote. On failure the temporary folder is removed and ``out_dir`` is left
    untouched.
    """
    inputs = tuple(inputs)
    check_output_folder(out_dir, force, inputs)
    out_dir = _named(out_dir).absolute()
    tmp = partial_path(out_dir)
    with created_parents(out_dir):
        remove_stale_partials(out_dir.parent, {out_dir.name})  # a run of the same output killed earlier
        try:
            shutil.rmtree(tmp, ignore_errors=True)
            tmp.mkdir()
        except OSError as exc:
            raise OutputError(f"{out_dir}: cannot create it ({os_reason(exc)})") from None
        try:
            yield tmp
            write_marker(tmp, made_by)
            check_output_folder(out_dir, force, inputs)
            _swap_in(tmp, out_dir)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise


@contextmanager
def replacing_folder(out_dir: str | os.PathLike, force: bool = False, made_by: str = "fmcwlog") -> Iterator[Path]:
    """Yield ``out_dir`` itself, new and empty, to be written in place; on failure it is removed
    and what was there before is put back. For outputs that must be made at their final path."""
    check_output_folder(out_dir, force)
    out_dir = _named(out_dir).absolute()
    old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
    with created_parents(out_dir):
        try:
            if out_dir.exists():
                shutil.rmtree(old, ignore_errors=True)
                os.replace(out_dir, old)
            out_dir.mkdir()
        except OSError as exc:
            if old.exists() and not out_dir.exists():
                os.replace(old, out_dir)
            raise OutputError(f"{out_dir}: cannot create it ({os_reason(exc)})") from None
        try:
            yield out_dir
            write_marker(out_dir, made_by)
        except BaseException:
            shutil.rmtree(out_dir, ignore_errors=True)
            if old.exists():
                os.replace(old, out_dir)
            raise
        shutil.rmtree(old, ignore_errors=True)
