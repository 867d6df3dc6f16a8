"""Which logs a batch covers, and the sub-folder of the output each one's results go to.

A path on the command line is a log, or a folder searched (recursively, in sorted order)
for logs by their file names, whatever their case (``*.mcap``, ``*.bag``, ``RUN.MCAP``; for
``import carmen`` the CARMEN names, ``.clf.GZ`` too: logs copied off other systems keep theirs).
For ``process``, a folder holding a ``metadata.yaml`` is a rosbag2 bag: one log, named by the
folder, whose files are not searched (given on the command line, it is that one log too; so is
its ``.db3``). What a search does not enter: hidden files and folders (``.name``, where
fmcwlog's own temporary outputs live), the batch's output folder, and any folder holding a
``run.json`` (a ``fmcwlog process`` output: its ``processed.mcap`` is a result, not a log).

Names: a log's results go to ``OUT/<stem>``; when two logs share a stem, the names of
their parent folders are prefixed (``day1-run``, ``day2-run``) until the names differ,
then ``-2``, ``-3``... in path order. Names depend only on the set of logs, so running
the same command again finds the same folders (:mod:`fmcwlog.fleet.state`).
"""

from __future__ import annotations

import fnmatch
import os
from collections.abc import Iterable, Sequence
from pathlib import Path

from ..errors import LogError
from ..io.logs import ROSBAG2_METADATA, is_rosbag2_folder, log_location

LOG_PATTERNS = ("*.mcap", "*.bag")  # and rosbag2 folders (find_logs' rosbag2)
CARMEN_PATTERNS = tuple(f"*.{ext}{comp}" for ext in ("clf", "log") for comp in ("", ".gz", ".xz", ".bz2"))
OUTPUT_MARKER = "run.json"  # a folder holding it is a 'fmcwlog process' output


def _matches(name: str, pattern: str) -> bool:
    """``name`` matches the (lower-case) ``pattern`` whatever its case."""
    return fnmatch.fnmatchcase(name.lower(), pattern)


def strip_suffixes(name: str, patterns: Sequence[str]) -> str:
    """``name`` without the suffix its pattern matched (``run.clf.xz`` -> ``run``)."""
    for pat in sorted(patterns, key=len, reverse=True):
        if _matches(name, pat) and pat.startswith("*"):
            return name[: len(name) - len(pat) + 1] or name
    return Path(name).stem


def _search(folder: Path, patterns: Sequence[str], skip: Path | None, rosbag2: bool) -> Iterable[Path]:
    for root, dirs, files in os.walk(folder):
        here = Path(root)
        if OUTPUT_MARKER in files or (skip is not None and here.resolve() == skip):
            dirs[:] = []
            continue
        if rosbag2 and ROSBAG2_METADATA in files and is_rosbag2_folder(here):
            dirs[:] = []
            yield here
            continue
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for f in sorted(files):
            if not f.startswith(".") and any(_matches(f, p) for p in patterns) and (here / f).is_file():
                yield here / f


def find_logs(paths: Sequence[str | os.PathLike], patterns: Sequence[str] = LOG_PATTERNS,
              skip: str | os.PathLike | None = None, rosbag2: bool = True) -> list[Path]:
    """Every log the ``paths`` name: files as given, folders searched; each log once, in order.

    ``rosbag2``: a folder holding a ``metadata.yaml`` is one log (a rosbag2 bag), and a ``.db3`` of
    one is that folder. ``skip``: a folder not to enter (the batch's own output). Raises
    :class:`LogError` for a path that does not exist, or when no log at all is found.
    """
    skip_dir = Path(skip).resolve() if skip is not None else None
    found: list[Path] = []
    seen: set[Path] = set()
    for p in map(Path, paths):
        if rosbag2:
            p = log_location(p)
        if rosbag2 and is_rosbag2_folder(p):
            logs = [p]
        elif p.is_dir():
            logs = list(_search(p, patterns, skip_dir, rosbag2))
        elif p.is_file():
            logs = [p]
        else:
            raise LogError(f"{p}: no such file or folder")
        for log in logs:
            key = log.resolve()
            if key not in seen:
                seen.add(key)
                found.append(log)
    if not found:
        names = ", ".join(str(p) for p in paths)
        bags = f" and rosbag2 folders (holding a {ROSBAG2_METADATA})" if rosbag2 else ""
        raise LogError(f"{names}: no logs found (looked for {', '.join(patterns)}{bags})")
    return found


def unique_names(logs: Sequence[Path], patterns: Sequence[str] = LOG_PATTERNS) -> list[str]:
    """A folder name per log, distinct, from its stem, or a rosbag2 folder's whole name (see the
    module's docstring)."""
    stems = [p.name if p.is_dir() else strip_suffixes(p.name, patterns) for p in logs]
    parents = [list(reversed(p.resolve().parent.parts)) for p in logs]
    names = list(stems)
    depth = 0
    while True:
        clashing = _clashes(names)
        if not clashing or depth >= max(len(x) for x in parents):
            break
        depth += 1
        for i in clashing:
            prefix = [part.strip(os.sep) for part in parents[i][:depth] if part.strip(os.sep)]
            names[i] = "-".join([*reversed(prefix), stems[i]])
    counts: dict[str, int] = {}
    for i in sorted(_clashes(names)):  # the same path components all the way up: number them
        key = names[i].lower()
        counts[key] = counts.get(key, 0) + 1
        if counts[key] > 1:
            names[i] = f"{names[i]}-{counts[key]}"
    return names


def _clashes(names: list[str]) -> list[int]:
    """Indices of names shared with another, whatever their case (``run`` and ``RUN`` are one folder
    on macOS's and Windows' file systems)."""
    seen: dict[str, int] = {}
    for n in names:
        seen[n.lower()] = seen.get(n.lower(), 0) + 1
    return [i for i, n in enumerate(names) if seen[n.lower()] > 1]
