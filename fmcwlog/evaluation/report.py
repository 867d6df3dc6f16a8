"""Reports written: one output folder's page and data, a batch's fleet page, a comparison of several.

``fmcwlog report`` calls these. Every page is written whole or not at all (a full disk leaves
the folder as it was).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import FmcwlogError, ReportError
from ..fleet.state import is_batch_folder, read_batch
from ..io.atomic import add_to_marker, atomic_batch, created_parents, json_text, reported_write_errors, write_text
from .evaluate import Evaluation, evaluate
from .fleet import FleetEntry, fleet_result, log_row, write_fleet
from .pages import comparison_rows, markdown_table, write_report

logger = logging.getLogger(__name__)


def report(out_dir: str | Path, log: str | Path | None = None,
           relations: str | Path | None = None) -> Evaluation:
    """:func:`evaluate` ``out_dir`` and write report.html, report.md and report.json into it:
    all of them or, if any write fails (a full disk), none."""
    ev = evaluate(out_dir, log, relations=relations)
    with reported_write_errors(ev.out_dir), atomic_batch():
        add_to_marker(ev.out_dir, write_report(ev))
    return ev


def report_fleet(out_dir: str | Path, on_log: Callable[[int, int, str], None] | None = None) -> dict[str, Any]:
    """:func:`report` every log folder of a batch (``process_many``'s ``out_dir``), then write
    fleet.json and fleet.html there; returns fleet.json's document
    (:mod:`fmcwlog.evaluation.fleet`). A log whose report fails gets the reason in its row.
    ``on_log(done, total, name)`` is called as each log is reported (several seconds each)."""
    out_dir = Path(out_dir)
    if not is_batch_folder(out_dir):
        raise ReportError(f"{out_dir}: not a batch folder (no batch.json, no log folders with run.json)")
    batch = read_batch(out_dir)
    names = set(batch["logs"]) | {p.name for p in out_dir.iterdir()
                                  if p.is_dir() and not p.name.startswith(".") and (p / "run.json").is_file()}
    rows = []
    for i, name in enumerate(sorted(names), 1):
        folder = out_dir / name
        entry = FleetEntry(name, folder if (folder / "run.json").is_file() else None, batch["logs"].get(name, {}))
        ev, error = None, None
        if entry.folder is not None and entry.record.get("status") != "failed":
            try:
                ev = report(entry.folder)
            except FmcwlogError as exc:
                error = str(exc)
        rows.append(log_row(entry, ev, error))
        logger.debug("%s: reported", name)
        if on_log is not None:
            on_log(i, len(names), name)
    result = fleet_result(out_dir, rows, batch)
    write_fleet(out_dir, result)
    return result


def compare(results: list[dict], target: str | Path) -> Path:
    """comparison.md and comparison.json of several reports' results in ``target``; returns the .md."""
    target = Path(target)
    with reported_write_errors(target), created_parents(target / "comparison.md"), atomic_batch():
        for name, text in _comparison_tables(results).items():
            write_text(target / name, text)
    return target / "comparison.md"


def compare_reported(evs: Sequence[Evaluation], target: str | Path) -> dict[str, Any]:
    """What ``report`` writes for several folders, in ``target``: comparison.md and comparison.json (the
    reports' tables) and ``compare``'s page, compare.html and compare.json
    (:func:`fmcwlog.evaluation.compare.comparison_pages`): all four or, if a write fails, none.
    Returns compare.json's document."""
    from .compare import check_runs, comparison_pages

    check_runs([ev.out_dir for ev in evs])
    doc, pages = comparison_pages(evs)
    target = Path(target)
    with reported_write_errors(target), created_parents(target / "comparison.md"), atomic_batch():
        for name, text in {**_comparison_tables([ev.result for ev in evs]), **pages}.items():
            write_text(target / name, text)
    return doc


def _comparison_tables(results: list[dict]) -> dict[str, str]:
    header, rows = comparison_rows(results)
    return {"comparison.md": markdown_table(header, rows) + "\n", "comparison.json": json_text(results)}
