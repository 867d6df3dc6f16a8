"""``fmcwlog report OUT`` on a batch folder: one row per log, totals, and the logs a person should look at.

Each log's numbers come from its own report (:func:`fmcwlog.evaluation.evaluate.evaluate`,
written beside its results as usual) and from what ``fmcwlog process`` left in its folder
(run.json, trajectories.parquet, the TUM files); a failed log's row carries the reason
recorded in ``OUT/batch.json``. fleet.json keys (schema ``fmcwlog.fleet/1``; ``null`` where
a value cannot be computed):

- ``logs``: a row per log: ``name``, ``log``, ``status`` (done, failed), ``reason`` (why it
  failed), ``report`` (its report.html, relative to OUT), ``report_error``, ``duration_s``
  (first to last sweep), ``distance_m`` and ``distance_from`` (along the ground truth, else
  along the improved estimate), ``sweeps``, ``wall_s`` (processing time), ``ms_per_sweep``
  (median, per method), ``warnings``, ``truncated_log``, ``skipped_sweeps_share`` (the share of its
  sweeps skipped as damaged, where more than 5 %: run.json's ``many_skipped_sweeps``), ``ground_truth``, ``ate_rmse_m`` and
  ``feature_avg_rel_error_pct`` (per method, where ground truth exists),
  ``methods_disagreement_m``, ``icp_starved_sweeps`` (per method), ``flags``;
- ``totals``: counts, sums, and per method the median and worst ATE over the logs with
  ground truth;
- ``flagged``: ``{name, flags}`` of every log with a flag, worst first;
- ``outlier_rule``: ``min_logs``, ``z``, ``floors`` (per metric, in its unit) and ``metrics``: per metric
  and population ranked, ``logs``, ``too_few``, ``median`` and ``threshold`` (None when too few).

What is flagged, and why a person should look:

- a failed log (its reason: more than half of its sweeps skipped as damaged is one, unless
  ``--keep-going``), a log whose report failed, a log cut off before its summary, a log that lost
  more than 5 % of its sweeps;
- with ground truth: a log whose improved method's ATE RMSE, or average feature-length error, is an
  outlier among the logs with ground truth (:func:`outliers`);
- without ground truth: a log whose methods' disagreement is an outlier among the logs without (the
  RMSE between the improved and baseline positions at the same sweeps after the best SE(2)
  alignment of one onto the other: where two independent estimates part, at least one is
  wrong), and any log where ICP ran out of correspondences (fewer than
  ``icp.min_correspondences`` pairs, so that sweep kept its motion prior) on more than
  ``STARVED_FRACTION`` of its sweeps.

An outlier needs a sample that can show one: fewer than ``MIN_LOGS_TO_FLAG`` logs with a value and
none is flagged (the page says there are too few to tell); and a value under the metric's
``ABSOLUTE_FLOOR`` is never flagged, however far from the others (the best of a fleet of good logs
needs no look). ``outlier_rule`` in fleet.json records the rule and, per metric, how many logs it
ranked and its threshold.
"""

from __future__ import annotations

import dataclasses
import html
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from ..io.atomic import json_text, write_text
from ..io.outputs import read_tum
from ..types import BASELINE, IMPROVED, WHEEL_ODOMETRY
from .evaluate import Evaluation
from .metrics import ate

FLEET_SCHEMA = "fmcwlog.fleet/1"
MIN_LOGS_TO_FLAG = 8  # fewer logs with a value: no outlier is flagged, the sample cannot tell one
OUTLIER_Z = 3.5  # modified z-score (Iglewicz and Hoaglin, 1993) beyond which a value is an outlier
MAD_TO_SIGMA = 1.4826  # the MAD of a normal sample times this is its standard deviation
# never flagged below these, whatever the other logs do (the units are the metrics' own)
ABSOLUTE_FLOOR = {"ate_rmse_m": 0.05, "feature_avg_rel_error_pct": 5.0, "methods_disagreement_m": 0.10}
FLOOR_WORDS = {"ate_rmse_m": "5 cm ATE RMSE", "feature_avg_rel_error_pct": "5 % average feature-length error",
               "methods_disagreement_m": "10 cm RMSE disagreement between the methods"}
STARVED_FRACTION = 0.01  # more than 1 % of sweeps without enough ICP pairs
_IMPROVED, _BASELINE = IMPROVED, BASELINE


@dataclass(frozen=True)
class FleetRow:
    """One log's row of the fleet page and of fleet.json's ``logs`` (the keys: the module's docstring).

    Units: seconds (``duration_s``, ``wall_s``), metres (``distance_m``, ``ate_rmse_m``,
    ``methods_disagreement_m``), milliseconds (``ms_per_sweep``), percent
    (``feature_avg_rel_error_pct``); None where a value cannot be computed. ``flags`` is filled by
    :func:`flag_logs`.
    """

    name: str
    log: str | None
    status: str  # done, failed
    reason: str | None = None
    report: str | None = None
    report_error: str | None = None
    duration_s: float | None = None
    distance_m: float | None = None
    distance_from: str | None = None
    sweeps: int | None = None
    wall_s: float | None = None
    ms_per_sweep: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    truncated_log: bool = False
    skipped_sweeps_share: float | None = None
    ground_truth: bool = False
    ate_rmse_m: dict[str, float | None] = field(default_factory=dict)
    feature_avg_rel_error_pct: dict[str, float | None] = field(default_factory=dict)
    methods_disagreement_m: float | None = None
    icp_starved_sweeps: dict[str, int] = field(default_factory=dict)
    flags: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """The row as fleet.json holds it."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class FleetEntry:
    """One log of a batch: its folder when it holds results, and its batch.json record."""

    name: str
    folder: Path | None
    record: dict[str, Any] = field(default_factory=dict)


def _run_json(folder: Path) -> dict[str, Any]:
    try:
        doc = json.loads((folder / "run.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}
    return doc if isinstance(doc, dict) else {}


def _path_length(xy: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(xy, axis=0).T))) if len(xy) > 1 else 0.0


def starved_sweeps(table: Any, min_correspondences: int) -> dict[str, int]:
    """Per method, the sweeps where ICP ran (``icp_iterations`` > 0) but kept fewer than
    ``min_correspondences`` pairs: it gave up and the sweep kept its motion prior."""
    method = np.asarray(table.column("method").to_pylist(), dtype=object)
    it = np.asarray(table.column("icp_iterations").to_pylist(), dtype=object)
    kept = np.asarray(table.column("correspondences").to_pylist(), dtype=object)
    out = {}
    for m in sorted(set(method) - {WHEEL_ODOMETRY}):
        sel = (method == m) & np.array([i is not None for i in it]) & np.array([k is not None for k in kept])
        if sel.any():
            out[str(m)] = int(np.sum((it[sel].astype(int) > 0) & (kept[sel].astype(int) < min_correspondences)))
    return out


def methods_disagreement(folder: Path) -> float | None:
    """RMSE (m) between the improved and baseline positions at their common sweeps, after the
    best SE(2) alignment of the baseline onto the improved trajectory; None without both."""
    a, b = folder / f"{_IMPROVED}.tum", folder / f"{_BASELINE}.tum"
    if not (a.is_file() and b.is_file()):
        return None
    ta, pa_ = read_tum(a)
    tb, pb = read_tum(b)
    common, ia, ib = np.intersect1d(np.round(ta, 6), np.round(tb, 6), return_indices=True)
    if len(common) < 3:
        return None
    return float(ate(pb[ib], pa_[ia], "se2").rmse)


def _from_folder(row: dict[str, Any], folder: Path) -> tuple[float, float] | None:
    """What ``fmcwlog process`` left: counts, timings, warnings, duration, disagreement, starved ICP;
    returns the first and last sweep's time (s)."""
    run = _run_json(folder)
    row.update(sweeps=run.get("sweeps", row["sweeps"]), wall_s=run.get("wall_seconds", row["wall_s"]),
               warnings=list(run.get("warnings") or []), truncated_log=bool(run.get("truncated_log")),
               ms_per_sweep=dict(run.get("ms_per_sweep_median") or {}))
    skipped = run.get("many_skipped_sweeps")
    if isinstance(skipped, dict) and isinstance(skipped.get("share"), (int, float)):
        row["skipped_sweeps_share"] = float(skipped["share"])
    row["log"] = row["log"] or run.get("log")
    min_corr = int(((run.get("params") or {}).get("icp") or {}).get("min_correspondences", 10))
    try:
        with open(folder / "trajectories.parquet", "rb") as fh:  # Arrow takes a path as UTF-8; a name need not be
            table = pq.read_table(fh, columns=["method", "t", "icp_iterations", "correspondences"],
                                  use_threads=False)  # one thread: evaluate._check_parquet says why
    except (OSError, ValueError, KeyError):
        return None
    t = table.column("t").to_numpy()
    span = (float(t.min()), float(t.max())) if len(t) else None
    if span is not None:
        row["duration_s"] = span[1] - span[0]
    row["icp_starved_sweeps"] = starved_sweeps(table, min_corr)
    row["methods_disagreement_m"] = methods_disagreement(folder)
    est = folder / f"{_IMPROVED}.tum"
    if est.is_file():
        row["distance_m"], row["distance_from"] = _path_length(read_tum(est)[1][:, :2]), f"{_IMPROVED} estimate"
    return span


def _from_report(row: dict[str, Any], ev: Evaluation, span: tuple[float, float] | None) -> None:
    """ATE and feature errors from the log's report; the distance along the ground truth."""
    methods = ev.result.get("methods", {})
    row["ate_rmse_m"] = {m: r.get("ate_rmse_m") for m, r in methods.items()}
    row["feature_avg_rel_error_pct"] = {m: r.get("feature_avg_rel_error_pct") for m, r in methods.items()
                                        if m != WHEEL_ODOMETRY}
    row["ground_truth"] = ev.gt is not None
    if ev.gt is not None and ev.gt_t is not None and span is not None:
        inside = (ev.gt_t >= span[0]) & (ev.gt_t <= span[1])
        row["distance_m"], row["distance_from"] = _path_length(ev.gt[inside, :2]), "ground truth"


def log_row(entry: FleetEntry, ev: Evaluation | None, report_error: str | None = None) -> FleetRow:
    """One log's row of the fleet page (keys: the module's docstring)."""
    rec = entry.record
    failed = rec.get("status") == "failed"
    row: dict[str, Any] = {
        "name": entry.name, "log": rec.get("log"), "status": "failed" if failed else "done",
        "reason": rec.get("reason") if failed else None,
        "report": f"{entry.name}/report.html" if ev is not None else None, "report_error": report_error,
        "duration_s": None, "distance_m": None, "distance_from": None, "sweeps": None if failed else rec.get("sweeps"),
        "wall_s": rec.get("wall_s"), "ms_per_sweep": {}, "warnings": [], "truncated_log": False,
        "ground_truth": False, "ate_rmse_m": {}, "feature_avg_rel_error_pct": {}, "methods_disagreement_m": None,
        "icp_starved_sweeps": {}, "flags": [],
    }
    if entry.folder is not None and not failed:
        span = _from_folder(row, entry.folder)
        if ev is not None:
            _from_report(row, ev, span)
    return FleetRow(**row)


def _primary(row: FleetRow, key: str) -> tuple[str, float] | None:
    vals = getattr(row, key)
    for m in (_IMPROVED, _BASELINE):
        if vals.get(m) is not None:
            return m, float(vals[m])
    return None


@dataclass(frozen=True)
class OutlierTest:
    """What :func:`outliers` found for one metric over one population of logs.

    ``threshold`` is in the metric's unit (None when too few logs); ``flagged`` indexes the values given.
    """

    n: int
    median: float | None
    threshold: float | None
    flagged: tuple[int, ...]

    @property
    def too_few(self) -> bool:
        """Fewer values than :data:`MIN_LOGS_TO_FLAG`: nothing could be flagged."""
        return self.n < MIN_LOGS_TO_FLAG


def outliers(values: list[float], floor: float, min_logs: int = MIN_LOGS_TO_FLAG, z: float = OUTLIER_Z) -> OutlierTest:
    """Which of ``values`` (one per log, larger is worse, any unit) are outliers worth a person's look.

    A value is flagged when all three hold:

    - there are at least ``min_logs`` values (with fewer, the median and the spread say too little:
      with three logs, "4 times the median" is one bad draw);
    - it lies above ``median + z * 1.4826 * MAD`` (MAD: the median absolute deviation from the
      median; 1.4826 * MAD estimates the standard deviation of normal data and, unlike the standard
      deviation, is not pulled up by the outliers themselves; z = 3.5 is Iglewicz and Hoaglin's
      modified z-score cut-off); with MAD = 0 (most values equal) any value above the median passes
      this test and the floor decides;
    - it is at least ``floor`` (same unit as ``values``): small in absolute terms is never worth a look.
    """
    n = len(values)
    if n < min_logs:
        return OutlierTest(n, float(np.median(values)) if n else None, None, ())
    v = np.asarray(values, dtype=float)
    median = float(np.median(v))
    threshold = median + z * MAD_TO_SIGMA * float(np.median(np.abs(v - median)))
    flagged = tuple(int(i) for i in np.flatnonzero((v > threshold) & (v >= floor)))
    return OutlierTest(n, median, max(threshold, floor), flagged)


def _flag_outliers(rows: list[FleetRow], value: Callable[[FleetRow], float | None],
                   describe: Callable[[FleetRow, float], str], fmt: Callable[[float], str], key: str,
                   population: str) -> dict[str, Any]:
    """Flag the rows whose ``value`` is an outlier (:func:`outliers`, the floor of ``key``); returns
    fleet.json's ``outlier_rule.metrics`` entry for this metric and population."""
    scored = [(v, r) for r in rows if (v := value(r)) is not None]
    test = outliers([v for v, _ in scored], ABSOLUTE_FLOOR[key])
    for i in test.flagged:
        v, r = scored[i]
        r.flags.append(f"{describe(r, v)}: an outlier among the {test.n} logs {population} (their median "
                       f"{fmt(test.median or 0.0)}; flagged above {fmt(test.threshold or 0.0)})")
    return {"metric": key, "population": population, "logs": test.n, "too_few": test.too_few,
            "median": test.median, "threshold": test.threshold, "floor": ABSOLUTE_FLOOR[key]}


def flag_logs(rows: list[FleetRow]) -> list[dict[str, Any]]:
    """Add to each row's ``flags`` why a person should look at it (see the module's docstring); returns
    per metric and population what the outlier rule ranked (fleet.json's ``outlier_rule.metrics``)."""
    for r in rows:
        if r.status == "failed":
            r.flags.append(f"failed: {r.reason}")
        if r.report_error:
            r.flags.append(f"no report: {r.report_error}")
        if r.truncated_log:
            r.flags.append("the log is cut off before its summary: processed up to where it ends")
        if r.skipped_sweeps_share is not None:
            r.flags.append(f"{100 * r.skipped_sweeps_share:.1f} % of its sweeps skipped as damaged: the results stand "
                           "on the rest (its warnings say why)")
    done = [r for r in rows if r.status == "done"]
    with_gt = [r for r in done if r.ground_truth]
    without = [r for r in done if not r.ground_truth]
    ranked: list[dict[str, Any]] = []

    def by(key: str, what: str, fmt: Callable[[float], str]) -> None:
        def value(r: FleetRow) -> float | None:
            p = _primary(r, key)
            return None if p is None else p[1]

        def describe(r: FleetRow, v: float) -> str:
            p = _primary(r, key)
            return f"{what} {fmt(v)} ({p[0] if p else '?'})"

        if with_gt:
            ranked.append(_flag_outliers(with_gt, value, describe, fmt, key, "with ground truth"))

    by("ate_rmse_m", "ATE RMSE", _cm)
    by("feature_avg_rel_error_pct", "feature error", lambda v: f"{v:.2f} %")
    if any(r.methods_disagreement_m is not None for r in without):
        ranked.append(_flag_outliers(without, lambda r: r.methods_disagreement_m,
                                     lambda r, v: f"improved and baseline disagree by {_cm(v)} RMSE", _cm,
                                     "methods_disagreement_m", "without ground truth"))
    for r in without:
        sweeps = max(int(r.sweeps or 0), 1)
        for m, n in r.icp_starved_sweeps.items():
            if n > STARVED_FRACTION * sweeps:
                r.flags.append(f"ICP ({m}) ran out of correspondences on {n} of {sweeps} sweeps")
    return ranked


def _cm(v: float) -> str:
    return f"{v * 100:.1f} cm"


def _totals(rows: list[FleetRow], batch: dict[str, Any]) -> dict[str, Any]:
    done = [r for r in rows if r.status == "done"]
    total = lambda key: float(sum(getattr(r, key) or 0 for r in done))
    sweeps = int(total("sweeps"))
    wall = batch.get("wall_s")  # the last 'fmcwlog process' run over this folder
    per_method: dict[str, dict[str, float | None]] = {}
    for m in sorted({m for r in done for m in r.ate_rmse_m}):
        vals = [v for r in done if (v := r.ate_rmse_m.get(m)) is not None]
        if vals:
            per_method[m] = {"ate_rmse_m_median": float(np.median(vals)), "ate_rmse_m_max": float(np.max(vals)),
                             "logs": len(vals)}
    return {"logs": len(rows), "done": len(done), "failed": len(rows) - len(done),
            "with_ground_truth": sum(r.ground_truth for r in done), "sweeps": sweeps,
            "duration_s": total("duration_s"), "distance_m": total("distance_m"), "processing_s": total("wall_s"),
            "batch_wall_s": wall, "methods": per_method}


def fleet_result(out_dir: Path, rows: list[FleetRow], batch: dict[str, Any]) -> dict[str, Any]:
    """fleet.json's document: rows flagged, totals, the flagged logs (most flags first)."""
    ranked = flag_logs(rows)
    flagged = sorted((r for r in rows if r.flags), key=lambda r: (r.status != "failed", -len(r.flags), r.name))
    return {"schema": FLEET_SCHEMA, "out_dir": str(out_dir), "executor": batch.get("executor"),
            "options_sha256": batch.get("options_sha256"), "totals": _totals(rows, batch),
            "flagged": [{"name": r.name, "flags": r.flags} for r in flagged], "logs": [r.to_json() for r in rows],
            "outlier_rule": {"min_logs": MIN_LOGS_TO_FLAG, "z": OUTLIER_Z, "floors": dict(ABSOLUTE_FLOOR),
                             "metrics": ranked}}


def _fmt(x: Any, digits: int = 1, scale: float = 1.0) -> str:
    return "—" if x is None else f"{x * scale:.{digits}f}"


FLEET_HEADER = ["log", "status", "duration s", "distance m", "sweeps", "ms/sweep improved", "ATE cm improved",
                "ATE cm baseline", "feature err % improved", "disagreement cm", "ICP starved", "warnings", "flags"]


def fleet_rows(result: dict[str, Any]) -> list[list[str]]:
    out = []
    for r in result["logs"]:
        out.append([r["name"], r["status"], _fmt(r["duration_s"]), _fmt(r["distance_m"]), str(r["sweeps"] or "—"),
                    _fmt(r["ms_per_sweep"].get(_IMPROVED), 2), _fmt(r["ate_rmse_m"].get(_IMPROVED), 1, 100),
                    _fmt(r["ate_rmse_m"].get(_BASELINE), 1, 100),
                    _fmt(r["feature_avg_rel_error_pct"].get(_IMPROVED), 2),
                    _fmt(r["methods_disagreement_m"], 1, 100),
                    str(sum(r["icp_starved_sweeps"].values())) if r["icp_starved_sweeps"] else "—",
                    str(len(r["warnings"])), str(len(r["flags"]))])
    return out


def _cell(text: str, link: str | None = None) -> str:
    body = html.escape(text)
    return f'<td><a href="{html.escape(link)}">{body}</a></td>' if link else f"<td>{body}</td>"


def render_fleet_html(result: dict[str, Any], figures: dict[str, str] | None = None) -> str:
    """fleet.html: totals, the logs that need a look and the rule that flagged them, the figures
    (``figures``: :func:`fmcwlog.evaluation.fleet_plots.fleet_plots`'s data URIs; none without), the
    table of every log, the warnings."""
    figures = figures or {}
    t = result["totals"]
    rows_html = []
    for r, cells in zip(result["logs"], fleet_rows(result)):
        tds = [_cell(cells[0], r["report"])] + [_cell(c) for c in cells[1:]]
        cls = ' class="failed"' if r["status"] == "failed" else (' class="flagged"' if r["flags"] else "")
        rows_html.append(f"<tr{cls}>{''.join(tds)}</tr>")
    head = "".join(f"<th>{html.escape(h)}</th>" for h in FLEET_HEADER)
    by_name = {r["name"]: r for r in result["logs"]}
    flagged = "".join(
        f"<li><b>{_link(by_name[f['name']])}</b><ul>{''.join(f'<li>{html.escape(x)}</li>' for x in f['flags'])}</ul></li>"
        for f in result["flagged"])
    method_rows = "".join(f"<tr><td>{html.escape(m)}</td><td>{v['logs']}</td><td>{_fmt(v['ate_rmse_m_median'], 1, 100)}"
                          f"</td><td>{_fmt(v['ate_rmse_m_max'], 1, 100)}</td></tr>" for m, v in t["methods"].items())
    warn = "".join(f"<li><b>{html.escape(r['name'])}</b>: {html.escape(w)}</li>" for r in result["logs"]
                   for w in r["warnings"])
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>fmcwlog fleet: {html.escape(Path(result['out_dir']).name)}</title>
<style>
body {{ font-family: system-ui, sans-serif; max-width: 1300px; margin: 2em auto; padding: 0 1em; color: #222; }}
table {{ border-collapse: collapse; margin: 1em 0; font-size: 0.88em; }}
th, td {{ border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: right; }}
th {{ background: #f3f3f3; }} td:first-child, th:first-child {{ text-align: left; }}
tr.failed td {{ background: #fde0e0; }} tr.flagged td {{ background: #fff4d6; }}
figure {{ margin: 1em 0; }} img {{ max-width: 100%; border: 1px solid #eee; }}
figcaption {{ font-size: 0.85em; color: #555; }}
.thumbs {{ display: flex; flex-wrap: wrap; gap: 0.8em; }} .thumbs figure {{ margin: 0; width: 262px; }}
.thumbs figure.flagged img {{ border: 2px solid #b71c1c; }}
</style></head><body>
<h1>fmcwlog fleet: {html.escape(result['out_dir'])}</h1>
<p>{t['logs']} logs: {t['done']} done, {t['failed']} failed; {t['with_ground_truth']} with ground truth.
{t['sweeps']} sweeps, {_fmt(t['duration_s'] / 3600, 2)} h of log, {_fmt(t['distance_m'] / 1000, 2)} km;
{_fmt(t['processing_s'])} s of processing{_batch_rate(t)}.</p>
<h2>Needs a look ({len(result['flagged'])})</h2>
{"<ul>" + flagged + "</ul>" if flagged else "<p>Nothing flagged.</p>"}
{_rule_html(result)}
<h2>ATE over the logs with ground truth</h2>
{_ate_table(method_rows)}
{_figure(figures, "errors", "errors per log: ATE RMSE per method (logs with ground truth), how far the methods "
         "part (logs without); dashed, the outlier threshold where there were logs enough to rank; a flagged "
         "log's name in red")}
{_figure(figures, "times", "time per log: processing wall-clock time, and each method's median ms per sweep")}
{_thumbnails_html(result, figures)}
<h2>Every log</h2>
<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows_html)}</tbody></table>
<p>Each log's name links to its own report. Disagreement: RMSE between the improved and baseline positions
after the best SE(2) alignment of one onto the other. ICP starved: sweeps where ICP kept fewer pairs than
it needs and the sweep kept its motion prior.</p>
<h2>Warnings</h2>{"<ul>" + warn + "</ul>" if warn else "<p>None.</p>"}
</body></html>
"""


def _figure(figures: dict[str, str], key: str, caption: str) -> str:
    if key not in figures:
        return ""
    return (f'<figure><img alt="{html.escape(caption)}" src="{figures[key]}"><figcaption>{html.escape(caption)}'
            "</figcaption></figure>")


def _thumbnails_html(result: dict[str, Any], figures: dict[str, str]) -> str:
    """Each log's map thumbnail (flagged logs first, outlined), its name linking to its report."""
    by_name = {r["name"]: r for r in result["logs"]}
    flagged = {f["name"] for f in result["flagged"]}
    names = [k.split(":", 1)[1] for k in figures if k.startswith("map:")]
    if not names:
        return ""
    outlined = ' class="flagged"'
    items = "".join(
        f'<figure{outlined if n in flagged else ""}><img alt="map of {html.escape(n)}" '
        f'src="{figures["map:" + n]}"><figcaption>{_link(by_name[n])}</figcaption></figure>' for n in names)
    done = sum(r["status"] == "done" for r in result["logs"])
    more = f"<p>{done - len(names)} more logs: their maps are in their reports.</p>" if done > len(names) else ""
    return (f"<h2>Maps</h2><p>The map each log's improved method built (the baseline's where there is none), "
            f"with its trajectory; flagged logs first, outlined in red.</p><div class=\"thumbs\">{items}</div>{more}")


def rule_sentences(result: dict[str, Any]) -> list[str]:
    """The outlier rule in words, and per metric whether the fleet had logs enough to rank (the page and
    the terminal say the same)."""
    rule = result.get("outlier_rule") or {}
    out = [f"Outliers: a log is flagged by a metric when at least {rule.get('min_logs', MIN_LOGS_TO_FLAG)} logs have "
           f"it and its value lies above the median + {rule.get('z', OUTLIER_Z):g} × 1.4826 × MAD of those logs "
           "(a modified z-score over 3.5, robust to the outliers themselves), and never below "
           + ", ".join(FLOOR_WORDS[k] for k in ABSOLUTE_FLOOR) + f"; failed logs, logs whose report failed, cut "
           f"off or with many damaged sweeps, and logs where ICP ran out of correspondences on more than "
           f"{STARVED_FRACTION:.0%} of the sweeps are flagged whatever their number."]
    for m in rule.get("metrics", []):
        what = _METRIC_WORDS.get(m["metric"], m["metric"])
        if m["too_few"]:
            out.append(f"Too few logs {m['population']} to flag outliers by {what}: {m['logs']} "
                       f"(at least {rule.get('min_logs', MIN_LOGS_TO_FLAG)} needed).")
        else:
            unit = _unit(m["metric"])
            out.append(f"{what[0].upper()}{what[1:]}: {m['logs']} logs {m['population']}, median {unit(m['median'])}, "
                       f"flagged above {unit(m['threshold'])}.")
    return out


_METRIC_WORDS = {"ate_rmse_m": "ATE RMSE", "feature_avg_rel_error_pct": "feature error",
                 "methods_disagreement_m": "the methods' disagreement"}


def _unit(metric: str) -> Callable[[float], str]:
    return (lambda v: f"{v:.2f} %") if metric.endswith("_pct") else _cm


def _rule_html(result: dict[str, Any]) -> str:
    return "".join(f"<p>{html.escape(s)}</p>" for s in rule_sentences(result))


def _ate_table(method_rows: str) -> str:
    if not method_rows:
        return "<p>No log has ground truth.</p>"
    return ("<table><thead><tr><th>method</th><th>logs</th><th>median ATE RMSE cm</th><th>worst ATE RMSE cm</th></tr>"
            f"</thead><tbody>{method_rows}</tbody></table>")


def _link(row: dict[str, Any]) -> str:
    name = html.escape(row["name"])
    return f'<a href="{html.escape(row["report"])}">{name}</a>' if row["report"] else name


def _batch_rate(t: dict[str, Any]) -> str:
    if not t["batch_wall_s"]:
        return ""
    return f"; the last batch took {_fmt(t['batch_wall_s'])} s"


def write_fleet(out_dir: Path, result: dict[str, Any]) -> list[Path]:
    """fleet.json and fleet.html in ``out_dir`` (each through a temporary name)."""
    write_text(out_dir / "fleet.json", json_text(result))
    from .fleet_plots import fleet_plots

    write_text(out_dir / "fleet.html", render_fleet_html(result, fleet_plots(out_dir, result)))
    return [out_dir / "fleet.json", out_dir / "fleet.html"]
