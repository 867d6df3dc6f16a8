"""The fleet page's figures (matplotlib, Agg), each a self-contained ``data:image/png`` URI as the
report page embeds its own (:func:`fmcwlog.evaluation.plots.png`).

- errors per log: horizontal bars, a row per log, a bar per method: the ATE RMSE (cm) of the logs
  with ground truth, the methods' disagreement (cm) of the logs without; the outlier threshold
  (:func:`fmcwlog.evaluation.fleet.outliers`) dashed where the sample was large enough to rank, and a
  flagged log's name in red;
- time per log: the processing wall-clock time (s) and each method's median ms per sweep;
- a map thumbnail per log: the occupancy map the improved method built (else the baseline's),
  cropped to its occupied cells, with that method's trajectory.

A figure is None where the fleet has nothing to draw in it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..io.outputs import read_tum
from .plots import Box, _map_image, _occupied_box, _pyplot, color, label, png

BAR_METHODS = ("improved", "baseline")  # wheel odometry's metres would squash the methods' centimetres
ROW_IN = 0.32  # inches of figure per log row
LOG_SPAN = 30.0  # bars whose values span more than this factor get a logarithmic axis
MAX_THUMBNAILS = 60  # a bigger fleet shows the flagged logs first, then the rest up to this many
_FLAGGED = "#b71c1c"


Series = list[tuple[str, str, list[float | None]]]  # (legend label, colour, a value per log)


def _by_method(rows: list[dict[str, Any]], key: str, methods: tuple[str, ...] | list[str]) -> Series:
    return [(label(m), color(m), [r[key].get(m) for r in rows]) for m in methods
            if any(r[key].get(m) is not None for r in rows)]


def _bars(ax, names: list[str], series: Series, unit_scale: float, fmt: str,
          marked: list[set[int]] | None = None) -> str:
    """Grouped horizontal bars, one group per name (top to bottom), one bar per series; each bar's value
    written at its end; a missing value is no bar; ``marked[i]``: the series whose bar of name ``i`` is
    outlined and starred (the best of its group). Where the values span more than
    :data:`LOG_SPAN` (a centimetre beside metres), the x axis is logarithmic so the small bars show;
    returns ``", log scale"`` then for the axis label, else ``""``."""
    y = np.arange(len(names))[::-1].astype(float)
    height = 0.8 / max(1, len(series))
    shown = [v * unit_scale for _, _, vals in series for v in vals if v is not None and v > 0]
    top, low = max(shown or [1.0]), min(shown or [1.0])
    log = top > LOG_SPAN * low
    left = 10 ** np.floor(np.log10(low / 2)) if log else 0.0
    for j, (name, colour, vals) in enumerate(series):
        off = (j - (len(series) - 1) / 2) * height
        xs = [left if v is None else max(v * unit_scale, left) - left for v in vals]
        stars = [marked is not None and j in marked[i] and v is not None for i, v in enumerate(vals)]
        ax.barh(y - off, xs, left=left, height=height * 0.95, color=colour, label=name)
        if any(stars):  # the outline drawn apart: the legend's swatch stays plain
            ax.barh([yi for yi, st in zip(y - off, stars) if st], [x for x, st in zip(xs, stars) if st], left=left,
                    height=height * 0.95, fill=False, edgecolor="#111111", linewidth=1.4)
        for yi, v, st in zip(y - off, vals, stars):
            if v is not None:
                at = v * unit_scale * 1.08 if log else v * unit_scale + 0.01 * top
                ax.text(max(at, left), yi, fmt.format(v * unit_scale) + (" ★" if st else ""), va="center",
                        fontsize=7, fontweight="bold" if st else "normal")
    ax.set_yticks(y, names, fontsize=8)
    ax.set_ylim(-0.6, len(names) - 0.4)
    if log:
        _log_x(ax)
        ax.set_xlim(left, top * 3)
    else:
        ax.set_xlim(0, top * 1.15)
    ax.grid(True, axis="x", alpha=0.3)
    return ", log scale" if log else ""


def _log_x(ax) -> None:
    """A log x axis labelled with plain numbers (0.1, 1, 10), as the report's log axes."""
    from matplotlib.ticker import FuncFormatter, NullLocator

    ax.set_xscale("log")
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_locator(NullLocator())


def _red_flagged(ax, flagged: set[str]) -> None:
    for tick in ax.get_yticklabels():
        if tick.get_text() in flagged:
            tick.set_color(_FLAGGED)
            tick.set_fontweight("bold")


def _threshold(ax, rule: dict[str, Any] | None, scale: float) -> None:
    if rule and not rule["too_few"] and rule["threshold"] is not None:
        x = rule["threshold"] * scale
        ax.axvline(x, color=_FLAGGED, ls="--", lw=1, label=f"flagged above ({x:.1f} cm)")
        ax.set_xlim(right=max(ax.get_xlim()[1], x * 1.1))


def _rule(result: dict[str, Any], metric: str) -> dict[str, Any] | None:
    for r in (result.get("outlier_rule") or {}).get("metrics", []):
        if r["metric"] == metric:
            return r
    return None


def errors_per_log(result: dict[str, Any]):
    """ATE RMSE per log and method (logs with ground truth) and the methods' disagreement per log (logs
    without), cm, as horizontal bars; None where no log has either."""
    plt = _pyplot()
    done = [r for r in result["logs"] if r["status"] == "done"]
    with_gt = [r for r in done if r["ground_truth"] and any(r["ate_rmse_m"].get(m) is not None for m in BAR_METHODS)]
    without = [r for r in done if not r["ground_truth"] and r["methods_disagreement_m"] is not None]
    panels = [p for p in (("gt", with_gt), ("free", without)) if p[1]]
    if not panels:
        return None
    flagged = {f["name"] for f in result["flagged"]}
    heights = [ROW_IN * len(rows) * (len(BAR_METHODS) if kind == "gt" else 1) + 1.0 for kind, rows in panels]
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, sum(heights) + 0.6), squeeze=False,
                             gridspec_kw={"height_ratios": heights}, layout="constrained")
    for ax, (kind, rows) in zip(axes[:, 0], panels):
        names = [r["name"] for r in rows]
        if kind == "gt":
            scale = _bars(ax, names, _by_method(rows, "ate_rmse_m", BAR_METHODS), 100.0, "{:.1f}")
            _threshold(ax, _rule(result, "ate_rmse_m"), 100.0)
            ax.set_xlabel(f"ATE RMSE (cm{scale}; SE(2)-aligned to ground truth, as evo_ape -a)")
            ax.set_title(f"Position error per log ({len(rows)} logs with ground truth)", fontsize=10)
        else:
            scale = _bars(ax, names, [("improved vs baseline", "#7b1fa2", [r["methods_disagreement_m"] for r in rows])],
                          100.0, "{:.1f}")
            _threshold(ax, _rule(result, "methods_disagreement_m"), 100.0)
            ax.set_xlabel(f"disagreement between improved and baseline (cm RMSE after SE(2) alignment{scale})")
            ax.set_title(f"How far the methods part per log ({len(rows)} logs without ground truth: "
                         "not an error)", fontsize=10)
        _red_flagged(ax, flagged)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)  # never over a bar
    return fig


def time_per_log(result: dict[str, Any]):
    """Per log, the processing wall-clock time (s) and each method's median ms per sweep, as horizontal
    bars; None where no log has either."""
    plt = _pyplot()
    rows = [r for r in result["logs"] if r["status"] == "done"]
    methods = [m for m in BAR_METHODS if any(r["ms_per_sweep"].get(m) is not None for r in rows)]
    if not rows or (not methods and not any(r["wall_s"] for r in rows)):
        return None
    names = [r["name"] for r in rows]
    h = ROW_IN * len(rows) * max(1, len(methods)) + 1.2
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, h), sharey=False, layout="constrained")
    scale = _bars(left, names, [("wall clock", "#5c6bc0", [r["wall_s"] for r in rows])], 1.0, "{:.1f}")
    left.set_xlabel(f"processing time of the log (s, wall clock{scale})")
    left.set_title("Processing time per log", fontsize=10)
    if methods:
        scale = _bars(right, names, _by_method(rows, "ms_per_sweep", methods), 1.0, "{:.2f}")
        right.set_xlabel(f"median time per sweep (ms, each method's own step{scale})")
        right.set_title("Time per sweep per log and method", fontsize=10)
        right.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    else:
        right.set_axis_off()
    return fig


THUMB_PX = 250  # a thumbnail's longer side, pixels of the map shown


def shrunk_map(pixels: np.ndarray, box: Box, extent: Box, px: int = THUMB_PX) -> tuple[np.ndarray, Box]:
    """The part of a map image (``pixels``, 0 occupied .. 255 free, spanning ``extent`` in metres)
    inside ``box``, shrunk to at most ``px`` pixels a side by keeping each block's darkest cell: a wall
    one cell thick stays a line, where averaging would fade it to grey. Returns the image and its extent."""
    h, w = pixels.shape
    res = (extent[1] - extent[0]) / w
    c0, c1 = (max(0, int((box[0] - extent[0]) / res)), min(w, int(np.ceil((box[1] - extent[0]) / res))))
    r0, r1 = (max(0, int((extent[3] - box[3]) / res)), min(h, int(np.ceil((extent[3] - box[2]) / res))))
    part = pixels[r0:r1, c0:c1]
    k = max(1, int(np.ceil(max(part.shape) / px)))
    ph, pw = -(-part.shape[0] // k) * k, -(-part.shape[1] // k) * k
    padded = np.full((ph, pw), 255, dtype=part.dtype)
    padded[:part.shape[0], :part.shape[1]] = part
    small = padded.reshape(ph // k, k, pw // k, k).min(axis=(1, 3))
    x0, y1 = extent[0] + c0 * res, extent[3] - r0 * res
    return small, (x0, x0 + pw * res, y1 - ph * res, y1)


def map_thumbnail(folder: Path):
    """The occupancy map the improved method built in ``folder`` (else the baseline's), cropped to its
    occupied cells and shrunk (:func:`shrunk_map`), with that method's trajectory; a small figure
    without ticks, its size in metres in the x label; None without a map."""
    plt = _pyplot()
    for m in BAR_METHODS:
        image = _map_image(folder, m)
        if image is not None:
            break
    else:
        return None
    occupied = _occupied_box(image) or image[1]
    pad = 0.03 * max(occupied[1] - occupied[0], occupied[3] - occupied[2]) + 0.3
    box = (occupied[0] - pad, occupied[1] + pad, occupied[2] - pad, occupied[3] + pad)
    small, extent = shrunk_map(image[0], box, image[1])
    fig, ax = plt.subplots(figsize=(2.6, 2.6), layout="constrained")
    ax.imshow(small, cmap="gray", vmin=0, vmax=255, extent=extent, interpolation="nearest")
    tum = folder / f"{m}.tum"
    if tum.is_file():
        _, poses = read_tum(tum)
        ax.plot(poses[:, 0], poses[:, 1], color=color(m), lw=1.2)
    ax.set_xlim(box[0], box[1])
    ax.set_ylim(box[2], box[3])
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_xlabel(f"{occupied[1] - occupied[0]:.0f} × {occupied[3] - occupied[2]:.0f} m, {label(m)} map", fontsize=8)
    return fig


def thumbnail_order(result: dict[str, Any]) -> list[dict[str, Any]]:
    """The logs whose thumbnails the page shows: flagged ones first, then the rest, up to MAX_THUMBNAILS."""
    flagged = {f["name"] for f in result["flagged"]}
    done = [r for r in result["logs"] if r["status"] == "done"]
    return sorted(done, key=lambda r: (r["name"] not in flagged, r["name"]))[:MAX_THUMBNAILS]


def fleet_plots(out_dir: Path, result: dict[str, Any]) -> dict[str, str]:
    """Every fleet figure that can be drawn, keyed by name (``errors``, ``times``, ``map:<log>``), as
    data URIs."""
    out: dict[str, str] = {}
    for key, fig in (("errors", errors_per_log(result)), ("times", time_per_log(result))):
        if fig is not None:
            out[key] = png(fig)
    for r in thumbnail_order(result):
        fig = map_thumbnail(out_dir / r["name"])
        if fig is not None:
            out[f"map:{r['name']}"] = png(fig)
    return out
