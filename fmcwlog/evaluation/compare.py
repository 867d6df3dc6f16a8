"""``fmcwlog compare``: several runs (``process`` output folders) side by side, as one tunes a front end.

Each run is measured as ``fmcwlog report`` measures it (:func:`fmcwlog.evaluation.evaluate.evaluate`,
nothing written into the run's folder); then, per trajectory and metric, every run's value, the
best marked, and a verdict only where a difference exceeds what the log itself says a metric
wanders by.

**The spread.** A metric measured once per run has no run-to-run spread of its own, so it is
measured from the log's own segments: each run's series behind the metric (the position errors
along the path for ATE, the per-pair errors for RPE, the heading errors, the time of each sweep)
is cut into :data:`SEGMENTS` consecutive segments of equal count and the metric is computed on
each. A run's spread (the ± on the page) is the standard deviation of its segment values over √k.
A difference between two runs of one log is judged against the spread of their segment-by-segment
differences (standard deviation over √k: the segments are the same stretches of the same log, so
what both runs find hard cancels); between runs of different logs, against their two spreads
combined, √(s₁² + s₂²). It counts, and gets a verdict, where it exceeds :data:`VERDICT_FACTOR`
times that spread. Extremes (min, max), the first-pose-aligned ATE, the feature errors and the
moving-point F1 have no segment series: their rows are marked best but carry no verdict.

``compare.json`` (schema ``fmcwlog.compare/1``; metric values in the units of report.json's keys):

- ``runs``: per run ``name`` (the folder's name, its parent's too where two share one),
  ``out_dir``, ``log``, ``log_sha256``, ``sweeps``, ``wall_seconds``, ``wall_sweeps_per_second``,
  ``params_sha256_12``;
- ``same_log``: whether every run comes from one log (:func:`log_identity`: run.json's sha256, else
  the log's file name), and
  ``logs``: the distinct logs;
- ``differences``: every run.json setting that differs between the runs: ``key`` (``params.a.b``
  for a parameter, else run.json's own key) and ``values`` (per run, ``null`` where a run lacks it);
- ``segments`` (k), ``verdict_factor``, ``spread_method`` (the sentence above, as the page says it);
- ``metrics``: per trajectory and metric, ``method``, ``metric`` (report.json's key), ``label``,
  ``unit``, ``scale`` (from report.json's unit to ``unit``), ``better`` (``lower`` or ``higher``),
  ``values``, ``spreads`` and ``segment_values`` (per run, ``null`` where not measured),
  ``best`` (the runs with the best value), ``judged_against`` (per run, the spread its difference
  from the best was judged against; ``null`` for the best and where there is none), ``beyond``
  (the runs whose difference from the best exceeds :data:`VERDICT_FACTOR` times that), ``verdict``
  (a sentence, or ``null`` when no difference exceeds it or the metric has no spread);
- ``notes``: what the comparison could not do, and why.
"""

from __future__ import annotations

import html
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ReportError
from ..fleet.state import is_batch_folder
from ..io.atomic import atomic_batch, created_parents, json_text, reported_write_errors, write_text
from .evaluate import Evaluation, evaluate, params_digest
from .plots import label

SEGMENTS = 5  # k: the log's own segments a metric's spread is measured on
VERDICT_FACTOR = 2.0  # a difference counts beyond this many combined spreads (about 95 % for normal errors)
SPREAD_METHOD = (f"each run's series behind a metric is cut into k = {SEGMENTS} consecutive segments of equal count "
                 "(position errors along the path for ATE, per-pair errors for RPE, heading errors, the time of each "
                 "sweep) and the metric computed on each; a run's spread (±) is the standard deviation of its segment "
                 "values over √k; a difference between two runs of one log is judged against the standard deviation "
                 "of their segment-by-segment differences over √k (of different logs: √(s₁² + s₂²)), and counts where "
                 f"it exceeds {VERDICT_FACTOR:g} times that")
# run.json's own keys that name how a run was made (its params are compared key by key)
_SETTINGS = ("log", "methods", "scan_topic", "prior", "doppler", "calibration_source", "backend.kind",
             "fmcwlog_version")


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def _std(x: np.ndarray) -> float:
    return float(np.std(x))


Series = Callable[[Evaluation, str], np.ndarray | None]


def _ate(ev: Evaluation, m: str) -> np.ndarray | None:
    return ev.aligned[m][2] if m in ev.aligned else None


def _rpe(delta: float, part: str) -> Series:
    def series(ev: Evaluation, m: str) -> np.ndarray | None:
        found = [s for s in ev.rpe.get(m, []) if s.delta == delta]
        return getattr(found[0], part) if found else None
    return series


@dataclass(frozen=True)
class Metric:
    """One row kind: report.json's ``key`` (``segmentation.f1`` reaches into a dict), its ``label``,
    the ``unit`` shown and ``scale`` from report.json's unit to it, whether ``lower`` is better,
    and, where the metric has one, the per-pose series and the statistic that gives it from a segment."""

    key: str
    label: str
    unit: str
    scale: float = 1.0
    lower: bool = True
    series: Series | None = None
    statistic: Callable[[np.ndarray], float] | None = None
    digits: int = 2


METRICS: tuple[Metric, ...] = (
    Metric("ate_rmse_m", "ATE RMSE", "cm", 100.0, series=_ate, statistic=_rms),
    Metric("ate_mean_m", "ATE mean", "cm", 100.0, series=_ate, statistic=np.mean),
    Metric("ate_median_m", "ATE median", "cm", 100.0, series=_ate, statistic=np.median),
    Metric("ate_std_m", "ATE std", "cm", 100.0, series=_ate, statistic=_std),
    Metric("ate_min_m", "ATE min", "cm", 100.0),
    Metric("ate_max_m", "ATE max", "cm", 100.0),
    Metric("ate_first_aligned_rmse_m", "ATE RMSE, first pose aligned", "cm", 100.0),
    Metric("rpe_1m_pct", "RPE over 1 m (mean)", "%", series=_rpe(1.0, "trans_pct"), statistic=np.mean),
    Metric("rpe_10m_pct", "RPE over 10 m (mean)", "%", series=_rpe(10.0, "trans_pct"), statistic=np.mean),
    Metric("rpe_1m_deg_per_m", "RPE yaw over 1 m (mean)", "deg/m", series=_rpe(1.0, "rot_deg_per_m"),
           statistic=np.mean, digits=3),
    Metric("rpe_10m_deg_per_m", "RPE yaw over 10 m (mean)", "deg/m", series=_rpe(10.0, "rot_deg_per_m"),
           statistic=np.mean, digits=3),
    Metric("heading_rmse_deg", "heading RMSE", "deg", series=lambda ev, m: ev.heading.get(m), statistic=_rms),
    Metric("heading_max_deg", "heading max", "deg"),
    Metric("feature_avg_rel_error_pct", "feature length error (mean)", "%"),
    Metric("segmentation.f1", "moving points F1", "", lower=False, digits=3),
    Metric("ms_per_sweep_median", "median ms per sweep", "ms", series=lambda ev, m: ev.sweep_ms.get(m),
           statistic=np.median),
)


def segment_values(series: np.ndarray | None, statistic: Callable[[np.ndarray], float] | None,
                   k: int = SEGMENTS) -> np.ndarray | None:
    """``statistic`` on each of ``k`` consecutive segments of equal count of ``series`` (its finite
    values); None where there is no series, no statistic, or fewer than 2 values per segment."""
    if series is None or statistic is None:
        return None
    x = np.asarray(series, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) < 2 * k:
        return None
    return np.array([statistic(part) for part in np.array_split(x, k)])


def spread(values: np.ndarray | None) -> float | None:
    """A run's spread of a metric from its segment values: their standard deviation (ddof=1) over √k."""
    return None if values is None else float(np.std(values, ddof=1) / math.sqrt(len(values)))


def spread_between(a: np.ndarray | None, b: np.ndarray | None, paired: bool) -> float | None:
    """The spread a difference between two runs is judged against: on one log (``paired``, the same
    segments), the standard deviation of the segment-by-segment differences over √k; else the two
    runs' spreads combined, √(s₁² + s₂²). None where either has no segment values."""
    if a is None or b is None:
        return None
    if paired and len(a) == len(b):
        return float(np.std(b - a, ddof=1) / math.sqrt(len(a)))
    return math.hypot(spread(a), spread(b))  # type: ignore[arg-type]


def _value(r: dict | None, key: str) -> float | None:
    if r is None:
        return None
    for part in key.split("."):
        r = r.get(part) if isinstance(r, dict) else None
    return float(r) if isinstance(r, int | float) and not isinstance(r, bool) and math.isfinite(r) else None


def judge(metric: Metric, names: Sequence[str], values: Sequence[float | None],
          between: Callable[[int, int], float | None]) -> dict[str, Any]:
    """One row's best runs, the spread each other run's difference from the best is judged against
    (``between(best, other)``), the runs beyond :data:`VERDICT_FACTOR` times it, and the verdict
    sentence (None where no difference exceeds it, or there is no spread)."""
    have = [i for i, v in enumerate(values) if v is not None]
    out: dict[str, Any] = {"best": [], "judged_against": [None] * len(values), "beyond": [], "verdict": None}
    if not have:
        return out
    sign = 1.0 if metric.lower else -1.0
    top = min(sign * values[i] for i in have)  # type: ignore[operator]
    best = [i for i in have if sign * values[i] <= top + 1e-12 * max(1.0, abs(top))]  # type: ignore[operator]
    out["best"] = [names[i] for i in best]
    b = best[0]
    beyond: list[int] = []
    within: list[int] = []
    for i in have:
        if i in best:
            continue
        s = out["judged_against"][i] = between(b, i)
        if s is None:
            continue  # no spread: marked best, no verdict on this run
        gap = abs(values[i] - values[b])  # type: ignore[operator]
        (beyond if gap > VERDICT_FACTOR * s else within).append(i)
    out["beyond"] = [names[i] for i in beyond]
    if beyond:
        out["verdict"] = _verdict(metric, names, values, out["judged_against"], best, beyond, within)
    return out


def _cell(metric: Metric, v: float | None) -> str:
    if v is None:
        return "—"
    unit = f" {metric.unit}" if metric.unit else ""
    return f"{v * metric.scale:.{metric.digits}f}{unit}"


def _verdict(metric: Metric, names: Sequence[str], values: Sequence[float | None],
             against: Sequence[float | None], best: list[int], beyond: list[int], within: list[int]) -> str:
    b = best[0]
    v = [math.nan if x is None else x for x in values]  # the runs named here all have a value and a spread
    s = [math.nan if x is None else x for x in against]
    word = "lower" if metric.lower else "higher"
    lead = " and ".join(names[i] for i in best)
    worse = "; ".join(f"{names[i]} ({_cell(metric, v[i])}: {_cell(metric, abs(v[i] - v[b]))} apart, "
                      f"{_times(abs(v[i] - v[b]), s[i])} the spread of {_cell(metric, s[i])})" for i in beyond)
    text = f"{lead} {'is' if len(best) == 1 else 'are'} {word} ({_cell(metric, v[b])}) than {worse}"
    if within:
        text += f"; within the spread of it: {', '.join(names[i] for i in within)}"
    return text + "."


def _times(gap: float, spread: float) -> str:
    return f"{gap / spread:.1f} ×" if spread > 0 else "beyond"


def run_names(out_dirs: Sequence[Path]) -> list[str]:
    """Each run's name on the page: its folder's name, with its parent's where two share a name,
    numbered where even that does not tell them apart."""
    short = [p.name or str(p) for p in out_dirs]
    names = [f"{p.parent.name}/{n}" if short.count(n) > 1 else n for p, n in zip(out_dirs, short)]
    return [n if names.count(n) == 1 else f"{n} ({i + 1})" for i, n in enumerate(names)]


def _flat(d: Any, prefix: str) -> dict[str, Any]:
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}.{k}" if prefix else str(k)))
    return out


def differences(runs: Sequence[dict]) -> list[dict[str, Any]]:
    """Every run.json setting (:data:`_SETTINGS`, and each parameter as ``params.a.b``) whose value
    is not the same in every run; a run that lacks it gives ``None``."""
    flats = []
    for run in runs:
        top = _flat({k: v for k, v in run.items() if k != "params"}, "")
        flat = {k: top.get(k) for k in _SETTINGS}
        flat.update(_flat(run.get("params") or {}, "params"))
        flats.append(flat)
    keys = sorted({k for f in flats for k in f}, key=lambda k: (k.startswith("params."), k))
    return [{"key": k, "values": [f.get(k) for f in flats]} for k in keys
            if any(f.get(k) != flats[0].get(k) for f in flats[1:])]


def log_identity(run: dict) -> str:
    """Which log a run was made from, to tell runs of one log: run.json's ``log_sha256`` where it has
    one, else the log's file name (a run written before logs were digested)."""
    sha = run.get("log_sha256")
    if isinstance(sha, str) and sha:
        return sha
    return Path(str(run.get("log") or "")).name


def check_runs(out_dirs: Sequence[Path]) -> None:
    """Refuse, in one line naming the folder, what cannot be compared: fewer than two runs, a folder
    given twice, a batch folder among runs; a folder that is not a run is refused by :func:`evaluate`.
    Batch folders only are fleets (:mod:`fmcwlog.evaluation.compare_fleets`)."""
    check_distinct(out_dirs, "runs", "'fmcwlog report' measures one")
    for d in out_dirs:
        if is_batch(d):
            raise ReportError(f"{d}: a batch folder (many logs) among single runs; compare batch folders with batch "
                              f"folders only, or its log folders, e.g. {d}/<log>, with runs")


def check_distinct(out_dirs: Sequence[Path], what: str, one: str) -> None:
    """Refuse, in one line naming the folder, fewer than two folders (``what``: "runs", "fleets";
    ``one``: what to do with one instead) and a folder given twice."""
    if len(out_dirs) < 2:
        raise ReportError(f"{out_dirs[0] if out_dirs else 'compare'}: compare needs two {what} or more ({one})")
    seen: dict[Path, Path] = {}
    for d in out_dirs:
        key = d.resolve()
        if key in seen:
            raise ReportError(f"{d}: given twice (as {seen[key]})")
        seen[key] = d


def is_batch(d: Path) -> bool:
    """A batch folder (many logs' results), not one run."""
    return is_batch_folder(d) and not (d / "run.json").is_file()


def compare_runs(out_dirs: Sequence[str | Path], target: str | Path) -> dict[str, Any]:
    """Measure each run as ``report`` does, and write compare.html and compare.json into ``target``
    (both or, if a write fails, neither); returns compare.json's document (module docstring)."""
    dirs = [Path(d) for d in out_dirs]
    check_runs(dirs)
    evs = [evaluate(d) for d in dirs]
    doc, pages = comparison_pages(evs)
    target = Path(target)
    with reported_write_errors(target), created_parents(target / "compare.html"), atomic_batch():
        for name, text in pages.items():
            write_text(target / name, text)
    return doc


def comparison_pages(evs: Sequence[Evaluation]) -> tuple[dict[str, Any], dict[str, str]]:
    """compare.json's document for the evaluated runs ``evs`` (named by :func:`run_names` of their
    folders), and the texts of compare.json and compare.html by file name; ``compare`` and a
    ``report`` of several folders both write these."""
    doc = comparison(evs, run_names([ev.out_dir for ev in evs]))
    return doc, {"compare.json": json_text(doc), "compare.html": render_html(doc, evs)}


def comparison(evs: Sequence[Evaluation], names: Sequence[str]) -> dict[str, Any]:
    """compare.json's document for the evaluated runs ``evs`` named ``names``."""
    runs = [_run_row(ev, n) for ev, n in zip(evs, names)]
    logs = list(dict.fromkeys(log_identity(ev.run) for ev in evs))
    notes = []
    if len(logs) > 1:
        notes.append(f"the runs come from {len(logs)} different logs: a difference between them mixes the logs' "
                     "with the settings'; each run's segments are cut on its own log")
    if all(ev.gt is None for ev in evs):
        notes.append("no run's log has ground truth: no errors to compare, only the speed")
    methods = list(dict.fromkeys(m for ev in evs for m in ev.result["methods"]))
    rows = [row for m in methods for metric in METRICS
            if (row := _row(evs, names, m, metric, paired=len(logs) == 1)) is not None]
    diffs = differences([ev.run for ev in evs])
    digests = {r["options_sha256"] for r in runs}
    if not diffs and len(digests) > 1:
        notes.append("the runs' options differ (run.json's options_sha256) in a way run.json does not list")
    return {"schema": "fmcwlog.compare/1", "runs": runs, "same_log": len(logs) == 1, "logs": logs,
            "differences": diffs, "segments": SEGMENTS, "verdict_factor": VERDICT_FACTOR,
            "spread_method": SPREAD_METHOD, "metrics": rows, "notes": notes}


def _row(evs: Sequence[Evaluation], names: Sequence[str], m: str, metric: Metric, paired: bool) -> dict | None:
    """One trajectory's one metric across the runs (compare.json's ``metrics`` entry); None where no run has it."""
    values = [_value(ev.result["methods"].get(m), metric.key) for ev in evs]
    if all(v is None for v in values):
        return None
    segs = [segment_values(metric.series(ev, m), metric.statistic) if metric.series and v is not None else None
            for ev, v in zip(evs, values)]
    verdict = judge(metric, names, values, lambda b, i: spread_between(segs[b], segs[i], paired))
    return {"method": m, "metric": metric.key, "label": metric.label, "unit": metric.unit, "scale": metric.scale,
            "better": "lower" if metric.lower else "higher", "values": values,
            "spreads": [spread(v) for v in segs], "segment_values": [None if v is None else v.tolist() for v in segs],
            **verdict}


def _run_row(ev: Evaluation, name: str) -> dict[str, Any]:
    r = ev.result
    return {"name": name, "out_dir": str(ev.out_dir), "log": str(ev.log), "log_sha256": ev.run.get("log_sha256"),
            "options_sha256": ev.run.get("options_sha256"), "sweeps": r["sweeps"], "wall_seconds": r["wall_seconds"],
            "wall_sweeps_per_second": r["wall_sweeps_per_second"], "params_sha256_12": params_digest(ev.run.get("params"))}


# ------------------------------------------------------------------ the page


def terminal_rows(doc: dict) -> tuple[list[str], list[list[str]]]:
    """The metrics table as text: a row per trajectory and metric, a column per run (best marked *)."""
    names = [r["name"] for r in doc["runs"]]
    rows = []
    for row in doc["metrics"]:
        metric = next(m for m in METRICS if m.key == row["metric"])
        cells = [_cell(metric, v) + (" *" if n in row["best"] and len(names) > 1 else "")
                 for n, v in zip(names, row["values"])]
        rows.append([label(row["method"]), row["label"], *cells])
    return ["trajectory", "metric", *names], rows


def _value_cell(metric: Metric, v: float | None, spread: float | None, best: bool, beyond: bool) -> str:
    text = _cell(metric, v)
    if v is not None and spread is not None:
        text += f" ± {spread * metric.scale:.{metric.digits}f}"
    cls = ' class="best"' if best else (' class="beyond"' if beyond else "")
    return f"<td{cls}>{html.escape(text)}{' ★' if best else ''}</td>"


def _said(row: dict, metric: Metric) -> str:
    """The verdict column: the verdict, or why there is none."""
    if row["verdict"]:
        return row["verdict"]
    if len(row["best"]) == sum(v is not None for v in row["values"]):
        return "the same in every run" if len(row["best"]) > 1 else "one run only"
    if any(s is not None for s in row["judged_against"]):
        return "within the spread"
    if metric.series is None:
        return "no segment series: no verdict"
    return f"too few values to cut into {SEGMENTS} segments: no verdict"


def _metrics_html(doc: dict) -> str:
    names = [r["name"] for r in doc["runs"]]
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    body = []
    for row in doc["metrics"]:
        metric = next(m for m in METRICS if m.key == row["metric"])
        said = html.escape(_said(row, metric))
        cells = "".join(_value_cell(metric, v, s, n in row["best"], n in row["beyond"])
                        for n, v, s in zip(names, row["values"], row["spreads"]))
        body.append(f'<tr><td class="text">{html.escape(label(row["method"]))}</td>'
                    f'<td class="text">{html.escape(row["label"])}; {row["better"]} is better</td>{cells}'
                    f'<td class="text">{said}</td></tr>')
    return (f'<table><thead><tr><th class="text">trajectory</th><th class="text">metric</th>{head}'
            f'<th class="text">verdict</th></tr></thead><tbody>{"".join(body)}</tbody></table>')


def _plain(v: Any) -> str:
    return "—" if v is None else (json_text(v).strip() if isinstance(v, dict | list) else str(v))


def _table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f'<th class="text">{html.escape(h)}</th>' for h in header)
    body = "".join("<tr>" + "".join(f'<td class="text">{html.escape(c)}</td>' for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _runs_html(doc: dict) -> str:
    rows = [[r["name"], r["out_dir"], r["log"], str(r["sweeps"]),
             "—" if r["wall_sweeps_per_second"] is None else f"{r['wall_sweeps_per_second']:.0f}",
             r["params_sha256_12"] or "—"] for r in doc["runs"]]
    return _table(["run", "folder", "log", "sweeps", "sweeps/s (the run's wall clock)", "parameters digest"], rows)


def differences_html(differences: list[dict], names: Sequence[str], what: str = "run") -> str:
    """The table of ``differences`` (:func:`differences`), a column per run (or fleet) named ``names``."""
    if not differences:
        return f"<p>None: every run.json setting and parameter is the same in every {what}.</p>"
    return _table(["setting", *names], [[d["key"], *(_plain(v) for v in d["values"])] for d in differences])


def errors_over_time(evs: Sequence[Evaluation], names: Sequence[str]):
    """Each trajectory's position error (cm, log scale, SE(2)-aligned) against time (s), one axis per
    trajectory, one line per run; the k segments the spread is measured on marked; None without errors."""
    from .plots import _log_y, _pyplot

    methods = list(dict.fromkeys(m for ev in evs for m in ev.aligned))
    if not methods:
        return None
    plt = _pyplot()
    colours = plt.get_cmap("tab10").colors
    fig, axes = plt.subplots(len(methods), 1, figsize=(10, 2.4 * len(methods) + 0.8), squeeze=False,
                             layout="constrained")
    for ax, m in zip(axes[:, 0], methods):
        for j, (ev, name) in enumerate(zip(evs, names)):
            if m not in ev.aligned:
                continue
            t, _, err = ev.aligned[m]
            t0 = float(t[0])
            ax.plot(t - t0, np.maximum(100.0 * err, 1e-3), color=colours[j % len(colours)], lw=1,
                    ls=_DASHES[j % len(_DASHES)], label=f"{name} (RMSE {100 * _rms(err):.1f} cm)")
            if j == 0:
                for part in np.array_split(t - t0, SEGMENTS)[1:]:
                    ax.axvline(float(part[0]), color="#999999", lw=0.6, ls=":")
        _log_y(ax)
        ax.set_ylabel(f"{label(m)}\nerror (cm, log)")
        ax.grid(True, which="major", alpha=0.3)
        ax.legend(fontsize=8, loc="center left", bbox_to_anchor=(1.01, 0.5), frameon=False)  # beside: never on a line
    axes[-1, 0].set_xlabel("time since the run's first pose (s); dotted: the segments the spread is measured on")
    fig.suptitle("Position error along the path, each run (SE(2)-aligned to ground truth, as evo_ape -a)")
    return fig


_DASHES = ("-", "--", ":", "-.")  # a run equal to another (its wheel odometry, say) still shows under it
_EXTRA_STYLE = """
td.best { font-weight: bold; background: #e8f5e9; } td.beyond { color: #b71c1c; }
tbody td:not(.text) { white-space: nowrap; }
"""


def render_html(doc: dict, evs: Sequence[Evaluation]) -> str:
    """compare.html: the runs, what differs between them, the verdicts, each trajectory's error over
    time overlaid across runs, the metrics with the best marked, and the notes."""
    from .pages import _STYLE
    from .plots import png

    names = [r["name"] for r in doc["runs"]]
    fig = errors_over_time(evs, names)
    figure = "" if fig is None else (f'<figure><img alt="position error along the path, each run" src="{png(fig)}">'
                                     "<figcaption>position error along the path, each run</figcaption></figure>")
    verdicts = [f"{label(r['method'])}, {r['label']}: {r['verdict']}" for r in doc["metrics"] if r["verdict"]]
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in doc["notes"])
    title = "fmcwlog compare: " + ", ".join(names) if len(", ".join(names)) < 80 else f"fmcwlog compare: {len(names)} runs"
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{html.escape(title)}</title>
<style>{_STYLE}{_EXTRA_STYLE}</style></head><body>
<h1>{html.escape(title)}</h1>
<h2>Runs</h2>
{_runs_html(doc)}
<p>{"All runs come from one log." if doc["same_log"] else
    html.escape(f"The runs come from {len(doc['logs'])} different logs: their differences mix the logs' and the settings'.")}</p>
<h2>What differs between the runs</h2>
{differences_html(doc["differences"], names)}
<h2>Verdicts</h2>
{"<ul>" + "".join(f"<li>{html.escape(v)}</li>" for v in verdicts) + "</ul>" if verdicts else
 "<p>No difference between the runs exceeds the spread.</p>"}
<h2>Position error along the path</h2>
{figure or "<p>No position errors (no ground truth).</p>"}
<h2>Metrics</h2>
<p>Each cell: the run's value ± its spread, measured from the log's own segments: {html.escape(SPREAD_METHOD)}.
★ marks the best run of each row; red, a run beyond the spread from it.</p>
{_metrics_html(doc)}
<h2>Notes</h2>
{f"<ul>{notes}</ul>" if notes else "<p>None.</p>"}
</body></html>
"""
