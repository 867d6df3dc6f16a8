"""``fmcwlog report``'s pages: report.html (self-contained), report.md, report.json, a terminal table.

report.json keys (stable; ``null`` where a value cannot be computed, with the
reason in ``notes`` or ``methods.M.notes``):

- ``methods.M`` for M in ``improved``, ``baseline``, ``wheel_odometry``:
  ``ate_rmse_m``, ``ate_mean_m``, ``ate_median_m``, ``ate_max_m`` (SE(2)-aligned,
  evo's ``evo_ape -a``), ``ate_first_aligned_rmse_m`` (first poses aligned),
  ``rpe_1m_pct``, ``rpe_10m_pct`` (mean translation error over 1 m / 10 m of
  travel, % of the distance), ``rpe_1m_deg_per_m``, ``rpe_10m_deg_per_m`` (mean
  yaw error per metre), ``features`` (list of ``{id, name, true_m, measured_m,
  abs_error_m, rel_error_pct}``), ``feature_avg_rel_error_pct``,
  ``segmentation`` (``precision``, ``recall``, ``f1`` and counts),
  ``ms_per_sweep_median``, ``ms_per_sweep_p95``, ``sweeps_per_second``, ``notes``;
- ``feature_avg_rel_error_reduction_pct``: how much the improved method cuts the
  baseline's average relative feature error (the paper's figures: :mod:`fmcwlog.evaluation.published`);
- ``paper``, ``params``, ``log``, ``out_dir``, ``sweeps``, ``doppler``, ``prior``, ``notes``.
"""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path
from typing import Any

import numpy as np

from ..io.atomic import atomic_path, json_text, write_text
from ..io.outputs import pgm_pixels, read_tum, write_tum
from .evaluate import Evaluation
from .published import paper_summary

LABELS = {"improved": "improved", "baseline": "baseline", "wheel_odometry": "wheel odometry"}
COLORS = {"improved": "#1b7837", "baseline": "#c2185b", "wheel_odometry": "#999999", "truth": "#000000"}


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
                     _fmt(r["ms_per_sweep_median"], 2), _fmt(r["sweeps_per_second"], 0)])
    return rows


TRAJECTORY_HEADER = ["method", "ATE RMSE cm", "ATE max cm", "ATE RMSE cm (first pose)", "RPE 1 m %", "RPE 10 m %",
                     "RPE 1 m deg/m", "feature error %", "moving precision", "moving recall", "moving F1",
                     "ms/sweep", "sweeps/s"]


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


def _summary_line(result: dict) -> str:
    red = result["feature_avg_rel_error_reduction_pct"]
    imp = result["methods"].get("improved", {}).get("feature_avg_rel_error_pct")
    base = result["methods"].get("baseline", {}).get("feature_avg_rel_error_pct")
    if red is None:
        return "The average relative feature error could not be compared (see the notes)."
    return (f"Average relative feature error: baseline {base:.2f} %, improved {imp:.2f} %: "
            f"a {red:.1f} % reduction ({paper_summary()}).")


def render_markdown(ev: Evaluation) -> str:
    r = ev.result
    fh, fr = feature_rows(r)
    parts = [f"# fmcwlog report: {ev.out_dir.name}", "",
             f"Log `{ev.log}`, {r['sweeps']} sweeps, prior: {r['prior']}, Doppler: {'on' if r['doppler'] else 'off'}.", "",
             "## Trajectory, segmentation, speed", "", markdown_table(TRAJECTORY_HEADER, trajectory_rows(r)), "",
             "## Map feature lengths (the paper's Tables 2 and 3)", "",
             markdown_table(fh, fr) if fr else "No feature lengths (see the notes).", "", _summary_line(r), ""]
    rel = relations_rows(r)
    if rel:
        parts += [f"## Relations metric ({r['relations_file']})", "", markdown_table(RELATIONS_HEADER, rel), ""]
    notes = _notes(r)
    if notes:
        parts += ["## Notes", ""] + [f"- {n}" for n in notes] + [""]
    parts += ["## Parameters", "", "```json", json.dumps(r["params"], indent=2), "```", ""]
    return "\n".join(parts)


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _plots(ev: Evaluation, walls: np.ndarray | None) -> dict[str, str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots: dict[str, str] = {}
    r = ev.result
    if ev.gt is not None and ev.aligned:
        fig, ax = plt.subplots(figsize=(7.5, 7))
        if walls is not None and len(walls):
            for x1, y1, x2, y2 in walls:
                ax.plot([x1, x2], [y1, y2], color="#bbbbbb", lw=1.5)
        ax.plot(ev.gt[:, 0], ev.gt[:, 1], color=COLORS["truth"], lw=1.2, label="ground truth")
        for m, (_, est, _) in ev.aligned.items():
            ax.plot(est[:, 0], est[:, 1], color=COLORS.get(m), lw=1.0, label=LABELS.get(m, m))
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title("Trajectories (SE(2)-aligned to ground truth) over the world's walls")
        ax.legend(loc="best", fontsize=8)
        plots["trajectories"] = _png(fig)

        fig, ax = plt.subplots(figsize=(8, 3.2))
        for m, (t, _, err) in ev.aligned.items():
            ax.plot(t - t[0], err * 100, color=COLORS.get(m), lw=1, label=LABELS.get(m, m))
        ax.set_xlabel("time since first sweep (s)")
        ax.set_ylabel("position error (cm)")
        ax.set_yscale("log")
        ax.set_title("Absolute position error along the path")
        ax.legend(fontsize=8)
        plots["errors"] = _png(fig)

    feats = {m: r["methods"][m]["features"] for m in ("baseline", "improved")
             if (r["methods"].get(m) or {}).get("features")}
    if feats:
        fig, ax = plt.subplots(figsize=(8, 3.2))
        first = next(iter(feats.values()))
        x = np.arange(len(first))
        width = 0.8 / len(feats)
        for i, (m, fs) in enumerate(feats.items()):
            vals = [f["rel_error_pct"] if f["rel_error_pct"] is not None else np.nan for f in fs]
            ax.bar(x + (i - (len(feats) - 1) / 2) * width, vals, width, color=COLORS[m], label=LABELS[m])
        ax.set_xticks(x, [str(f["id"]) for f in first])
        ax.set_xlabel("feature")
        ax.set_ylabel("relative error (%)")
        ax.set_title("Relative error of the feature lengths (as the paper's Figure 4)")
        ax.legend(fontsize=8)
        plots["features"] = _png(fig)
    for m in ("improved", "baseline"):
        fig = _trajectory_over_own_map(ev.out_dir, m)
        if fig is not None:
            plots[f"map_{m}"] = _png(fig)
        fig = loop_closures_over_map(ev.out_dir, m)
        if fig is not None:
            plots[f"closures_{m}"] = _png(fig)
    return plots


def loop_closures_over_map(out_dir: Path, method: str):
    """The back end's loop closures (``<method>_backend.json``) drawn on the method's map: each a
    segment between its two nodes at their optimised poses, green where the Cauchy kernel kept it,
    red where it did not; the front end's own trajectory dashed. None without a back end."""
    import matplotlib.pyplot as plt

    graph = out_dir / f"{method}_backend.json"
    fig = _trajectory_over_own_map(out_dir, method) if graph.is_file() else None
    if fig is None:
        return None
    ax = fig.axes[0]
    data = json.loads(graph.read_text())
    stamps = np.asarray(data["nodes"]["stamp_ns"], np.int64)
    xy = np.column_stack([data["nodes"]["x"], data["nodes"]["y"]])
    at = {int(s): i for i, s in enumerate(stamps)}
    for kept, color in ((True, "#1565c0"), (False, "#d32f2f")):
        segs = [(xy[at[c["candidate_stamp_ns"]]], xy[at[c["query_stamp_ns"]]]) for c in data["closures"]
                if c["accepted"] is kept]
        for a, b in segs:
            ax.plot([a[0], b[0]], [a[1], b[1]], color=color, lw=0.8, alpha=0.8)
        ax.plot([], [], color=color, lw=0.8, label=f"loop closures {'kept' if kept else 'down-weighted'} ({len(segs)})")
    front = out_dir / f"{method}_frontend.tum"
    if front.is_file():
        _, fposes = read_tum(front)
        ax.plot(fposes[:, 0], fposes[:, 1], color="#777777", lw=0.7, ls="--", label="front end alone")
    ax.set_title(f"Loop closures of the {LABELS.get(method, method)} method's back end, on its map")
    ax.legend(loc="upper right", fontsize=7)
    plt.figure(fig.number)
    return fig


def _trajectory_over_own_map(out_dir: Path, method: str):
    """The occupancy map a method built, with its own trajectory on it (its own frame; no ground truth needed)."""
    import matplotlib.pyplot as plt
    import yaml


    pgm, meta, tum = (out_dir / f"{method}_map.pgm", out_dir / f"{method}_map.yaml", out_dir / f"{method}.tum")
    if not (pgm.is_file() and meta.is_file() and tum.is_file()):
        return None
    info = yaml.safe_load(meta.read_text())
    img = pgm_pixels(pgm.read_bytes())
    res, (ox, oy) = float(info["resolution"]), info["origin"][:2]
    h, w = img.shape
    _, poses = read_tum(tum)
    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    ax.imshow(img, cmap="gray", vmin=0, vmax=255, extent=(ox, ox + w * res, oy, oy + h * res), interpolation="nearest")
    ax.plot(poses[:, 0], poses[:, 1], color=COLORS.get(method), lw=1.0, label=f"{LABELS.get(method, method)} trajectory")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Map built by the {LABELS.get(method, method)} method, with its trajectory")
    ax.legend(loc="upper right", fontsize=8)
    return fig


def _html_table(header: list[str], rows: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def render_html(ev: Evaluation, walls: np.ndarray | None) -> str:
    r = ev.result
    plots = _plots(ev, walls)
    fh, fr = feature_rows(r)
    img = lambda key, alt: (f'<figure><img alt="{alt}" src="{plots[key]}"><figcaption>{alt}</figcaption></figure>'
                            if key in plots else "")
    notes = _notes(r)
    maps = "".join(img(f"map_{m}", f"occupancy map built by the {m} method, with its trajectory")
                   for m in ("improved", "baseline"))
    maps += "".join(img(f"closures_{m}", f"the {m} method's loop closures on its map") for m in ("improved", "baseline"))
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>fmcwlog report: {html.escape(ev.out_dir.name)}</title>
<style>
body {{ font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; }}
table {{ border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }}
th, td {{ border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: right; }}
th {{ background: #f3f3f3; }} td:first-child, th:first-child {{ text-align: left; }}
figure {{ margin: 1em 0; }} img {{ max-width: 100%; border: 1px solid #eee; }}
figcaption {{ font-size: 0.85em; color: #555; }} .maps {{ display: flex; flex-wrap: wrap; gap: 1em; }}
.maps figure {{ flex: 1 1 45%; }}
pre {{ background: #f7f7f7; padding: 1em; overflow-x: auto; font-size: 0.85em; }}
</style></head><body>
<h1>fmcwlog report: {html.escape(ev.out_dir.name)}</h1>
<p>Log <code>{html.escape(str(ev.log))}</code>: {r['sweeps']} sweeps; motion prior: {html.escape(str(r['prior']))};
Doppler stages: {'on' if r['doppler'] else 'off'}.</p>
<h2>Trajectory, segmentation, speed</h2>
{_html_table(TRAJECTORY_HEADER, trajectory_rows(r))}
{img("trajectories", "trajectories over the world's walls")}
{img("errors", "position error along the path")}
<h2>Map feature lengths (the paper's Tables 2 and 3)</h2>
{_html_table(fh, fr) if fr else "<p>No feature lengths (see the notes).</p>"}
<p>{html.escape(_summary_line(r))}</p>
{img("features", "relative error of each feature, both methods")}
<p>How a feature is measured: the points each method kept for its map that saw an end of the feature
(found by placing them with the ground-truth pose) are averaged as the method placed them; the
distance between the two ends' averages, less the same distance with ground-truth placement, is the
method's error on that length.</p>
{_relations_html(r)}
<h2>Maps</h2><div class="maps">{maps}</div>
<h2>Notes</h2>{"<ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes) + "</ul>" if notes else "<p>None.</p>"}
<h2>Parameters</h2><pre>{html.escape(json.dumps(r['params'], indent=2))}</pre>
</body></html>
"""


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
        with atomic_path(ev.out_dir / "gt.tum") as tmp:
            write_tum(tmp, ev.gt_ns, ev.gt)
        out.append(ev.out_dir / "gt.tum")
    for name, text in (("report.json", json_text(ev.result)), ("report.md", render_markdown(ev)),
                       ("report.html", render_html(ev, ev.walls))):
        write_text(ev.out_dir / name, text)
        out.append(ev.out_dir / name)
    return out


def comparison_rows(results: list[dict]) -> tuple[list[str], list[list[str]]]:
    header = ["output", "method", "ATE RMSE cm", "RPE 1 m %", "RPE 10 m %", "feature error %", "moving F1", "ms/sweep"]
    rows = []
    for res in results:
        for m, r in res["methods"].items():
            seg = r.get("segmentation") or {}
            rows.append([Path(res["out_dir"]).name, LABELS.get(m, m), _fmt(r["ate_rmse_m"], 1, 100),
                         _fmt(r["rpe_1m_pct"], 2), _fmt(r["rpe_10m_pct"], 2), _fmt(r["feature_avg_rel_error_pct"], 2),
                         _fmt(seg.get("f1"), 3), _fmt(r["ms_per_sweep_median"], 2)])
    return header, rows
