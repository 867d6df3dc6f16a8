"""``fmcwlog compare``: several runs of ``process`` side by side: a page and compare.json."""

from __future__ import annotations

from pathlib import Path

import click

from ..io.atomic import check_folder_can_be_made
from .console import console
from .paths import as_path, as_paths

_COMPARE_HELP = """Compare several runs of 'fmcwlog process' (their output folders), as one tunes a
front end: each is measured as 'fmcwlog report' measures it, and OUTPUT gets

\b
  compare.html  the runs; the run.json settings and parameters that differ between them;
                every metric per run and trajectory (ATE rmse, mean, median, std, min, max,
                RPE, heading, feature and moving-point errors, median ms per sweep) with the
                best run of each row marked; a verdict where a difference exceeds the spread;
                each trajectory's position error over time, the runs overlaid
  compare.json  the same, stable keys for scripts (docs/commands/compare.md)

\b
The spread is measured from the log's own segments: the series behind a metric (the
position errors along the path, the per-pair RPE, the time of each sweep) is cut into 5
segments, the metric computed on each; a difference counts beyond twice the two runs'
spreads combined. Runs of different logs are compared too, and the page says so.
Nothing is written into the runs' folders.

\b
Fleets: given batch folders only (what 'fmcwlog process' writes for many logs, e.g. the
same logs with two settings), the logs are paired across them by the log they were made
from (sha256), and compare.html shows what differs between the fleets, per metric (ATE
RMSE, median ms per sweep; without ground truth, how far improved and baseline part) a
group of bars per log with a bar per fleet and the best marked, a table with each
fleet's median, and a verdict only where a paired t-test on the per-log ratios says
p < 0.05 (5 paired logs at least). Logs not in every fleet are listed, not compared.
A run and a batch folder cannot be mixed.
"""


@click.command("compare", help=_COMPARE_HELP)
@click.argument("runs", nargs=-1, required=True, type=click.Path(), callback=as_paths)
@click.option("-o", "--output", type=click.Path(file_okay=False), callback=as_path, required=True,
              help="The folder compare.html and compare.json go into (made if missing).")
def compare_cmd(runs: tuple[Path, ...], output: Path) -> None:
    from ..evaluation.compare import check_runs, compare_runs, is_batch, terminal_rows
    from ..evaluation.pages import terminal_table
    if runs and is_batch(runs[0]):
        return _compare_fleets(list(runs), output)
    check_runs(list(runs))  # before any run is measured; a folder that is not a run: evaluate's one line
    check_folder_can_be_made(output)
    doc = compare_runs(list(runs), output)
    if not doc["same_log"]:
        console.warning(f"the runs come from {len(doc['logs'])} different logs: their differences mix the logs' "
                        "and the settings'")
    for d in doc["differences"]:
        console.info(f"differs: {d['key']}: " + "; ".join(f"{r['name']}={v}" for r, v in zip(doc["runs"], d["values"])))
    console.info(terminal_table(*terminal_rows(doc)))
    for line in said_of(doc):
        console.info(line)
    console.info(f"wrote {output / 'compare.html'} (and compare.json)")


def said_of(doc: dict) -> list[str]:
    """compare.json's verdicts as lines for the terminal (``compare`` and ``report`` of several runs)."""
    from ..evaluation.plots import label

    return [f"{label(row['method'])}, {row['label']}: {row['verdict']}" for row in doc["metrics"] if row["verdict"]]


def _compare_fleets(fleets: list[Path], output: Path) -> None:
    """Batch folders: their logs paired, per-log values per fleet, the fleet-level verdicts."""
    from ..evaluation.compare_fleets import check_fleets, compare_fleets, terminal_rows, verdict_lines
    from ..evaluation.pages import terminal_table
    check_fleets(fleets)  # before any log is measured
    check_folder_can_be_made(output)
    doc = compare_fleets(fleets, output)
    for u in doc["unpaired"]:
        console.warning(f"{u['name']}: only in {', '.join(u['in'])}: not compared")
    for d in doc["differences"]:
        console.info(f"differs: {d['key']}: " + "; ".join(f"{f['name']}={v}" for f, v in zip(doc["fleets"], d["values"])))
    console.info(terminal_table(*terminal_rows(doc)))
    if len(doc["logs"]) < doc["test"]["min_logs"]:
        console.warning(f"{len(doc['logs'])} paired log(s): too few to judge the fleets (at least "
                        f"{doc['test']['min_logs']} needed); the per-log values are on the page")
    else:
        for line in verdict_lines(doc) or ["no clear difference between the fleets on any metric"]:
            console.info(line)
    console.info(f"wrote {output / 'compare.html'} (and compare.json)")
