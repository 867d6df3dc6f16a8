"""``fmcwlog report``: an output folder measured against ground truth, several compared, or a batch's fleet page."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import click

from ..evaluation.published import PAPER_FEATURE_ERROR_REDUCTION_PCT
from ..fleet.state import is_batch_folder
from ..io.atomic import check_folder_can_be_made
from .console import console
from .exits import UserError
from .paths import as_path
from .progress import progress

if TYPE_CHECKING:
    from ..evaluation.evaluate import Evaluation

_REPORT_HELP = """Measure what 'fmcwlog process' wrote in OUT_DIR against the ground truth of the
log it came from (found through run.json, or --log), and write into OUT_DIR:

\b
  report.html   one self-contained page: trajectories over the walls, error along the
                path, feature errors of both methods (the paper's Figure 4), tables, maps
  report.md     the same tables for a pull request or a lab notebook
  report.json   stable keys for scripts, e.g. methods.improved.ate_rmse_m (docs/commands/report.md)

\b
Measured for improved, baseline and wheel odometry: ATE (RMSE, mean, median, std, min,
max; SE(2)-aligned, and RMSE first-pose-aligned, as evo defines them), RPE over 1 m and 10 m (% of distance,
deg/m), each labelled feature's length in the map each method built and its error (the
paper's Tables 2 and 3, and the reduction of the average), precision/recall/F1 of the moving
points, ms per sweep. What cannot be computed is left empty with the reason.

With several OUT_DIRs, each gets its report, a comparison table and the verdicts are
printed, and --output (default: the current folder) gets what 'fmcwlog compare' writes,
compare.html (what differs between the runs, the best run per metric, verdicts beyond
the log's own spread, the errors over time overlaid) and compare.json, and the table as
comparison.md/.json.

A batch folder (what 'fmcwlog process' wrote for many logs) gets each log's report in
its folder, and fleet.html and fleet.json: a row per log (duration, distance, sweeps,
ms per sweep, warnings, why it failed, ATE and feature errors where there is ground
truth), totals, bars of each log's errors and times, each log's map as a thumbnail, and
the logs that need a look: failed ones; the outliers by ATE, feature error or (without
ground truth) the methods' disagreement, once there are at least 8 logs to tell an
outlier by (median + 3.5 x 1.4826 x MAD) and never under 5 cm ATE, 5 % feature error or
10 cm disagreement; where ICP ran out of correspondences.
"""


@click.command("report", help=_REPORT_HELP)
@click.argument("out_dirs", nargs=-1, required=True, type=click.Path(path_type=Path))
@click.option("--log", "log", type=click.Path(), callback=as_path, default=None,
              help="The log the folder was processed from (default: the one run.json names).")
@click.option("-o", "--output", "comparison_dir", type=click.Path(file_okay=False), callback=as_path, default=None,
              help="Where compare.html/.json and comparison.md/.json go when several folders are given.  [default: .]")
@click.option("--relations", type=click.Path(dir_okay=False), callback=as_path, default=None,
              help="A Freiburg relations file (t1 t2 x y z roll pitch yaw): the Kuemmerle et al. 2009 metric, "
                   "beside the published figures for that dataset.")
def report_cmd(out_dirs, log, comparison_dir, relations=None):
    if log is not None and len(out_dirs) > 1:
        raise UserError("--log goes with a single output folder")
    batches = [d for d in out_dirs if is_batch_folder(d)]
    if batches:
        if len(out_dirs) > 1 or log is not None or relations is not None:
            raise UserError(f"{batches[0]}: a batch folder is reported alone (no other folders, --log or --relations)")
        _report_fleet(batches[0])
        return
    if len(out_dirs) > 1:  # refused before any folder gets its report
        from ..evaluation.compare import check_runs

        check_runs(list(out_dirs))
        check_folder_can_be_made(comparison_dir or Path("."))
    evs = [report_evaluation(out_dir, log, relations) for out_dir in out_dirs]
    if len(evs) > 1:
        _compare(evs, comparison_dir or Path("."))


def report_folder(out_dir: Path, log: Path | None, relations: Path | None) -> dict:
    """One output folder's report (``report`` and ``run``): its tables printed, its result returned."""
    return report_evaluation(out_dir, log, relations).result


def report_evaluation(out_dir: Path, log: Path | None, relations: Path | None) -> Evaluation:
    """One output folder's report: its tables printed, its evaluation returned."""
    from ..evaluation.pages import (
        DISAGREEMENT_HEADER,
        RELATIONS_HEADER,
        TRAJECTORY_HEADER,
        change_words,
        disagreement_rows,
        relations_rows,
        terminal_table,
        trajectory_rows,
    )
    from ..evaluation.report import report

    ev = report(out_dir, log, relations)
    console.info(f"{out_dir}: {ev.result['sweeps']} sweeps of {ev.log.name}")
    if ev.gt is None and disagreement_rows(ev.result):  # a table of dashes would say nothing
        ref = ev.result["disagreement"]["reference"]
        console.info(f"no ground truth in {ev.log.name}: no errors; how far each trajectory is from the {ref} one "
                     f"once SE(2)-aligned onto it (as evo_ape -a), a disagreement, not an error:")
        console.info(terminal_table(DISAGREEMENT_HEADER, disagreement_rows(ev.result)))
    else:
        console.info(terminal_table(TRAJECTORY_HEADER[:8], [r[:8] for r in trajectory_rows(ev.result)]))
    if relations_rows(ev.result):
        console.info(terminal_table(RELATIONS_HEADER, relations_rows(ev.result)))
    scored = [r["relations"]["n"] for r in ev.result["methods"].values() if r.get("relations")]
    if relations is not None and not any(scored):  # the wrong file for this log, or stamps that never match
        console.warning(f"{relations}: none of its relations falls on this log's sweeps (each pose's stamp "
                        "must be within 1 ms of a relation's); nothing was scored")
    cmp = ev.result["feature_comparison"]
    if cmp and cmp["reduction_pct"] is not None:
        console.info(f"average feature error over the {cmp['features']} feature(s) both maps measure: "
                     f"{change_words(cmp['reduction_pct'])} (the paper: a {PAPER_FEATURE_ERROR_REDUCTION_PCT} % reduction)")
    console.info(f"wrote {ev.out_dir / 'report.html'} (and report.md, report.json)")
    return ev


def _compare(evs: list[Evaluation], target: Path) -> None:
    """Several folders side by side: the reports' table and compare's verdicts printed; in ``target``,
    comparison.md/.json and compare's page, compare.html/.json."""
    from ..evaluation.pages import comparison_rows, terminal_table
    from ..evaluation.report import compare_reported
    from .compare import said_of

    header, rows = comparison_rows([ev.result for ev in evs])
    console.info("\n" + terminal_table(header, rows))
    doc = compare_reported(evs, target)
    for line in said_of(doc):
        console.info(line)
    console.info(f"wrote {target / 'compare.html'} (and compare.json, comparison.md, comparison.json)")


def _report_fleet(out_dir: Path) -> None:
    """A batch folder: each log's report (a bar on a terminal), the fleet table, the logs that need a look."""
    from ..evaluation.fleet import FLEET_HEADER, fleet_rows, rule_sentences
    from ..evaluation.pages import terminal_table
    from ..evaluation.report import report_fleet

    with progress(None, "reporting") as bar:  # on a terminal; a batch's logs take several seconds each
        def reported(done: int, total: int, name: str) -> None:
            bar.length = total
            bar.update(1, name)

        result = report_fleet(out_dir, on_log=reported)
    t = result["totals"]
    console.info(f"{out_dir}: {t['logs']} logs, {t['done']} done, {t['failed']} failed, {t['sweeps']} sweeps, "
                 f"{t['duration_s'] / 60:.1f} min of log, {t['distance_m']:.0f} m")
    console.info(terminal_table(FLEET_HEADER, fleet_rows(result)))
    if result["flagged"]:
        console.info(f"\nneeds a look ({len(result['flagged'])}):")
        for f in result["flagged"]:
            console.info(f"  {f['name']}: " + "; ".join(f["flags"]))
    for said in rule_sentences(result)[1:]:  # per metric: ranked, or too few logs to
        console.info(said)
    for r in result["logs"]:
        if r["report_error"]:
            console.warning(f"{r['name']}: no report: {r['report_error']}")
    console.info(f"wrote {out_dir / 'fleet.html'} (and fleet.json), and each log's report.html in its folder")
