"""The report page's figures and words on constructed trajectories: framing a map on the walls and
the best trajectories (an outlier said to leave, not followed), lists of names that hold commas,
notes that do not repeat their subject, and the run's wall-clock rate labelled as such."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fmcwlog.evaluation import plots
from fmcwlog.evaluation.evaluate import Evaluation
from fmcwlog.evaluation.pages import ATE_HEADER, TRAJECTORY_HEADER, ate_rows, header_rows, run_rate_line


def _square_world() -> np.ndarray:
    """A 20 m x 10 m room's four walls (x0, y0, x1, y1), m."""
    return np.array([[0, 0, 20, 0], [20, 0, 20, 10], [20, 10, 0, 10], [0, 10, 0, 0]], dtype=float)


def _evaluation() -> Evaluation:
    """Ground truth along the room; improved 2 cm off it, baseline 10 cm off, wheel odometry wandering 60 m away."""
    t = np.linspace(0.0, 30.0, 301)
    gt = np.column_stack([1.0 + 18.0 * t / 30.0, np.full_like(t, 5.0), np.zeros_like(t)])
    ev = Evaluation(Path("."), Path("log.mcap"), {})
    ev.gt_t, ev.gt, ev.walls = t, gt, _square_world()
    wander = gt + np.column_stack([60.0 * (t / 30.0) ** 2, -40.0 * (t / 30.0) ** 2, np.zeros_like(t)])
    for m, est in (("improved", gt + [0.02, 0.0, 0.0]), ("baseline", gt + [0.0, 0.1, 0.0]), ("wheel_odometry", wander)):
        ev.aligned[m] = (t, est, np.hypot(*(est[:, :2] - gt[:, :2]).T))
    return ev


def test_the_best_trajectories_frame_the_plots_and_an_outlier_does_not():
    rmse = {"improved": 0.02, "baseline": 0.05, "wheel_odometry": 30.0}
    assert plots.framing_methods(rmse) == ["improved", "baseline"]  # within 3x the best; 30 m is not
    assert plots.framing_methods({"a": 1.0}) == ["a"] and plots.framing_methods({}) == []
    box = plots.frame([(0.0, 20.0, 0.0, 10.0), (1.0, 19.0, 5.0, 5.0)], pad_share=0.05, pad_m=0.5)
    assert box == pytest.approx((-1.5, 21.5, -1.5, 11.5))  # 5 % of the 20 m side + 0.5 m each way
    assert plots.beyond(box, np.array([[0.0, 0.0], [31.5, 11.5]])) == pytest.approx(10.0)
    assert plots.beyond(box, np.array([[0.0, 0.0]])) == 0.0


def test_a_wandering_odometry_leaves_the_map_framed_on_the_walls():
    ev = _evaluation()
    fig = plots.trajectories_over_walls(ev)
    ax = fig.axes[0]
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    # the frame holds the room and no more than its margin (not the 60 m the odometry wandered)
    assert x0 <= 0.0 and x1 >= 20.0 and y0 <= 0.0 and y1 >= 10.0
    assert x1 - x0 < 25.0 and y1 - y0 < 25.0
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any(t.startswith("wheel odometry (leaves the frame") for t in legend), legend
    assert "improved" in legend and "baseline" in legend  # inside: no remark
    plots._pyplot().close(fig)
    fig = plots.xy_yaw_over_time(ev)
    top, lo_hi = fig.axes[0], fig.axes[0].get_ylim()
    assert lo_hi[1] < 25.0  # x framed on the truth (1 to 19 m), not on the odometry's 79 m
    assert any("wheel odometry (leaves the frame)" == t.get_text() for t in fig.legends[0].get_texts())
    assert top.get_title().startswith("x, y and yaw over time")
    plots._pyplot().close(fig)


def test_ablation_without_framing_the_odometry_would_set_the_scale(monkeypatch):
    """Framing every trajectory (as if all were the best) brings the 60 m back into the frame."""
    monkeypatch.setattr(plots, "FRAMED_WITHIN", 1e9)
    fig = plots.trajectories_over_walls(_evaluation())
    x0, x1 = fig.axes[0].get_xlim()
    assert x1 - x0 > 60.0
    plots._pyplot().close(fig)


def test_error_histograms_one_per_trajectory():
    fig = plots.error_histograms(_evaluation())
    shown = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title() for ax in shown] == ["improved", "baseline", "wheel odometry"]
    plots._pyplot().close(fig)


def test_names_holding_commas_are_listed_apart():
    result = {"header": {"methods": ["improved", "baseline"], "trajectories": ["improved", "peer, tuned", "kiss"]},
              "log": "x.mcap"}
    rows = dict(header_rows(result))
    assert rows["trajectories compared"] == "improved; peer, tuned; kiss"
    assert rows["methods"] == "improved; baseline"


def test_labels_say_what_the_numbers_are():
    assert "RPE 1 m % (mean)" in TRAJECTORY_HEADER and "median ms per sweep" in TRAJECTORY_HEADER
    assert "sweeps/s" not in TRAJECTORY_HEADER  # 1000 / ms of one method's step is not the run's rate
    line = run_rate_line({"sweeps": 300, "wall_seconds": 0.75, "wall_sweeps_per_second": 400.0})
    assert "300 sweeps in 0.8 s of wall clock, 400 sweeps/s" in line
    assert "not in run.json" in run_rate_line({"sweeps": 300, "wall_seconds": None, "wall_sweeps_per_second": None})
    result = {"methods": {"improved": {"ate_rmse_m": 0.01, "ate_mean_m": 0.008, "ate_median_m": 0.007,
                                       "ate_std_m": 0.002, "ate_min_m": 0.001, "ate_max_m": 0.03,
                                       "ate_first_aligned_rmse_m": 0.02},
                          "wheel_odometry": {"ate_rmse_m": None}}}
    assert ATE_HEADER[1:7] == ["rmse cm", "mean cm", "median cm", "std cm", "min cm", "max cm"]
    assert ate_rows(result) == [["improved", "1.00", "0.80", "0.70", "0.20", "0.10", "3.00", "2.00"]]
