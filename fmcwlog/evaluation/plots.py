"""The report's figures (matplotlib, Agg), each returned as a self-contained ``data:image/png`` URI.

With ground truth (as evo's plots): every trajectory SE(2)-aligned over the world's walls;
x, y and yaw over time (``evo_traj --plot``); each one coloured by its position error with a
colorbar (``evo_ape --plot_colormap_*``); position error over time and its histogram; RPE
per pair against the distance travelled where the pair starts (``evo_rpe``'s per-pair values, 1 m and 10 m);
heading error over time. Always: the time
per sweep as a distribution (box from quartiles, whisker to p95, the slower sweeps as dots,
median, p95 and max written out), each map with its own trajectory, and how far the
trajectories disagree once aligned onto the improved one (needs no ground truth). With
feature lengths: their relative errors (the paper's Figure 4).

The maps are framed on the walls (or a map's occupied cells), the ground truth (or the reference
trajectory) and the best trajectories: an outlier (wheel odometry wandering tens of metres) is
marked where it leaves the frame and said to in the legend, not followed.

Axis units are in every label. Legends sit outside the axes wherever a path could run under
them. Figures are rendered at :data:`DPI` for a page about 1100 px wide.
"""

from __future__ import annotations

import base64
import inspect
import io
import json
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from ..io.outputs import pgm_pixels, read_tum
from .evaluate import Evaluation

LABELS = {"improved": "improved", "baseline": "baseline", "wheel_odometry": "wheel odometry",
          "improved_frontend": "improved, front end alone", "baseline_frontend": "baseline, front end alone"}
# a front end's own trajectory in a paler shade of its method's: related, and told apart from every other
COLORS = {"improved": "#1b7837", "baseline": "#c2185b", "wheel_odometry": "#6e6e6e", "truth": "#000000",
          "improved_frontend": "#8fd18a", "baseline_frontend": "#f59ac3"}
_OTHER_COLORS = ("#1f77b4", "#ff7f0e", "#9467bd", "#17becf", "#bcbd22")
DPI = 100
LEGEND_CHARS_PER_INCH = 14.0  # characters of a 9-point legend label per inch of figure, about
ERROR_CMAP = "turbo"  # dark at both ends, so low and high errors both stand out on white


def label(m: str) -> str:
    """The name a method (or a peer) goes by on the figures."""
    return LABELS.get(m, m)


def color(m: str) -> str:
    """A method's colour on every figure; a peer's is picked from its name, the same on every run."""
    if m in COLORS:
        return COLORS[m]
    return _OTHER_COLORS[sum(map(ord, m)) % len(_OTHER_COLORS)]  # a peer: stable across runs


def line(m: str) -> str:
    """A trajectory's line style: dashed for a front end's own (often the same as its method's final
    trajectory, which it would otherwise hide), solid for the rest."""
    return "--" if m.endswith("_frontend") else "-"


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def png(fig) -> str:
    """The figure as a base64 PNG data URI; closes it."""
    plt = _pyplot()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _walls(ax, walls: np.ndarray | None) -> None:
    if walls is not None and len(walls):
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(list(walls.reshape(-1, 2, 2)), colors="#b0b0b0", linewidths=1.5, zorder=1))


def _legend_below(fig, ax, ncol: int) -> None:
    """A legend under the axes and their x label (the figure must use the constrained layout), in at
    most ``ncol`` columns and no wider than the figure: a legend wider than its axes would widen the
    saved image and shrink the whole figure on the page."""
    handles, labels = ax.get_legend_handles_labels()
    width_chars = fig.get_figwidth() * LEGEND_CHARS_PER_INCH
    fit = int(width_chars // (max((len(t) for t in labels), default=1) + 6))  # + the line sample and gap
    fig.legend(handles, labels, loc="outside lower center", ncol=max(1, min(ncol, fit)), fontsize=9, frameon=False)


def _log_y(ax, scale: str = "log", **kw) -> None:
    """A log (or symlog) y axis labelled with plain numbers (0.1, 1, 10) and no minor ticks:
    easier to read than 10^x, and the minor ticks would be half the drawing time of these figures."""
    from matplotlib.ticker import FuncFormatter, NullLocator

    ax.set_yscale(scale, **kw)
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_locator(NullLocator())


def _t0(ev: Evaluation) -> float:
    return float(min(t[0] for t, _, _ in ev.aligned.values()))


Box = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax (m)
FRAMED_WITHIN = 3.0  # a trajectory frames the plots when its ATE RMSE is within this factor of the best one's


def bounds(xy: np.ndarray) -> Box | None:
    """The (xmin, xmax, ymin, ymax) of finite points ``xy`` (N, 2), or None when there are none."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    xy = xy[np.all(np.isfinite(xy), axis=1)]
    if not len(xy):
        return None
    return float(xy[:, 0].min()), float(xy[:, 0].max()), float(xy[:, 1].min()), float(xy[:, 1].max())


def frame(boxes: list[Box | None], pad_share: float = 0.05, pad_m: float = 0.5) -> Box | None:
    """The union of ``boxes`` widened by ``pad_share`` of its larger side plus ``pad_m`` (m) each way."""
    given = [b for b in boxes if b is not None]
    if not given:
        return None
    x0, x1 = min(b[0] for b in given), max(b[1] for b in given)
    y0, y1 = min(b[2] for b in given), max(b[3] for b in given)
    pad = pad_share * max(x1 - x0, y1 - y0) + pad_m
    return x0 - pad, x1 + pad, y0 - pad, y1 + pad


def beyond(box: Box, xy: np.ndarray) -> float:
    """How far (m) the farthest of ``xy`` (N, 2) lies outside ``box``; 0 when every point is inside."""
    dx = np.maximum(np.maximum(box[0] - xy[:, 0], xy[:, 0] - box[1]), 0.0)
    dy = np.maximum(np.maximum(box[2] - xy[:, 1], xy[:, 1] - box[3]), 0.0)
    return float(np.max(np.hypot(dx, dy))) if len(xy) else 0.0


def framing_methods(rmse: dict[str, float]) -> list[str]:
    """The trajectories the plots are framed on: those whose ATE RMSE (m) is within
    :data:`FRAMED_WITHIN` times the lowest (the best ones); an outlier (wheel odometry wandering
    tens of metres) is drawn as far as the frame goes and said to leave it, not followed."""
    if not rmse:
        return []
    best = min(rmse.values())
    return [m for m, v in rmse.items() if v <= FRAMED_WITHIN * best + 1e-9]


def _walls_box(walls: np.ndarray | None) -> Box | None:
    return bounds(np.asarray(walls).reshape(-1, 2)) if walls is not None and len(walls) else None


def _frame_axes(ax, box: Box, paths: dict[str, np.ndarray]) -> dict[str, float]:
    """Set ``ax``'s limits to ``box`` (equal aspect) and mark where each path of ``paths`` crosses
    its edge (an ✕ at the pose inside, the first six crossings); returns how far (m) each path that leaves goes beyond."""
    ax.set_xlim(box[0], box[1])
    ax.set_ylim(box[2], box[3])
    ax.set_aspect("equal")
    out = {}
    for m, xy in paths.items():
        far = beyond(box, xy[:, :2])
        if far > 0.0:
            out[m] = far
            inside = (xy[:, 0] >= box[0]) & (xy[:, 0] <= box[1]) & (xy[:, 1] >= box[2]) & (xy[:, 1] <= box[3])
            cross = np.flatnonzero(inside[:-1] != inside[1:])[:6]  # the inside pose of each crossing
            at = xy[np.where(inside[cross], cross, cross + 1), :2]
            ax.plot(at[:, 0], at[:, 1], ls="none", marker="X", ms=9, color=color(m), mec="white", zorder=5)
    return out


def _leaves_label(m: str, far: dict[str, float]) -> str:
    return f"{label(m)} (leaves the frame at ✕, goes up to {far[m]:.1f} m beyond)" if m in far else label(m)


def _ate_rmse(ev: Evaluation) -> dict[str, float]:
    return {m: float(np.sqrt(np.mean(err**2))) for m, (_, _, err) in ev.aligned.items()}


def trajectories_over_walls(ev: Evaluation):
    """All SE(2)-aligned trajectories and the ground truth, over the world's walls, framed on the
    walls, the ground truth and the best trajectories (:func:`framing_methods`); a trajectory that
    leaves the frame is marked where it does and said to in the legend, not followed."""
    plt = _pyplot()
    assert ev.gt is not None
    fig, ax = plt.subplots(figsize=(7.5, 7.5), layout="constrained")
    _walls(ax, ev.walls)
    best = framing_methods(_ate_rmse(ev))
    box = frame([_walls_box(ev.walls), bounds(ev.gt[:, :2]), *(bounds(ev.aligned[m][1][:, :2]) for m in best)])
    assert box is not None
    far = _frame_axes(ax, box, {m: est for m, (_, est, _) in ev.aligned.items()})
    ax.plot(ev.gt[:, 0], ev.gt[:, 1], color=COLORS["truth"], lw=1.2, ls="--", label="ground truth")
    for m, (_, est, _) in ev.aligned.items():
        ax.plot(est[:, 0], est[:, 1], color=color(m), ls=line(m), lw=1.2, label=_leaves_label(m, far))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Trajectories (SE(2)-aligned to ground truth) over the world's walls")
    _legend_below(fig, ax, 2 if far else len(ev.aligned) + 1)
    return fig


def _unwrapped_near(yaw: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``yaw`` (rad) unwrapped and shifted by whole turns to lie nearest ``ref`` (rad, same stamps) on average."""
    u = np.unwrap(yaw)
    return u - 2 * np.pi * np.round(np.mean(u - ref) / (2 * np.pi))


def xy_yaw_over_time(ev: Evaluation):
    """x, y (m) and yaw (deg) of every SE(2)-aligned trajectory and of the ground truth against time
    (s), as evo_traj's first plot; each axis framed on the ground truth and the best trajectories
    (:func:`framing_methods`), a trajectory that leaves it said to in the legend."""
    plt = _pyplot()
    assert ev.gt is not None and ev.gt_t is not None
    t0 = _t0(ev)
    gt_yaw = np.unwrap(ev.gt[:, 2])
    fig, axes = plt.subplots(3, 1, figsize=(10, 7.2), sharex=True, layout="constrained")
    best = framing_methods(_ate_rmse(ev))
    series: dict[str, list[np.ndarray]] = {}
    for m, (t, est, _) in ev.aligned.items():
        ref_yaw = np.interp(t, ev.gt_t, gt_yaw)
        series[m] = [est[:, 0], est[:, 1], np.degrees(_unwrapped_near(est[:, 2], ref_yaw))]
    leaves: set[str] = set()
    for i, (ax, name) in enumerate(zip(axes, ("x (m)", "y (m)", "yaw (deg, unwrapped)"))):
        gt_i = ev.gt[:, i] if i < 2 else np.degrees(gt_yaw)
        ax.plot(ev.gt_t - t0, gt_i, color=COLORS["truth"], lw=1.2, ls="--", label="ground truth")
        for m, (t, _, _) in ev.aligned.items():
            ax.plot(t - t0, series[m][i], color=color(m), ls=line(m), lw=1)
        framed = np.concatenate([gt_i, *(series[m][i] for m in best)])
        lo, hi = float(np.min(framed)), float(np.max(framed))
        pad = 0.05 * (hi - lo) + (0.5 if i < 2 else 5.0)
        ax.set_ylim(lo - pad, hi + pad)
        leaves |= {m for m in series if np.any(series[m][i] < lo - pad) or np.any(series[m][i] > hi + pad)}
        ax.set_ylabel(name)
        ax.grid(True, alpha=0.3)
    for m in ev.aligned:  # the legend's entries, once
        axes[0].plot([], [], color=color(m), ls=line(m), lw=1,
                     label=f"{label(m)} (leaves the frame)" if m in leaves else label(m))
    axes[-1].set_xlabel("time since the first sweep (s)")
    axes[0].set_title("x, y and yaw over time (SE(2)-aligned to ground truth, as evo_traj --plot)")
    _legend_below(fig, axes[0], len(ev.aligned) + 1)
    return fig


def error_histograms(ev: Evaluation):
    """Each trajectory's position errors (cm, SE(2)-aligned) as a histogram of its own, with its
    RMSE, mean and median marked (evo_ape's statistics)."""
    plt = _pyplot()
    items = list(ev.aligned.items())
    cols = min(3, len(items))
    rows = -(-len(items) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols + 0.4, 2.7 * rows + 0.5), squeeze=False,
                             layout="constrained")
    for ax, (m, (_, _, err)) in zip(axes.ravel(), items):
        cm = 100.0 * err
        ax.hist(cm, bins=30, color=color(m), alpha=0.75)
        for value, style, name in ((np.sqrt(np.mean(cm**2)), "-", "RMSE"), (np.mean(cm), "--", "mean"),
                                   (np.median(cm), ":", "median")):
            ax.axvline(value, color="#222222", ls=style, lw=1.2, label=f"{name} {value:.1f}")
        ax.set_title(label(m), fontsize=10)
        ax.set_xlabel("position error (cm)")
        ax.set_ylabel("poses")
        ax.legend(fontsize=7, frameon=False)
    for ax in axes.ravel()[len(items):]:
        ax.set_visible(False)
    fig.suptitle("Distribution of the position error (SE(2)-aligned, as evo_ape -a --plot)")
    return fig


def error_colored(ev: Evaluation, method: str):
    """One method's aligned trajectory coloured by its position error (cm), with a colorbar."""
    plt = _pyplot()
    from matplotlib.collections import LineCollection

    assert ev.gt is not None
    _, est, err = ev.aligned[method]
    fig, ax = plt.subplots(figsize=(5.6, 5.2))
    _walls(ax, ev.walls)
    ax.plot(ev.gt[:, 0], ev.gt[:, 1], color="#000000", lw=0.6, ls=":", zorder=2)
    seg = np.stack([est[:-1, :2], est[1:, :2]], axis=1)
    cm = 100.0 * 0.5 * (err[:-1] + err[1:])  # a segment takes its ends' mean error
    lc = LineCollection(list(seg), cmap=ERROR_CMAP, linewidths=2.6, capstyle="round", zorder=3)  # round: no gaps
    lc.set_array(cm)
    lc.set_clim(0.0, max(100.0 * float(err.max()), 1e-6))  # the bar's top is the stated max
    ax.add_collection(lc)
    fig.colorbar(lc, ax=ax, fraction=0.046, pad=0.03, label="position error (cm)")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"{label(method)}: position error along the path\n"
                 f"(RMSE {100 * np.sqrt(np.mean(err**2)):.1f} cm, max {100 * err.max():.1f} cm; "
                 "dotted: ground truth)", fontsize=10)
    return fig


def ate_over_time(ev: Evaluation):
    """Each method's absolute position error (cm, log scale) against time (s) after SE(2) alignment."""
    plt = _pyplot()
    t0 = _t0(ev)
    fig, ax = plt.subplots(figsize=(10, 3.4), layout="constrained")
    for m, (t, _, err) in ev.aligned.items():
        ax.plot(t - t0, np.maximum(err * 100, 1e-3), color=color(m), ls=line(m), lw=1,
                label=f"{label(m)} (RMSE {100 * np.sqrt(np.mean(err**2)):.1f} cm)")
    ax.set_xlabel("time since the first sweep (s)")
    ax.set_ylabel("position error (cm, log)")
    _log_y(ax)
    ax.set_title("Absolute position error along the path (SE(2)-aligned, as evo_ape -a)")
    ax.grid(True, which="major", alpha=0.3)
    _legend_below(fig, ax, len(ev.aligned))
    return fig


def rpe_over_distance(ev: Evaluation):
    """Per-pair RPE (translation % of delta, yaw deg/m) against the distance where each pair starts."""
    plt = _pyplot()
    deltas = sorted({s.delta for series in ev.rpe.values() for s in series})
    fig, axes = plt.subplots(len(deltas), 2, figsize=(11, 2.9 * len(deltas) + 0.6), squeeze=False,
                             layout="constrained")
    for row, delta in enumerate(deltas):
        for m, series in ev.rpe.items():
            for s in series:
                if s.delta != delta:
                    continue
                marker = "." if len(s.start_m) <= 60 else None  # dots only where they can be told apart
                for col, y in enumerate((s.trans_pct, s.rot_deg_per_m)):
                    axes[row, col].plot(s.start_m, np.maximum(y, 1e-4), color=color(m), ls=line(m), lw=1, marker=marker, ms=4,
                                        label=label(m))
        axes[row, 0].set_ylabel(f"over {delta:g} m:\ntranslation (% of {delta:g} m)")
        axes[row, 1].set_ylabel(f"over {delta:g} m:\nyaw (deg/m)")
    for ax in axes.ravel():
        _log_y(ax)
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("distance travelled where the pair starts (m)")
    fig.suptitle("Relative pose error of each pair (as evo_rpe --delta_unit m, pairs on ground truth; log scale)")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=max(1, len(labels)), frameon=False)
    return fig


def heading_over_time(ev: Evaluation):
    """Each method's heading error (deg, estimate − ground truth after SE(2) alignment) against time (s)."""
    plt = _pyplot()
    t0 = _t0(ev)
    fig, ax = plt.subplots(figsize=(10, 3.4), layout="constrained")
    for m, h in ev.heading.items():
        ax.plot(ev.aligned[m][0] - t0, h, color=color(m), ls=line(m), lw=1,
                label=f"{label(m)} (RMSE {np.sqrt(np.mean(h**2)):.2f}°, largest {np.max(np.abs(h)):.2f}°)")
    ax.axhline(0.0, color="#444444", lw=0.6)
    _log_y(ax, "symlog", linthresh=0.1)  # tenths of a degree and tens of degrees on one axis
    ax.set_xlabel("time since the first sweep (s)")
    ax.set_ylabel("heading error (deg)\nlinear within ±0.1, log beyond")
    ax.set_title("Heading error (estimate − ground truth, after SE(2) alignment)")
    ax.grid(True, which="major", alpha=0.3)
    _legend_below(fig, ax, len(ev.heading))
    return fig


def sweep_times(ev: Evaluation):
    """Time per sweep per method: box (quartiles), whisker (min to p95), dots beyond p95, ▲ max."""
    plt = _pyplot()
    items = [(m, ms) for m, ms in ev.sweep_ms.items() if len(ms)]
    fig, ax = plt.subplots(figsize=(10, 0.9 * len(items) + 1.3))
    data = [ms for _, ms in items]
    # matplotlib >= 3.10 says `orientation`, older ones only `vert` (deprecated from 3.11)
    flat = {"orientation": "horizontal"} if "orientation" in inspect.signature(ax.boxplot).parameters else {"vert": False}
    ax.boxplot(data, **flat, whis=(0, 95), widths=0.5, medianprops={"color": "#000000", "lw": 2},
               flierprops={"marker": ".", "markersize": 3, "markerfacecolor": "#666666", "markeredgecolor": "none"})
    ax.set_yticks(range(1, len(items) + 1), [label(m) for m, _ in items])
    hi = max(float(ms.max()) for ms in data)
    for i, (m, ms) in enumerate(items, start=1):
        med, p95, mx = np.median(ms), np.percentile(ms, 95), ms.max()
        ax.plot([p95], [i], marker="|", ms=16, mew=2, color="#d62728")
        ax.plot([mx], [i], marker="^", ms=7, color=color(m))
        ax.annotate(f"median {med:.1f} · p95 {p95:.1f} · max {mx:.1f} ms", (1.0, i), xycoords=("axes fraction", "data"),
                    xytext=(8, 0), textcoords="offset points", va="center", fontsize=9)
    if hi > 20 * min(float(np.median(ms)) for ms in data):  # a long tail: log, with plain-number ticks
        from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

        ax.set_xscale("log")
        lo = min(float(ms.min()) for ms in data)
        ticks = [v for e in range(-2, 6) for v in (10.0**e, 2 * 10.0**e, 5 * 10.0**e) if lo / 2 <= v <= hi * 2]
        ax.xaxis.set_major_locator(FixedLocator(ticks))
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
    ax.invert_yaxis()
    ax.set_xlabel("time per sweep (ms)")
    ax.grid(True, axis="x", which="major", alpha=0.3)
    ax.set_title("Time per sweep: box = quartiles, whisker to p95 (red |), dots = slower sweeps, ▲ = max")
    return fig


def feature_errors(result: dict):
    """The baseline's and the improved method's relative feature-length errors (%; ``result``: the
    report's numbers), one bar per feature; None when neither has feature rows."""
    plt = _pyplot()
    feats = {m: result["methods"][m]["features"] for m in ("baseline", "improved")
             if (result["methods"].get(m) or {}).get("features")}
    if not feats:
        return None
    fig, ax = plt.subplots(figsize=(10, 3.4), layout="constrained")
    first = next(iter(feats.values()))
    x = np.arange(len(first))
    width = 0.8 / len(feats)
    for i, (m, fs) in enumerate(feats.items()):
        vals = [f["rel_error_pct"] if f.get("rel_error_pct") is not None else np.nan for f in fs]
        ax.bar(x + (i - (len(feats) - 1) / 2) * width, vals, width, color=color(m), label=label(m))
    ax.set_xticks(x, [str(f["id"]) for f in first])
    ax.set_xlabel("feature (id; a missing bar: not measured)", labelpad=2)
    ax.set_ylabel("relative error (%)")
    ax.set_title("Relative error of the feature lengths (as the paper's Figure 4)")
    _legend_below(fig, ax, len(feats))
    return fig


def _map_image(out_dir: Path, method: str) -> tuple[np.ndarray, tuple[float, float, float, float]] | None:
    import yaml

    pgm, meta = out_dir / f"{method}_map.pgm", out_dir / f"{method}_map.yaml"
    if not (pgm.is_file() and meta.is_file()):
        return None
    info = yaml.safe_load(meta.read_text())
    img = pgm_pixels(pgm.read_bytes())
    res, (ox, oy) = float(info["resolution"]), info["origin"][:2]
    h, w = img.shape
    return img, (ox, ox + w * res, oy, oy + h * res)


def trajectory_over_own_map(out_dir: Path, method: str):
    """The occupancy map a method built, with its own trajectory on it (its own frame; no ground truth needed)."""
    plt = _pyplot()
    image, tum = _map_image(out_dir, method), out_dir / f"{method}.tum"
    if image is None or not tum.is_file():
        return None
    _, poses = read_tum(tum)
    fig, ax = plt.subplots(figsize=(5.6, 5.6))
    ax.imshow(image[0], cmap="gray", vmin=0, vmax=255, extent=image[1], interpolation="nearest")
    ax.plot(poses[:, 0], poses[:, 1], color=color(method), lw=1.2)
    ax.set_xlabel(f"x in {method}/odom (m)")
    ax.set_ylabel(f"y in {method}/odom (m)")
    ax.set_title(f"Map built by the {label(method)} method,\nwith its trajectory (coloured line)", fontsize=10)
    return fig


def loop_closures_over_map(out_dir: Path, method: str):
    """The back end's loop closures (``<method>_backend.json``) drawn on the method's map: each a
    segment between its two nodes at their optimised poses, blue where the Cauchy kernel kept it,
    red where it did not; the front end's own trajectory dashed. None without a back end."""
    graph = out_dir / f"{method}_backend.json"
    fig = trajectory_over_own_map(out_dir, method) if graph.is_file() else None
    if fig is None:
        return None
    ax = fig.axes[0]
    data = json.loads(graph.read_text())
    xy = np.column_stack([data["nodes"]["x"], data["nodes"]["y"]])
    at = {int(s): i for i, s in enumerate(data["nodes"]["stamp_ns"])}
    for kept, colour in ((True, "#1565c0"), (False, "#d32f2f")):
        segs = [(xy[at[c["candidate_stamp_ns"]]], xy[at[c["query_stamp_ns"]]]) for c in data["closures"]
                if c["accepted"] is kept]
        for a, b in segs:
            ax.plot([a[0], b[0]], [a[1], b[1]], color=colour, lw=0.8, alpha=0.8)
        ax.plot([], [], color=colour, lw=0.8, label=f"loop closures {'kept' if kept else 'down-weighted'} ({len(segs)})")
    front = out_dir / f"{method}_frontend.tum"
    if front.is_file():
        _, fposes = read_tum(front)
        ax.plot(fposes[:, 0], fposes[:, 1], color="#777777", lw=0.7, ls="--", label="front end alone")
    ax.set_title(f"Loop closures of the {label(method)} method's back end, on its map", fontsize=10)
    ax.legend(loc="upper right", fontsize=7)
    return fig


def _occupied_box(image: tuple[np.ndarray, Box] | None) -> Box | None:
    """The extent (m) of a map's occupied (dark) cells; None without a map or an occupied cell."""
    if image is None:
        return None
    pixels, (x0, x1, y0, y1) = image
    rows, cols = np.nonzero(pixels < 100)
    if not len(rows):
        return None
    h, w = pixels.shape
    res = (x1 - x0) / w
    return x0 + cols.min() * res, x0 + (cols.max() + 1) * res, y1 - (rows.max() + 1) * res, y1 - rows.min() * res


def aligned_over_reference_map(ev: Evaluation):
    """Every trajectory SE(2)-aligned onto the reference one, over the reference's map (no ground
    truth), framed on the map's walls and the reference trajectory: one that leaves the frame is
    marked where it does and said to in the legend, not followed."""
    plt = _pyplot()
    ref = ev.disagreement_reference
    if ref is None or not ev.disagreements:
        return None
    image = _map_image(ev.out_dir, ref)
    _, ref_poses = read_tum(ev.out_dir / f"{ref}.tum")
    fig, ax = plt.subplots(figsize=(7.5, 7.5), layout="constrained")
    if image is not None:
        ax.imshow(image[0], cmap="gray", vmin=0, vmax=255, extent=image[1], interpolation="nearest", alpha=0.6)
    box = frame([_occupied_box(image), bounds(ref_poses[:, :2])])
    far = _frame_axes(ax, box, {m: d.aligned for m, d in ev.disagreements.items()}) if box is not None else {}
    ax.plot(ref_poses[:, 0], ref_poses[:, 1], color=color(ref), lw=1.4, label=f"{label(ref)} (reference)",
            zorder=3)
    for m, d in ev.disagreements.items():
        ax.plot(d.aligned[:, 0], d.aligned[:, 1], color=color(m), ls=line(m), lw=1.1, label=f"{_leaves_label(m, far)}, aligned")
    ax.set_xlabel(f"x in {ref}/odom (m)")
    ax.set_ylabel(f"y in {ref}/odom (m)")
    ax.set_title(f"Trajectories SE(2)-aligned onto the {label(ref)} one, over its map")
    _legend_below(fig, ax, 2 if far else len(ev.disagreements) + 1)
    return fig


def disagreement_along(ev: Evaluation):
    """The distance (m) of each trajectory to the reference one after SE(2) alignment, against time
    (s); None without a reference (needs no ground truth)."""
    plt = _pyplot()
    ref = ev.disagreement_reference
    if ref is None or not ev.disagreements:
        return None
    fig, ax = plt.subplots(figsize=(10, 3.4), layout="constrained")
    for m, d in ev.disagreements.items():
        ax.plot(d.along_m, d.gap_m, color=color(m), ls=line(m), lw=1, label=f"{label(m)} (RMSE {d.stats.rmse:.2f} m)")
    ax.set_xlabel(f"distance travelled along the {label(ref)} trajectory (m)")
    ax.set_ylabel(f"distance to {label(ref)} (m)")
    ax.set_title(f"Disagreement with the {label(ref)} trajectory after SE(2) alignment (not an error: "
                 "no ground truth)", fontsize=10)
    ax.set_ylim(bottom=0)
    ax.grid(True, alpha=0.3)
    _legend_below(fig, ax, len(ev.disagreements))
    return fig


def all_plots(ev: Evaluation) -> dict[str, str]:
    """Every figure that can be drawn for ``ev``, keyed by name, as data URIs."""
    makers: list[tuple[str, Callable[[], Any]]] = []
    if ev.gt is not None and ev.aligned:
        makers += [("trajectories", partial(trajectories_over_walls, ev))]
        makers += [(f"error_{m}", partial(error_colored, ev, m)) for m in ev.aligned]
        makers += [("xy_yaw", partial(xy_yaw_over_time, ev))]
        makers += [("errors", partial(ate_over_time, ev))]
        makers += [("histograms", partial(error_histograms, ev))]
        if any(ev.rpe.values()):
            makers += [("rpe", partial(rpe_over_distance, ev))]
        makers += [("heading", partial(heading_over_time, ev))]
    else:
        makers += [("aligned_on_map", partial(aligned_over_reference_map, ev)),
                   ("disagreement", partial(disagreement_along, ev))]
    if any(len(ms) for ms in ev.sweep_ms.values()):
        makers += [("sweep_times", partial(sweep_times, ev))]
    makers += [("features", partial(feature_errors, ev.result))]
    makers += [(f"map_{m}", partial(trajectory_over_own_map, ev.out_dir, m)) for m in ("improved", "baseline")]
    makers += [(f"closures_{m}", partial(loop_closures_over_map, ev.out_dir, m)) for m in ("improved", "baseline")]
    out = {}
    for key, make in makers:
        fig = make()
        if fig is not None:
            out[key] = png(fig)
    return out
