"""What a batch remembers, so that running the same command again redoes only what changed.

A log's results are complete when its folder ``OUT/<name>`` exists (``fmcwlog process``
renames it into place only once everything is written) and its ``run.json`` says it was
made from a file of the same size and SHA-256 (``log_size_bytes``, ``log_sha256``) with the
same options (``options_sha256``: :func:`options_digest`). Anything else is done again.

``OUT/batch.json`` records the latest outcome of every log of the batch: done, skipped
(complete already) or failed with its one-line reason (schema ``fmcwlog.batch/1``). A
failed log has no folder (or keeps the complete folder of an earlier run), so the reason
lives here; ``fmcwlog report OUT`` reads it.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

from ..io.atomic import read_marker, write_json
from ..io.digest import log_sha256, log_size

BATCH_FILE = "batch.json"
BATCH_SCHEMA = "fmcwlog.batch/1"




def completeness(out_dir: Path, log: Path, options_sha256: str) -> tuple[bool, str]:
    """Whether ``out_dir`` holds complete results of ``log`` with these options, and if not, why."""
    run_json = out_dir / "run.json"
    if not out_dir.is_dir():
        return False, "no results yet"
    try:
        run = json.loads(run_json.read_text())
    except (OSError, json.JSONDecodeError):
        return False, f"{out_dir} holds no readable run.json"
    if run.get("options_sha256") != options_sha256:
        return False, "the options changed"
    if run.get("log_size_bytes") != log_size(log) or run.get("log_sha256") != log_sha256(log):
        return False, "the log changed"
    return True, "complete"


def follow_renamed(out_root: Path, logs: list[Path], names: list[str]) -> list[tuple[Path, Path]]:
    """Move the results of a log whose name changed since an earlier run to its new name.

    A log's name is its stem until another log of the batch shares it (``run`` becomes
    ``day1-run`` once ``day2/run.mcap`` arrives). Its earlier folder, an fmcwlog output whose
    ``run.json`` names this very file, is renamed to the new name (and its batch.json entry
    dropped), so that running the batch again resumes it instead of redoing it beside the old
    folder: the batch then holds what a fresh one would, not the same log twice. Returns the
    moves made (from, to)."""
    if not out_root.is_dir():
        return []
    current = set(names)
    earlier: dict[str, Path] = {}
    for folder in sorted(out_root.iterdir()):
        if folder.name in current or folder.name.startswith(".") or not is_fmcwlog_output(folder):
            continue
        try:
            made_from = json.loads((folder / "run.json").read_text()).get("log")
        except (OSError, json.JSONDecodeError, AttributeError):
            continue
        if isinstance(made_from, str):
            earlier.setdefault(made_from, folder)
    moves = []
    for log, name in zip(logs, names):
        old, new = earlier.get(str(log.resolve())), out_root / name
        if old is not None and not new.exists():
            try:
                old.rename(new)
            except OSError:  # left where it is: the log is done again under its new name, as before
                continue
            moves.append((old, new))
    if moves:
        doc = read_batch(out_root)
        for old, _ in moves:
            doc["logs"].pop(old.name, None)
        write_batch(out_root, doc)
    return moves


def is_fmcwlog_output(out_dir: Path) -> bool:
    """An existing folder that ``fmcwlog process`` wrote (its marker says so), which it may replace
    (:func:`fmcwlog.io.atomic.check_output_folder` still refuses one holding anything else)."""
    marker = read_marker(out_dir) if out_dir.is_dir() else None
    return marker is not None and marker.get("made_by") == "fmcwlog process"


def remove_partial(out_root: Path, name: str, pid: int) -> bool:
    """Remove what a worker of process ``pid`` left of ``OUT/<name>`` when it was killed."""
    tmp = out_root / f".{name}.partial-{pid}"
    if tmp.exists():
        shutil.rmtree(tmp, ignore_errors=True)
        return True
    return False


def read_batch(out_root: Path) -> dict[str, Any]:
    """``OUT/batch.json``, or an empty record."""
    try:
        doc = json.loads((out_root / BATCH_FILE).read_text())
    except (OSError, json.JSONDecodeError):
        return {"schema": BATCH_SCHEMA, "logs": {}}
    if not isinstance(doc, dict) or doc.get("schema") != BATCH_SCHEMA or not isinstance(doc.get("logs"), dict):
        return {"schema": BATCH_SCHEMA, "logs": {}}
    return doc


def write_batch(out_root: Path, doc: dict[str, Any]) -> None:
    """Write ``doc`` with its logs in name order: outcomes arrive as the workers end, and an
    earlier batch.json kept the order of its own run, so the order they came in is the timing's,
    not the batch's (the same batch would otherwise list its logs differently run to run)."""
    out_root.mkdir(parents=True, exist_ok=True)
    write_json(out_root / BATCH_FILE, {**doc, "logs": dict(sorted(doc["logs"].items()))})


def is_batch_folder(out_dir: Path) -> bool:
    """A folder of ``fmcwlog process``'s per-log results (not one log's results itself)."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir() or (out_dir / "run.json").is_file():
        return False
    if (out_dir / BATCH_FILE).is_file():
        return True
    return any(p.is_dir() and (p / "run.json").is_file() for p in out_dir.iterdir() if not p.name.startswith("."))
