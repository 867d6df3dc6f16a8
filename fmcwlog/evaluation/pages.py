"""``fmcwlog report``'s pages: report.html (self-contained), report.md, report.json, a terminal table.

The figures are drawn by :mod:`fmcwlog.evaluation.plots`.

report.json keys (stable; ``null`` where a value cannot be computed, with the
reason in ``notes`` or ``methods.M.notes``):

- ``header``: what was run: ``fmcwlog_version_processed`` (run.json's
  ``fmcwlog_version``), ``fmcwlog_version_report`` (the version writing the report),
  ``report_date_utc`` (ISO 8601, ``YYYY-MM-DDTHH:MM:SSZ``), ``log``, ``scenario`` and
  ``seed`` (an integer; from the log's ``fmcwlog.sim`` record, ``null`` for a real log),
  ``methods`` (run.json's), ``trajectories`` (every one compared, in the page's order),
  ``params_sha256_12`` (first 12 hex digits of the sha256 of run.json's ``params`` as
  canonical JSON: ``json.dumps(params, sort_keys=True, separators=(",", ":"))``, UTF-8);
  ``many_skipped_sweeps``, only where the run skipped more than 5 % of the log's sweeps as
  damaged: run.json's record of it (``skipped``, ``read``, ``share``, ``main_reason``, ...);
  ``gaps``, only where the sweeps had gaps (none, or none with a usable point, for more than a few
  sweep periods): run.json's list of them (``start_s``, ``length_s``); ``jumps``, only where a method
  found its sweeps no longer fitting the map where the motion prior put them (a robot carried away):
  run.json's ``jumps`` of the methods that found one (``start_s``, ``found_s``, ``kind``, ...);
- ``methods.M`` for M in ``improved``, ``baseline``, ``wheel_odometry`` (and any other
  ``*.tum`` in the folder, e.g. a peer's):
  ``ate_rmse_m``, ``ate_mean_m``, ``ate_median_m``, ``ate_std_m``, ``ate_min_m``, ``ate_max_m``
  (evo_ape's statistics of the translation error, SE(2)-aligned as ``evo_ape -a``; std is the
  population one), ``ate_first_aligned_rmse_m`` (first poses aligned),
  ``rpe_1m_pct``, ``rpe_10m_pct`` (mean translation error over 1 m / 10 m of
  travel, % of the distance), ``rpe_1m_deg_per_m``, ``rpe_10m_deg_per_m`` (mean
  yaw error per metre), ``heading_rmse_deg``, ``heading_max_deg`` (yaw error of the
  SE(2)-aligned estimate, RMS and largest absolute, degrees), ``features`` (list of
  ``{id, name, true_m, measured_m, abs_error_m, rel_error_pct}``; a row may carry more
  keys, ``measured_m`` is ``null`` for a feature not measured), ``feature_avg_rel_error_pct``,
  ``segmentation`` (``precision``, ``recall``, ``f1`` and counts),
  ``ms_per_sweep_median``, ``ms_per_sweep_p95``, ``ms_per_sweep_mean``,
  ``ms_per_sweep_max`` (ms of the method's own step per sweep, over the timed sweeps), ``sweeps_per_second`` (1000 / mean ms: the
  rate of that method alone, not the run's), ``notes``;
- ``wall_seconds``, ``wall_sweeps_per_second``: the whole run's wall-clock time (run.json's
  ``wall_seconds``: reading, the methods side by side, writing) and sweeps per second of it, as
  ``process`` printed them (``null`` where run.json has no ``wall_seconds``);
- ``disagreement`` (needs no ground truth): ``reference`` (``improved`` if present, else
  the first method) and ``methods.M`` for every other trajectory: ``rmse_m``, ``mean_m``,
  ``median_m``, ``max_m``, ``final_m`` (at the last common stamp), ``path_m`` (the
  reference's path length over the compared stamps), ``poses``: the distance between M,
  SE(2)-aligned onto the reference (Umeyama, no scale), and the reference, at M's stamps.
  This is how far two estimates disagree, not an error (:mod:`fmcwlog.evaluation.along_path`);
- ``feature_avg_rel_error_reduction_pct``: how much the improved method cuts the
  baseline's average relative feature error over the features both maps measure (the paper's
  figures: :mod:`fmcwlog.evaluation.published`); ``feature_comparison``: how many features
  that is (``features``) and each method's average over them (``baseline_avg_rel_error_pct``,
  ``improved_avg_rel_error_pct``), or ``null`` when none is in both;
- ``paper``, ``params``, ``log``, ``out_dir``, ``sweeps``, ``doppler``, ``prior``, ``notes``,
  ``schema``, ``relations_file``, ``relations_published`` (and ``methods.M.relations`` with
  ``--relations``).
"""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..io.atomic import atomic_path, json_text, write_text
from ..io.outputs import write_tum
from .evaluate import GROUND_TRUTH_TUM, Evaluation
from .plots import LABELS, all_plots
from .published import paper_summary


def _fmt(x: Any, digits: int = 3, scale: float = 1.0, unit: str = "") -> str:
    if x is None:
        return "—"
    return f"{x * scale:.{digits}f}{unit}"


def trajectory_rows(result: dict) -> list[list[str]]:
    rows = []
    for m, r in result["methods"].items():
        seg = r.get("segmentation") or {}
        rows.append([LABELS.get(m, m), _fmt(r["ate_rmse_m"], 1, 100), _fmt(r["ate_max_m"], 1, 100),
                     _fmt(r["ate_first_aligned_rmse_m"], 1, 100), _fmt(r["rpe_1m_pct"], 2), _fmt(r["rpe_10m_pct"], 2),
                     _fmt(r["rpe_1m_deg_per_m"], 3), _fmt(r["feature_avg_rel_error_pct"], 2),
                     _fmt(seg.get("precision"), 3), _fmt(seg.get("recall"), 3), _fmt(seg.get("f1"), 3),
                     _fmt(r["ms_per_sweep_median"], 2)])
    return rows


TRAJECTORY_HEADER = ["method", "ATE RMSE cm", "ATE max cm", "ATE RMSE cm (first pose)", "RPE 1 m % (mean)",
                     "RPE 10 m % (mean)", "RPE 1 m deg/m (mean)", "feature error %", "moving precision",
                     "moving recall", "moving F1", "median ms per sweep"]

ATE_STATS = ("rmse", "mean", "median", "std", "min", "max")
ATE_HEADER = ["method", *(f"{s} cm" for s in ATE_STATS), "first-pose-aligned RMSE cm"]


def ate_rows(result: dict) -> list[list[str]]:
    """evo_ape's statistics of each trajectory's position error (SE(2)-aligned), cm; none without them."""
    return [[LABELS.get(m, m), *(_fmt(r.get(f"ate_{s}_m"), 2, 100) for s in ATE_STATS),
             _fmt(r.get("ate_first_aligned_rmse_m"), 2, 100)]
            for m, r in result["methods"].items() if r.get("ate_rmse_m") is not None]


ATE_INTRO = ("evo_ape's statistics (-r trans_part -a): the distance between each pose, once the whole trajectory "
             "is SE(2)-aligned onto the ground truth (Umeyama, no scale), and the ground truth interpolated at its "
             "stamp; std is the population one (as evo). The last column aligns the first poses instead "
             "(--align_origin).")


def feature_rows(result: dict) -> tuple[list[str], list[list[str]]]:
    methods = [m for m in ("baseline", "improved") if (result["methods"].get(m) or {}).get("features")]
    header = ["feature", "name", "true mm"]
    for m in methods:
        header += [f"{LABELS[m]} measured mm", f"{LABELS[m]} abs error mm", f"{LABELS[m]} rel error %"]
    rows: list[list[str]] = []
    if not methods:
        return header, rows
    for i, f in enumerate(result["methods"][methods[0]]["features"]):
        row = [str(f["id"]), f["name"], _fmt(f["true_m"], 0, 1000)]
        for m in methods:
            g = result["methods"][m]["features"][i]
            row += [_fmt(g["measured_m"], 0, 1000), _fmt(g["abs_error_m"], 0, 1000), _fmt(g["rel_error_pct"], 4)]
        rows.append(row)
    avg = ["average", "", ""]
    for m in methods:
        avg += ["", "", _fmt(result["methods"][m]["feature_avg_rel_error_pct"], 4)]
    rows.append(avg)
    return header, rows


RELATIONS_HEADER = ["method", "relations", "translation m (mean ± std)", "rotation deg (mean ± std)",
                    "< 20 s: n, translation m", "≥ 20 s: n, translation m", "path length m"]


def _span_cell(n: int | None, mean: float | None) -> str:
    return "—" if not n or mean is None else f"{n}: {mean:.3f}"


def relations_rows(result: dict) -> list[list[str]]:
    rows = []
    for m, r in result["methods"].items():
        rel = r.get("relations")
        if rel is None:
            continue
        rows.append([LABELS.get(m, m), str(rel["n"]),
                     "—" if rel["trans_mean_m"] is None else f"{rel['trans_mean_m']:.3f} ± {rel['trans_std_m']:.3f}",
                     "—" if rel["rot_mean_deg"] is None else f"{rel['rot_mean_deg']:.2f} ± {rel['rot_std_deg']:.2f}",
                     _span_cell(rel.get("short_n"), rel.get("short_trans_mean_m")),
                     _span_cell(rel.get("long_n"), rel.get("long_trans_mean_m")),
                     _fmt(rel.get("path_length_m"), 1)])
    for p in result.get("relations_published") or []:
        rows.append([f"published: {p['method']}", "all", f"{p['trans_mean_m']:.3f} ± {p['trans_std_m']:.3f}", "—",
                     "—", "—", "—"])
    return rows


def without_empty_columns(header: list[str], rows: list[list[str]]) -> tuple[list[str], list[list[str]]]:
    """Drop the columns (other than the first) that hold only "—" (e.g. every error column of a log
    without ground truth): the page says why in its notes instead."""
    keep = [i for i in range(len(header)) if i == 0 or any(r[i] != "—" for r in rows)] if rows else range(len(header))
    return [header[i] for i in keep], [[r[i] for i in keep] for r in rows]


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def terminal_table(header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(header)]
    fmt = "  ".join(f"{{:<{w}}}" if i == 0 else f"{{:>{w}}}" for i, w in enumerate(widths))
    return "\n".join([fmt.format(*header), fmt.format(*("-" * w for w in widths))] + [fmt.format(*r) for r in rows])


def _notes(result: dict) -> list[str]:
    out = list(result["notes"])
    for m, r in result["methods"].items():
        out += [f"{LABELS.get(m, m)}: {n}" for n in r["notes"]]
    return out


def change_words(reduction_pct: float) -> str:
    """``reduction_pct`` as words: "a 40.6 % reduction", or "a 2.1 % increase" when it is negative."""
    return f"a {reduction_pct:.1f} % reduction" if reduction_pct >= 0 else f"a {-reduction_pct:.1f} % increase"


def _summary_line(result: dict) -> str:
    cmp = result.get("feature_comparison")
    if not cmp or cmp["reduction_pct"] is None:
        return "The average relative feature error could not be compared (see the notes)."
    n = cmp["features"]
    return (f"Average relative feature error over the {n} feature{'s' if n != 1 else ''} both maps measure: "
            f"baseline {cmp['baseline_avg_rel_error_pct']:.2f} %, improved {cmp['improved_avg_rel_error_pct']:.2f} %: "
            f"{change_words(cmp['reduction_pct'])} ({paper_summary()}).")


def header_rows(result: dict) -> list[tuple[str, str]]:
    """What was run, as (label, value) pairs: the page's header (``result["header"]``)."""
    h = result.get("header") or {}
    none = "— (not in the log)"
    return [
        ("log", str(h.get("log", result.get("log")))),
        *_skipped_rows(h.get("many_skipped_sweeps")),
        *_gap_rows(h.get("gaps")),
        *_jump_rows(h.get("jumps")),
        ("scenario", none if h.get("scenario") is None else str(h["scenario"])),
        ("seed", none if h.get("seed") is None else str(h["seed"])),
        ("methods", "; ".join(h.get("methods") or []) or "—"),
        ("trajectories compared", "; ".join(LABELS.get(m, m) for m in h.get("trajectories") or []) or "—"),
        ("parameters digest", f"{h.get('params_sha256_12') or '—'} (sha256 of run.json's params as canonical JSON)"),
        ("processed by", f"fmcwlog {h.get('fmcwlog_version_processed') or '— (not in run.json)'}"),
        ("reported by", f"fmcwlog {h.get('fmcwlog_version_report')} on {h.get('report_date_utc')} (UTC)"),
    ]


def _skipped_rows(skipped: Any) -> list[tuple[str, str]]:
    """The header's row for a run that skipped more than 5 % of its sweeps (none otherwise)."""
    if not isinstance(skipped, dict):
        return []
    try:
        share = f"{skipped['skipped']} of {skipped['read']} ({100 * float(skipped['share']):.1f} %)"
    except (KeyError, TypeError, ValueError):
        share = "more than 5 %"
    went_on = ", processed on past half as asked (--keep-going)" if skipped.get("kept_going") else ""
    return [("sweeps skipped", f"{share}{went_on}: the results stand on the rest; the main reason: "
                               f"{skipped.get('main_reason', '— (not in run.json)')}")]


def _gap_rows(gaps: Any) -> list[tuple[str, str]]:
    """The header's row for a run whose sweeps had gaps (none otherwise): how many, how long, where."""
    if not isinstance(gaps, list) or not gaps:
        return []
    try:
        spans = [(float(g["start_s"]), float(g["length_s"])) for g in gaps]
    except (KeyError, TypeError, ValueError):
        return [("gaps in the sweeps", f"{len(gaps)} (bridged by the motion prior)")]
    listed = ", ".join(f"{length:.1f} s at {start:.3f} s" for start, length in spans[:5])
    more = f" and {len(spans) - 5} more" if len(spans) > 5 else ""
    bridged_by = gaps[0].get("bridged_by", "the motion prior") if isinstance(gaps[0], dict) else "the motion prior"
    return [("gaps in the sweeps", f"{len(spans)}, {sum(s[1] for s in spans):.1f} s in all ({listed}{more}): "
                                   f"bridged by {bridged_by}; the poses across them are as good as that is")]


def _jump_rows(jumps: Any) -> list[tuple[str, str]]:
    """The header's row for a run where a method found its sweeps no longer fitting the map where the
    motion prior put them (a robot carried away; none otherwise): per method, when and what came of it."""
    if not isinstance(jumps, dict) or not jumps:
        return []
    said = []
    for method, found in jumps.items():
        try:
            parts = [f"{float(j['start_s']):.3f} s, relocalised {float(j['distance_m']):.2f} m away"
                     if j.get("kind") == "relocalised" else f"{float(j['start_s']):.3f} s, a new piece (unknown offset)"
                     for j in found]
        except (KeyError, TypeError, ValueError, AttributeError):
            parts = [f"{len(found)}"]
        said.append(f"{method}: {'; '.join(parts)}")
    return [("robot carried away (jumps)", " | ".join(said))]


DISAGREEMENT_HEADER = ["method", "RMSE m", "mean m", "median m", "max m", "at the end m", "over path m"]


def disagreement_rows(result: dict) -> list[list[str]]:
    d = result.get("disagreement") or {}
    return [[LABELS.get(m, m), _fmt(s["rmse_m"], 3), _fmt(s["mean_m"], 3), _fmt(s["median_m"], 3), _fmt(s["max_m"], 3),
             _fmt(s["final_m"], 3), _fmt(s["path_m"], 1)] for m, s in (d.get("methods") or {}).items()]


def _disagreement_intro(result: dict) -> str:
    ref = LABELS.get((result.get("disagreement") or {}).get("reference") or "", "the reference")
    return (f"No ground truth: each trajectory is SE(2)-aligned onto the {ref} one (least squares, no scale, as "
            f"evo_ape -a) and the distance between the two is measured at every common stamp. This is how far "
            f"the methods disagree, not an error: the {ref} trajectory is itself an estimate, and a drift shows "
            f"spread over the whole path by the alignment.")


SPEED_HEADER = ["method", "sweeps", "median ms", "p95 ms", "max ms", "mean ms",
                "1000 / mean ms (the method's step alone)"]


def run_rate_line(result: dict) -> str:
    """The whole run's wall-clock rate, as ``process`` printed it; the per-sweep times are each method's step."""
    wall, rate = result.get("wall_seconds"), result.get("wall_sweeps_per_second")
    steps = ("Each method's time per sweep is its own step (wall clock around it); with the methods side by "
             "side, their sum is not the run's.")
    if wall is None or rate is None:
        return f"{steps} The run's wall-clock time is not in run.json."
    return (f"The run: {result['sweeps']} sweeps in {wall:.1f} s of wall clock, {rate:.0f} sweeps/s (reading the log, "
            f"the methods side by side, writing the outputs; as process printed it). {steps}")


def speed_rows(ev: Evaluation) -> list[list[str]]:
    return [[LABELS.get(m, m), str(len(ms)), _fmt(r["ms_per_sweep_median"], 2), _fmt(r["ms_per_sweep_p95"], 2),
             _fmt(r["ms_per_sweep_max"], 2), _fmt(r["ms_per_sweep_mean"], 2), _fmt(r["sweeps_per_second"], 0)]
            for m, r in ev.result["methods"].items() if len(ms := ev.sweep_ms.get(m, np.zeros(0)))]


def render_markdown(ev: Evaluation) -> str:
    r = ev.result
    fh, fr = feature_rows(r)
    parts = [f"# fmcwlog report: {ev.out_dir.name}", ""] + [f"- {k}: {v}" for k, v in header_rows(r)] + ["",
             f"Log `{ev.log}`, {r['sweeps']} sweeps, prior: {r['prior']}, Doppler: {'on' if r['doppler'] else 'off'}.", "",
             "## Trajectory, segmentation, speed", "",
             markdown_table(*without_empty_columns(TRAJECTORY_HEADER, trajectory_rows(r))), ""]
    if ev.gt is None and disagreement_rows(r):
        parts += ["## How far the methods disagree", "", _disagreement_intro(r), "",
                  markdown_table(DISAGREEMENT_HEADER, disagreement_rows(r)), ""]
    if ate_rows(r):
        parts += ["## Position error (ATE), evo_ape's statistics", "", ATE_INTRO, "",
                  markdown_table(ATE_HEADER, ate_rows(r)), ""]
    if speed_rows(ev):
        parts += ["## Time per sweep", "", markdown_table(SPEED_HEADER, speed_rows(ev)), "", run_rate_line(r), ""]
    parts += ["## Map feature lengths (the paper's Tables 2 and 3)", "",
              markdown_table(fh, fr) if fr else "No feature lengths (see the notes).", "", _summary_line(r), ""]
    rel = relations_rows(r)
    if rel:
        parts += [f"## Relations metric ({r['relations_file']})", "", markdown_table(RELATIONS_HEADER, rel), ""]
    if sources_rows(r) or calibration_rows(r):
        parts += ["## Motion sources and the calibration check", ""]
        if sources_rows(r):
            parts += [markdown_table(SOURCES_HEADER, sources_rows(r)), ""]
        if calibration_rows(r):
            parts += [markdown_table(CALIBRATION_HEADER, calibration_rows(r)), ""]
    notes = _notes(r)
    if notes:
        parts += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    parts += ["## Parameters", "", "```json", json.dumps(r["params"], indent=2), "```", ""]
    return "\n".join(parts)


def _html_table(header: list[str], rows: list[list[str]], text_columns: int = 1) -> str:
    """A table whose first ``text_columns`` columns are text (left-aligned), the others numbers."""
    left = ' class="text"'
    head = "".join(f"<th{left if i < text_columns else ''}>{html.escape(h)}</th>" for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(f"<td{left if i < text_columns else ''}>{html.escape(c)}</td>"
                                    for i, c in enumerate(r)) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


_STYLE = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: right; }
th { background: #f3f3f3; } .text { text-align: left; }
table.header td { text-align: left; border: none; padding: 0.1em 1em 0.1em 0; }
table.header td:first-child { color: #666; }
figure { margin: 1em 0; } img { max-width: 100%; border: 1px solid #eee; }
figcaption { font-size: 0.85em; color: #555; } .grid { display: flex; flex-wrap: wrap; gap: 1em; }
.grid figure { flex: 1 1 45%; margin: 0; }
pre { background: #f7f7f7; padding: 1em; overflow-x: auto; font-size: 0.85em; }
"""


def _header_html(r: dict) -> str:
    rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in header_rows(r))
    return f'<table class="header">{rows}</table>'


def _ground_truth_html(r: dict, img) -> str:
    """The trajectory section's figures against ground truth; without it, the methods' disagreement."""
    if "trajectories" in img.plots:
        errors = "".join(img(f"error_{m}", f"{LABELS.get(m, m)} trajectory coloured by its position error")
                         for m in r["methods"])
        return f"""{img("trajectories", "trajectories over the world's walls")}
{img("xy_yaw", "x, y and yaw over time, with ground truth")}
<h3>Position error (ATE), evo_ape's statistics</h3>
<p>{html.escape(ATE_INTRO)}</p>
{_html_table(ATE_HEADER, ate_rows(r))}
{img("errors", "position error along the path")}
{img("histograms", "distribution of the position error")}
<h3>Position error along the path</h3><div class="grid">{errors}</div>
<h3>Relative pose error against distance travelled</h3>
{img("rpe", "relative pose error of each pair against distance travelled")}
<h3>Heading error</h3>
{img("heading", "heading error over time")}"""
    if not disagreement_rows(r):
        return ""
    return f"""<h2>How far the methods disagree (no ground truth)</h2>
<p>{html.escape(_disagreement_intro(r))}</p>
{_html_table(DISAGREEMENT_HEADER, disagreement_rows(r))}
{img("aligned_on_map", "trajectories aligned onto the reference one, over its map")}
{img("disagreement", "disagreement between the methods along the path")}"""


class _Figures:
    """``img(key, alt)``: a figure with its caption, or nothing if that plot was not drawn."""

    def __init__(self, plots: dict[str, str]):
        self.plots = plots

    def __call__(self, key: str, alt: str) -> str:
        if key not in self.plots:
            return ""
        return f'<figure><img alt="{html.escape(alt)}" src="{self.plots[key]}"><figcaption>{html.escape(alt)}' \
               "</figcaption></figure>"


def render_html(ev: Evaluation) -> str:
    r = ev.result
    img = _Figures(all_plots(ev))
    fh, fr = feature_rows(r)
    notes = _notes(r)
    maps = "".join(img(f"map_{m}", f"occupancy map built by the {m} method, with its trajectory")
                   for m in ("improved", "baseline"))
    maps += "".join(img(f"closures_{m}", f"the {m} method's loop closures on its map") for m in ("improved", "baseline"))
    digest = (r.get("header") or {}).get("params_sha256_12")
    speed = speed_rows(ev)
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>fmcwlog report: {html.escape(ev.out_dir.name)}</title>
<style>{_STYLE}</style></head><body>
<h1>fmcwlog report: {html.escape(ev.out_dir.name)}</h1>
{_header_html(r)}
<p>Log <code>{html.escape(str(ev.log))}</code>: {r['sweeps']} sweeps; motion prior: {html.escape(str(r['prior']))};
Doppler stages: {'on' if r['doppler'] else 'off'}.</p>
<h2>Trajectory, segmentation, speed</h2>
{_html_table(*without_empty_columns(TRAJECTORY_HEADER, trajectory_rows(r)))}
{_ground_truth_html(r, img)}
{f"<h2>Time per sweep</h2>{_html_table(SPEED_HEADER, speed)}<p>{html.escape(run_rate_line(r))}</p>" if speed else ""}
{img("sweep_times", "time per sweep of each method")}
<h2>Map feature lengths (the paper's Tables 2 and 3)</h2>
{_html_table(fh, fr, text_columns=2) if fr else "<p>No feature lengths (see the notes).</p>"}
<p>{html.escape(_summary_line(r))}</p>
{img("features", "relative error of each feature, both methods")}
<p>How a feature is measured: its two ends are found in the occupancy map the method built (its own
frame) and its length is their distance in that map. The ground truth only says where to look (the
trajectory aligned to it over the poses within 8 m of the end) and what to look for (a corner or a
wall end); the walls there are fitted in the map's occupied cells. A feature the map does not show
well enough is not measurable and not scored (its row says why).</p>
{_relations_html(r)}
{_sources_html(r)}
<h2>Maps</h2><div class="grid">{maps}</div>
<h2>Notes</h2>{"<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>" if notes else "<p>None.</p>"}
<h2>Parameters (digest {html.escape(str(digest))})</h2>
<details><summary>run.json's params</summary><pre>{html.escape(json.dumps(r['params'], indent=2))}</pre></details>
</body></html>
"""


SOURCES_HEADER = ["method", "Doppler observes", "Doppler share of v", "Doppler share of ω", "sweeps held to the fused motion",
                  "source dropped"]
CALIBRATION_HEADER = ["value", "calibration", "estimate from the log", "σ", "verdict"]


def sources_rows(result: dict) -> list[list[str]]:
    """Where each method's motion came from (run.json's ``motion_sources``)."""
    rows = []
    for m, s in (result.get("motion_sources") or {}).items():
        checks = s.get("sensor_checks") or {}
        dropped = [f"{what} at {checks[key]:.1f} s" for what, key in (("Doppler", "doppler_dropped_at_s"),
                                                                       ("wheels", "wheels_dropped_at_s"))
                   if checks.get(key) is not None]
        rows.append([m, str(s.get("doppler_observes", "—")), _fmt(s.get("doppler_share_v"), 3),
                     _fmt(s.get("doppler_share_omega"), 3), str(s.get("doppler_prior_sweeps", "—")),
                     ", ".join(dropped) or "none"])
    return rows


def calibration_rows(result: dict) -> list[list[str]]:
    """The calibration check (run.json's ``calibration_check``): each value against the log's own estimate."""
    check = result.get("calibration_check") or {}
    rows = []
    for name, v in (check.get("values") or {}).items():
        if v.get("disagrees"):
            verdict = "disagrees (beyond 3σ and its tolerance)"
        else:
            verdict = "differs by over 3σ, within its tolerance" if v.get("differs") else "agrees"
        rows.append([name, _fmt(v.get("calibration"), 4), _fmt(v.get("estimate"), 4), _fmt(v.get("sigma"), 4), verdict])
    rows += [[name, "—", "not estimated", "—", str(why)] for name, why in (check.get("not_estimated") or {}).items()]
    return rows


def _sources_html(r: dict) -> str:
    sources, cal = sources_rows(r), calibration_rows(r)
    if not sources and not cal:
        return ""
    parts = ["<h2>Motion sources and the calibration check</h2>"]
    if sources:
        parts.append(_html_table(SOURCES_HEADER, sources, text_columns=2))
    check = r.get("calibration_check") or {}
    if cal:
        parts.append("<p>The LiDAR's mount and the wheels estimated from this log (Doppler, wheel turns and "
                     "scan-matched heading changes); <code>fmcwlog calibrate</code> writes them as a file "
                     "<code>process --calibration</code> takes. Units: m and rad.</p>")
        parts.append(_html_table(CALIBRATION_HEADER, cal))
    elif check.get("reason"):
        parts.append(f"<p>No calibration check: {html.escape(str(check['reason']))}</p>")
    return "".join(parts)


def _relations_html(r: dict) -> str:
    rows = relations_rows(r)
    if not rows:
        return ""
    return (f"<h2>Relations metric ({html.escape(str(r.get('relations_file')))})</h2>"
            + _html_table(RELATIONS_HEADER, rows))


def write_report(ev: Evaluation) -> list[Path]:
    """Write report.json, report.md and report.html into the output folder (each via a temporary name),
    and the log's ground truth as ``gt.tum`` beside the estimates (``base_link`` in ``map``; evo:
    ``evo_ape tum gt.tum improved.tum -a``)."""
    out = []
    if ev.gt_ns is not None and ev.gt is not None:
        with atomic_path(ev.out_dir / GROUND_TRUTH_TUM) as tmp:
            write_tum(tmp, ev.gt_ns, ev.gt)
        out.append(ev.out_dir / GROUND_TRUTH_TUM)
    for name, text in (("report.json", json_text(ev.result)), ("report.md", render_markdown(ev)),
                       ("report.html", render_html(ev))):
        write_text(ev.out_dir / name, text)
        out.append(ev.out_dir / name)
    return out


def comparison_rows(results: list[dict]) -> tuple[list[str], list[list[str]]]:
    header = ["output", "method", "ATE RMSE cm", "RPE 1 m % (mean)", "RPE 10 m % (mean)", "feature error %",
              "moving F1", "median ms per sweep"]
    rows = []
    for res in results:
        for m, r in res["methods"].items():
            seg = r.get("segmentation") or {}
            rows.append([Path(res["out_dir"]).name, LABELS.get(m, m), _fmt(r["ate_rmse_m"], 1, 100),
                         _fmt(r["rpe_1m_pct"], 2), _fmt(r["rpe_10m_pct"], 2), _fmt(r["feature_avg_rel_error_pct"], 2),
                         _fmt(seg.get("f1"), 3), _fmt(r["ms_per_sweep_median"], 2)])
    return header, rows
