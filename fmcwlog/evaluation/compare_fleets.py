"""``fmcwlog compare FLEET_A FLEET_B ...``: batch folders (fleets) side by side, log by log.

"The same logs with setting A and with setting B: which is better, on which logs, by how much?"
Each fleet is a folder ``fmcwlog process`` wrote for many logs (:func:`fmcwlog.fleet.state.is_batch_folder`).
Its log folders are paired across the fleets by the log they were made from
(:func:`fmcwlog.evaluation.compare.log_identity`: run.json's sha256 of the log, else the log's file
name); a log present in only some fleets is listed, not compared. Each paired log's run is measured as
``fmcwlog report`` measures it (:func:`fmcwlog.evaluation.evaluate.evaluate`, nothing written into the
fleets' folders), on the main metrics: per trajectory the ATE RMSE (logs with ground truth) and the
median ms per sweep, and for logs without ground truth what the fleet page ranks them by, how far the
improved and baseline trajectories part (:func:`fmcwlog.evaluation.fleet.methods_disagreement`).

**The fleet-level verdict** (:func:`paired_test`). For two fleets A and B and one metric, each log
with a value in both gives the log-ratio d_i = ln(b_i / a_i) (a ratio, so that a crowded log's
centimetres and a corridor's millimetres weigh alike). Over the n such logs, with the mean
d̄ = Σ d_i / n, the standard deviation s = √(Σ (d_i − d̄)² / (n − 1)) and the standard error
SE = s / √n, the difference is clear where n ≥ :data:`MIN_PAIRED_LOGS` and
|d̄| > t₀.₉₇₅,ₙ₋₁ × SE (a two-sided paired t-test on the log-ratios at p < 0.05; t₀.₉₇₅,₄ = 2.78 for
5 logs, 2.09 for 20); only then is there a verdict, giving B's value as exp(d̄) times A's (the
geometric mean of the per-log ratios) and on how many logs it is lower. Every log differing by the
same ratio (SE = 0, d̄ ≠ 0) is clear; the same value on every log (d̄ = 0) never is. With fewer than
:data:`MIN_PAIRED_LOGS` paired logs the page says there are too few to judge. A log where either value
is not positive is left out of the test.

compare.json (schema ``fmcwlog.compare_fleets/1``; values in the units of report.json's keys):

- ``fleets``: per fleet ``name`` (its folder's name, its parent's too where two share one),
  ``out_dir``, ``logs`` (log folders with results), ``failed`` (``name`` and ``reason`` of each log
  its batch.json records as failed), ``options_sha256`` (batch.json's);
- ``logs``: the paired logs: ``id`` (the log's sha256 or file name), ``name`` (its folder's name in
  the first fleet), ``folders`` (per fleet, its folder's name there);
- ``unpaired``: the logs present in only some fleets: ``id``, ``name``, ``in`` (those fleets' names);
- ``differences``: the run.json settings and parameters that differ between the fleets
  (:func:`fmcwlog.evaluation.compare.differences` on each paired log's runs): ``key``, ``values`` (per
  fleet) and ``varies`` (true where the logs do not all differ alike; ``values`` is then the first
  paired log's);
- ``test``: ``method`` (the rule above in words), ``alpha`` (0.05), ``min_logs``;
- ``metrics``: per trajectory and metric: ``method``, ``metric`` (report.json's key, or
  ``methods_disagreement_m``), ``label``, ``unit``, ``scale`` (from report.json's unit to ``unit``),
  ``better`` (``lower``), ``values`` (per paired log, per fleet; ``null`` where not measured),
  ``best`` (per log, the fleets with its best value), ``medians`` (per fleet, over the paired logs
  with a value) and ``comparisons``: per pair of fleets (``a``, ``b``) ``logs`` (n), ``ratio``
  (exp d̄), ``mean_log_ratio``, ``standard_error``, ``critical`` (t₀.₉₇₅,ₙ₋₁), ``lower_in_b`` and
  ``higher_in_b`` (logs), ``clear``, ``verdict`` (a sentence or ``null``) and ``why_not`` (why there
  is none);
- ``notes``: what the comparison could not do, and why.
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import FmcwlogError, ReportError
from ..fleet.state import read_batch
from ..io.atomic import atomic_batch, created_parents, json_text, reported_write_errors, write_text
from .compare import (
    METRICS,
    Metric,
    _cell,
    _table,
    check_distinct,
    differences,
    differences_html,
    is_batch,
    log_identity,
    run_names,
)
from .evaluate import Evaluation, evaluate
from .fleet import methods_disagreement
from .plots import label

SCHEMA = "fmcwlog.compare_fleets/1"
MIN_PAIRED_LOGS = 5  # fewer paired logs: too few to judge a fleet-level difference
ALPHA = 0.05  # two-sided significance of the paired t-test
DISAGREEMENT = "improved vs baseline"  # the trajectory name of the methods' disagreement rows
_DISAGREEMENT_METRIC = Metric("methods_disagreement_m", "disagreement (logs without ground truth)", "cm", 100.0)
FLEET_METRICS: tuple[Metric, ...] = tuple(m for m in METRICS if m.key in ("ate_rmse_m", "ms_per_sweep_median"))
TEST_METHOD = (f"per log, the ratio of the two fleets' values, d = ln(B / A); over the n logs with both, the mean d̄, "
               f"its standard error SE = s / √n (s: the standard deviation of d, n − 1 in its denominator); a "
               f"difference is clear where n ≥ {MIN_PAIRED_LOGS} and |d̄| > t(0.975, n − 1) × SE (a two-sided "
               f"paired t-test on the log-ratios, p < {ALPHA:g}); B is then exp(d̄) times A (the geometric mean of "
               "the per-log ratios)")


@dataclass(frozen=True)
class FleetLog:
    """One log folder of a fleet: its folder's ``name``, ``folder`` and run.json (``run``)."""

    name: str
    folder: Path
    run: dict[str, Any]


def fleet_logs(out_dir: Path) -> list[FleetLog]:
    """The log folders of a batch folder that hold a run (run.json), in name order."""
    out = []
    for p in sorted(out_dir.iterdir()):
        if p.name.startswith(".") or not p.is_dir() or not (p / "run.json").is_file():
            continue
        try:
            run = json.loads((p / "run.json").read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ReportError(f"{p / 'run.json'}: unreadable ({exc})") from exc
        out.append(FleetLog(p.name, p, run if isinstance(run, dict) else {}))
    return out


def check_fleets(out_dirs: Sequence[Path]) -> None:
    """Refuse, in one line naming the folder: fewer than two fleets, a folder given twice, a folder that
    is not a batch folder (a single run among fleets included)."""
    check_distinct(out_dirs, "fleets", "'fmcwlog report' gives one fleet's page")
    for d in out_dirs:
        if not d.is_dir():
            raise ReportError(f"{d}: no such folder")
        if not is_batch(d):
            raise ReportError(f"{d}: a single run among batch folders; compare fleets with fleets only, or runs "
                              "with runs")


def compare_fleets(out_dirs: Sequence[str | Path], target: str | Path) -> dict[str, Any]:
    """Measure each fleet's logs as ``report`` does, pair them by log, and write compare.html and
    compare.json into ``target`` (both or, if a write fails, neither); returns compare.json's
    document (module docstring)."""
    dirs = [Path(d) for d in out_dirs]
    check_fleets(dirs)
    doc = fleet_comparison(dirs)
    target = Path(target)
    pages = {"compare.json": json_text(doc), "compare.html": render_fleets_html(doc)}
    with reported_write_errors(target), created_parents(target / "compare.html"), atomic_batch():
        for name, text in pages.items():
            write_text(target / name, text)
    return doc


def _pair(fleets: list[list[FleetLog]], names: Sequence[str]) -> tuple[list[dict], list[dict], list[str]]:
    """The logs present in every fleet (paired), those in only some, and notes (a log twice in one fleet)."""
    notes = []
    by_id: list[dict[str, FleetLog]] = []
    for fleet, name in zip(fleets, names):
        ids: dict[str, FleetLog] = {}
        for lg in fleet:
            key = log_identity(lg.run)
            if key in ids:
                notes.append(f"{name}: {lg.name} and {ids[key].name} are runs of one log; {ids[key].name} is compared")
                continue
            ids[key] = lg
        by_id.append(ids)
    order = list(dict.fromkeys(k for ids in by_id for k in ids))
    paired: list[dict[str, Any]] = []
    unpaired: list[dict[str, Any]] = []
    for key in order:
        present = [ids.get(key) for ids in by_id]
        first = next(p for p in present if p is not None)
        if all(p is not None for p in present):
            paired.append({"id": key, "name": first.name, "folders": [p.name for p in present if p is not None]})
        else:
            unpaired.append({"id": key, "name": first.name, "in": [n for n, p in zip(names, present) if p is not None]})
    paired.sort(key=lambda r: r["name"])
    unpaired.sort(key=lambda r: r["name"])
    return paired, unpaired, notes


def fleet_comparison(dirs: Sequence[Path]) -> dict[str, Any]:
    """compare.json's document for the fleets in ``dirs`` (a paired log's run that cannot be measured
    has no values; a note says why)."""
    names = run_names(dirs)
    fleets = [fleet_logs(d) for d in dirs]
    paired, unpaired, notes = _pair(fleets, names)
    evs: list[list[Evaluation | None]] = []
    for lg in paired:
        row: list[Evaluation | None] = []
        for d, name, folder in zip(dirs, names, lg["folders"]):
            try:
                row.append(evaluate(d / folder))
            except FmcwlogError as exc:
                notes.append(f"{name}/{folder}: not measured: {exc}")
                row.append(None)
        evs.append(row)
    batches = [read_batch(d) for d in dirs]
    failed = [[{"name": n, "reason": r.get("reason")} for n, r in b["logs"].items() if r.get("status") == "failed"]
              for b in batches]
    for name, f in zip(names, failed):
        if f:
            notes.append(f"{name}: {len(f)} log(s) failed and are not compared: " + ", ".join(x["name"] for x in f))
    if unpaired:
        notes.append(f"{len(unpaired)} log(s) are not in every fleet and are not compared (listed above)")
    if len(paired) < MIN_PAIRED_LOGS:
        notes.append(f"only {len(paired)} log(s) are in every fleet: too few to judge a fleet-level difference "
                     f"(at least {MIN_PAIRED_LOGS} needed); the per-log values stand")
    fleet_rows = [{"name": n, "out_dir": str(d), "logs": len(f), "failed": fl, "options_sha256": b.get("options_sha256")}
                  for n, d, f, fl, b in zip(names, dirs, fleets, failed, batches)]
    doc = {"schema": SCHEMA, "fleets": fleet_rows, "logs": paired, "unpaired": unpaired,
           "differences": fleet_differences(paired, dirs), "test": {"method": TEST_METHOD, "alpha": ALPHA,
                                                                     "min_logs": MIN_PAIRED_LOGS},
           "metrics": metric_rows(evs, paired, dirs, names), "notes": notes}
    return doc


def fleet_differences(paired: list[dict], dirs: Sequence[Path]) -> list[dict[str, Any]]:
    """The settings that differ between the fleets: :func:`differences` of each paired log's runs, a key
    ``varies`` where the logs do not all differ alike (its ``values``: the first log's)."""
    seen: dict[str, list[list[Any]]] = {}
    for lg in paired:
        runs = [json.loads((d / f / "run.json").read_text()) for d, f in zip(dirs, lg["folders"])]
        for d in differences(runs):
            seen.setdefault(d["key"], []).append(d["values"])
    return [{"key": k, "values": vals[0], "varies": len(vals) < len(paired) or any(v != vals[0] for v in vals)}
            for k, vals in seen.items()]


def metric_rows(evs: list[list[Evaluation | None]], paired: list[dict], dirs: Sequence[Path],
                names: Sequence[str]) -> list[dict[str, Any]]:
    """compare.json's ``metrics``: per trajectory and metric, every paired log's value per fleet."""
    methods = list(dict.fromkeys(m for row in evs for ev in row if ev is not None for m in ev.result["methods"]))
    rows = []
    for m in methods:
        for metric in FLEET_METRICS:
            values = [[_value(ev, m, metric.key) for ev in row] for row in evs]
            if any(v is not None for vs in values for v in vs):
                rows.append(_metric_row(m, metric, values, names))
    free = [[None if ev is None or ev.gt is not None else methods_disagreement(d / f)
             for ev, d, f in zip(row, dirs, lg["folders"])] for row, lg in zip(evs, paired)]
    if any(v is not None for vs in free for v in vs):
        rows.append(_metric_row(DISAGREEMENT, _DISAGREEMENT_METRIC, free, names))
    return rows


def _value(ev: Evaluation | None, m: str, key: str) -> float | None:
    if ev is None:
        return None
    v = (ev.result["methods"].get(m) or {}).get(key)
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) else None


def _metric_row(method: str, metric: Metric, values: list[list[float | None]], names: Sequence[str]) -> dict[str, Any]:
    best = []
    for vs in values:
        have = [v for v in vs if v is not None]
        top = min(have) if have else None
        best.append([] if top is None else [n for n, v in zip(names, vs)
                                            if v is not None and v <= top + 1e-12 * max(1.0, abs(top))])
    medians = []
    for j in range(len(names)):
        col = [v for vs in values if (v := vs[j]) is not None]
        medians.append(float(np.median(col)) if col else None)
    comparisons = []
    for i, j in combinations(range(len(names)), 2):
        test = paired_test([vs[i] for vs in values], [vs[j] for vs in values])
        test["verdict"] = _verdict(method, metric, names[i], names[j], test) if test["clear"] else None
        comparisons.append({"a": names[i], "b": names[j], **test})
    return {"method": method, "metric": metric.key, "label": metric.label, "unit": metric.unit, "scale": metric.scale,
            "better": "lower", "values": values, "best": best, "medians": medians, "comparisons": comparisons}


def paired_test(a: Sequence[float | None], b: Sequence[float | None], min_logs: int = MIN_PAIRED_LOGS,
                alpha: float = ALPHA) -> dict[str, Any]:
    """Whether fleet B's values differ from fleet A's over the logs both have (one value per log, any
    positive unit), by a two-sided paired t-test on the per-log log-ratios d_i = ln(b_i / a_i):

        d̄ = Σ d_i / n,   SE = √(Σ (d_i − d̄)² / (n − 1)) / √n,   clear  ⇔  n ≥ min_logs  and  |d̄| > t(1 − α/2, n − 1) · SE

    (SE = 0 with d̄ ≠ 0: every log differs by the same ratio, clear; d̄ = 0: never). Returns ``logs``
    (n), ``ratio`` (exp d̄: B over A, the geometric mean of the per-log ratios), ``mean_log_ratio``,
    ``standard_error``, ``critical`` (the t quantile), ``lower_in_b`` and ``higher_in_b`` (logs),
    ``clear`` and ``why_not`` (None where clear); None for what n does not give."""
    from scipy.stats import t as student_t

    pairs = [(x, y) for x, y in zip(a, b) if x is not None and y is not None and x > 0 and y > 0]
    n = len(pairs)
    d = np.array([math.log(y / x) for x, y in pairs])
    out: dict[str, Any] = {"logs": n, "ratio": None, "mean_log_ratio": None, "standard_error": None, "critical": None,
                           "lower_in_b": int(np.sum(d < 0)), "higher_in_b": int(np.sum(d > 0)), "clear": False,
                           "why_not": None}
    if n == 0:
        out["why_not"] = "no log has a value in both"
        return out
    mean = float(np.mean(d))
    out.update(ratio=math.exp(mean), mean_log_ratio=mean)
    if n < 2:
        out["why_not"] = f"{n} paired log: too few to judge (at least {min_logs} needed)"
        return out
    se = float(np.std(d, ddof=1) / math.sqrt(n))
    crit = float(student_t.ppf(1.0 - alpha / 2.0, n - 1))
    out.update(standard_error=se, critical=crit)
    if n < min_logs:
        out["why_not"] = f"{n} paired logs: too few to judge (at least {min_logs} needed)"
    elif mean == 0.0:
        out["why_not"] = "the same on every log"
    elif abs(mean) > crit * se:
        out["clear"] = True
    else:
        out["why_not"] = (f"within the noise: mean log-ratio {mean:+.3f} is {abs(mean) / se:.1f} × its standard "
                          f"error {se:.3f}, not beyond t = {crit:.2f}")
    return out


def _verdict(method: str, metric: Metric, a: str, b: str, test: dict[str, Any]) -> str:
    """The sentence of a clear difference: which fleet is better, on how many logs, by what ratio."""
    n, ratio, mean, se = test["logs"], test["ratio"], test["mean_log_ratio"], test["standard_error"]
    better, worse, r = (a, b, ratio) if ratio > 1 else (b, a, 1.0 / ratio)
    on = test["higher_in_b"] if ratio > 1 else test["lower_in_b"]
    noise = ("the same ratio on every log" if se == 0 else
             f"mean log-ratio {mean:+.3f}, {abs(mean) / se:.1f} × its standard error {se:.3f}, beyond "
             f"t = {test['critical']:.2f} (p < {ALPHA:g})")
    return (f"{better} is better: {worse}'s {metric.label} is {r:.2f} × {better}'s (geometric mean over {n} logs), "
            f"higher on {on} of {n} logs; {noise}.")


# ------------------------------------------------------------------ the page


def _bars_figure(doc: dict, row: dict) -> Any:
    """One trajectory's one metric: a group of horizontal bars per paired log, a bar per fleet, the best
    of each log outlined and starred (:func:`fmcwlog.evaluation.fleet_plots._bars`)."""
    from .fleet_plots import ROW_IN, _bars
    from .plots import _pyplot

    plt = _pyplot()
    names = [f["name"] for f in doc["fleets"]]
    colours = plt.get_cmap("tab10").colors
    shown = _measured(row)
    logs = [doc["logs"][i]["name"] for i in shown]
    series = [(n, colours[j % len(colours)], [row["values"][i][j] for i in shown]) for j, n in enumerate(names)]
    marked = [{names.index(n) for n in best} if len(best) < len(names) else set()
              for best in (row["best"][i] for i in shown)]
    fig, ax = plt.subplots(figsize=(7, ROW_IN * len(logs) * max(2, len(names)) * 0.75 + 0.9), layout="constrained")
    scale = _bars(ax, logs, series, row["scale"], "{:.2f}", marked)
    ax.set_xlabel(f"{row['label']} ({row['unit']}{scale}); ★ the best fleet of the log")
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return fig


def _metric_table(doc: dict, row: dict) -> str:
    metric = _metric_of(row)
    names = [f["name"] for f in doc["fleets"]]
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    body = []
    for i in _measured(row):
        lg, vs, best = doc["logs"][i], row["values"][i], row["best"][i]
        cells = "".join(_value_td(metric, v, n in best and len(best) < len(names)) for n, v in zip(names, vs))
        body.append(f'<tr><td class="text">{html.escape(lg["name"])}</td>{cells}</tr>')
    medians = "".join(f"<td><b>{html.escape(_cell(metric, v))}</b></td>" for v in row["medians"])
    body.append(f'<tr><td class="text"><b>median over the logs</b></td>{medians}</tr>')
    return (f'<table><thead><tr><th class="text">log</th>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'
            + "".join(f"<p>{html.escape(_said(c))}</p>" for c in row["comparisons"]))


def _measured(row: dict) -> list[int]:
    """The paired logs (their indices) with a value of this row in at least one fleet."""
    return [i for i, vs in enumerate(row["values"]) if any(v is not None for v in vs)]


def _said(c: dict) -> str:
    if c["verdict"]:
        return f"{c['a']} vs {c['b']}: {c['verdict']}"
    return f"{c['a']} vs {c['b']}: no verdict: {c['why_not']}."


def _value_td(metric: Metric, v: float | None, best: bool) -> str:
    cls = ' class="best"' if best else ""
    return f"<td{cls}>{html.escape(_cell(metric, v))}{' ★' if best else ''}</td>"


def _metric_of(row: dict) -> Metric:
    return next((m for m in (*FLEET_METRICS, _DISAGREEMENT_METRIC) if m.key == row["metric"]), _DISAGREEMENT_METRIC)


def verdict_lines(doc: dict) -> list[str]:
    """The fleet-level verdicts as lines (the page's list, the terminal's)."""
    return [f"{label(r['method'])}, {r['label']}: {c['verdict']}" for r in doc["metrics"]
            for c in r["comparisons"] if c["verdict"]]


def terminal_rows(doc: dict) -> tuple[list[str], list[list[str]]]:
    """A row per trajectory and metric, a column per fleet: its median over the paired logs."""
    names = [f["name"] for f in doc["fleets"]]
    rows = [[label(r["method"]), r["label"], *(_cell(_metric_of(r), v) for v in r["medians"])] for r in doc["metrics"]]
    return ["trajectory", "metric (median over the paired logs)", *names], rows


_PAIR_STYLE = """
body { max-width: 1300px; } .pair { display: flex; flex-wrap: wrap; gap: 1.5em; align-items: flex-start; }
.pair figure { flex: 0 1 640px; margin: 0; } .pair > div { flex: 1 1 380px; }
"""


def render_fleets_html(doc: dict) -> str:
    """compare.html of fleets: the fleets, the logs not in every fleet, what differs, the fleet-level
    verdicts and the rule behind them, and per trajectory and metric the per-log bars and table."""
    from .compare import _EXTRA_STYLE
    from .pages import _STYLE
    from .plots import png

    names = [f["name"] for f in doc["fleets"]]
    title = "fmcwlog compare: fleets " + ", ".join(names)
    fleets = _table(["fleet", "folder", "log folders", "failed logs", "options digest"],
                    [[f["name"], f["out_dir"], str(f["logs"]), str(len(f["failed"])),
                      (f["options_sha256"] or "—")[:12]] for f in doc["fleets"]])
    unpaired = ("" if not doc["unpaired"] else "<p>Not in every fleet, not compared:</p>"
                + _table(["log", "in"], [[u["name"], ", ".join(u["in"])] for u in doc["unpaired"]]))
    diffs = [{**d, "key": d["key"] + (" (varies by log; the first log's)" if d["varies"] else "")}
             for d in doc["differences"]]
    verdicts = verdict_lines(doc)
    too_few = len(doc["logs"]) < doc["test"]["min_logs"]
    sections = []
    for row in doc["metrics"]:
        fig = _bars_figure(doc, row)
        what = f"{label(row['method'])}: {row['label']} per log"
        sections.append(f"<h3>{html.escape(what)}</h3><div class=\"pair\"><figure><img alt=\"{html.escape(what)}\" "
                        f"src=\"{png(fig)}\"><figcaption>a group of bars per log, a bar per fleet; the best of each log "
                        f"outlined and ★</figcaption></figure><div>{_metric_table(doc, row)}</div></div>")
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in doc["notes"])
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>{_STYLE}{_EXTRA_STYLE}{_PAIR_STYLE}</style></head><body>
<h1>{html.escape(title)}</h1>
<h2>Fleets</h2>
{fleets}
<p>{len(doc["logs"])} log(s) in every fleet, paired by the log they were made from (run.json's sha256 of the log,
else its file name).</p>
{unpaired}
<h2>What differs between the fleets</h2>
{differences_html(diffs, names, "fleet")}
<h2>Verdicts over the logs</h2>
{"<p><b>Too few paired logs to judge</b> (" + str(len(doc["logs"])) + f", at least {doc['test']['min_logs']} needed): "
 "the per-log values below stand, without verdicts.</p>" if too_few else ""}
{"<ul>" + "".join(f"<li>{html.escape(v)}</li>" for v in verdicts) + "</ul>" if verdicts else
 "<p>No clear difference between the fleets on any metric.</p>"}
<p>The rule: {html.escape(doc["test"]["method"])}.</p>
<h2>Per log</h2>
{"".join(sections)}
<h2>Notes</h2>
{f"<ul>{notes}</ul>" if notes else "<p>None.</p>"}
</body></html>
"""
