"""Many CARMEN logs imported at once: ``fmcwlog import carmen FILE_OR_FOLDER... -o OUT``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import FmcwlogError
from ..io.carmen_import import ImportSummary, import_carmen
from .inputs import CARMEN_PATTERNS, find_logs, unique_names


@dataclass
class ImportOutcome:
    """One source of :func:`import_carmen_many`: ``status`` done, skipped (its output exists) or failed."""

    source: Path
    output: Path
    status: str
    reason: str | None = None
    summary: ImportSummary | None = None
    format: str | None = None


def import_carmen_many(paths: Sequence[str | Path], out_dir: str | Path, force: bool = False) -> list[ImportOutcome]:
    """:func:`import_carmen` every CARMEN log that ``paths`` name (files, or folders searched for
    ``*.clf``, ``*.log``, plain, ``.gz`` or ``.xz``) into ``out_dir/<name>.mcap`` (names as
    :mod:`fmcwlog.fleet.inputs` gives them). An existing output is kept unless ``force``; a
    source that cannot be read is reported in its outcome and the others go on."""
    out_dir = Path(out_dir)
    sources = find_logs(paths, CARMEN_PATTERNS, skip=out_dir, rosbag2=False)
    outcomes = []
    for src, name in zip(sources, unique_names(sources, CARMEN_PATTERNS)):
        out = out_dir / f"{name}.mcap"
        if out.exists() and not force:
            outcomes.append(ImportOutcome(src, out, "skipped", f"{out}: exists; use --force to convert it again"))
            continue
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
            summary, fmt = import_carmen(src, out)
        except (FmcwlogError, OSError, EOFError, UnicodeDecodeError) as exc:
            outcomes.append(ImportOutcome(src, out, "failed", f"{src}: cannot import ({exc})"
                                          if not isinstance(exc, FmcwlogError) else str(exc)))
            continue
        outcomes.append(ImportOutcome(src, out, "done", summary=summary, format=fmt))
    return outcomes
