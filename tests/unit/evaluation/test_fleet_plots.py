"""The fleet page's figures: bars on the scale their values need, flagged logs marked, thumbnails that
keep one-cell walls."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fmcwlog.evaluation.fleet import FleetRow, fleet_result, render_fleet_html
from fmcwlog.evaluation.fleet_plots import errors_per_log, shrunk_map, time_per_log


def _result(ates: list[float], disagree: list[float] = ()) -> dict:
    rows = [FleetRow(f"gt{i}", None, "done", ground_truth=True, sweeps=100, wall_s=1.0 + i,
                     ate_rmse_m={"improved": a, "baseline": 40 * a}, ms_per_sweep={"improved": 0.5, "baseline": 0.2})
            for i, a in enumerate(ates)]
    rows += [FleetRow(f"free{i}", None, "done", sweeps=100, wall_s=1.0, methods_disagreement_m=d)
             for i, d in enumerate(disagree)]
    return fleet_result(Path("/x"), rows, {})


def test_bars_go_logarithmic_where_values_span_over_thirty_times_and_flagged_names_turn_red():
    wide = _result([0.01] * 9 + [0.3], disagree=[0.02, 0.03])  # improved 1 cm beside baseline 12 m
    fig = errors_per_log(wide)
    gt_ax, free_ax = fig.axes
    assert gt_ax.get_xscale() == "log" and free_ax.get_xscale() == "linear"  # 2-3 cm: linear
    red = [t.get_text() for t in gt_ax.get_yticklabels() if t.get_color() != "black"]
    assert red == ["gt9"] and [f["name"] for f in wide["flagged"]] == ["gt9"]
    assert any(ln.get_linestyle() == "--" for ln in gt_ax.get_lines())  # the threshold: 10 logs rank
    few = errors_per_log(_result([0.01, 0.012, 0.011]))
    assert not few.axes[0].get_lines()  # three logs: no threshold drawn
    assert time_per_log(wide) is not None


def test_a_one_cell_wall_survives_the_shrinking():
    pixels = np.full((1000, 1000), 255, dtype=np.uint8)
    pixels[500, :] = 0  # a wall one cell thick across a 50 m map at 5 cm
    small, extent = shrunk_map(pixels, (0.0, 50.0, 0.0, 50.0), (0.0, 50.0, 0.0, 50.0), px=250)
    assert small.shape == (250, 250) and extent == (0.0, 50.0, 0.0, 50.0)
    assert small.min(axis=1).tolist().count(0) == 1  # still a black line
    mean = pixels.reshape(250, 4, 250, 4).mean(axis=(1, 3))
    assert mean.min() > 180  # ablation: averaged, the wall fades to a pale grey


def test_the_page_embeds_its_figures_as_data_uris():
    result = _result([0.01] * 9 + [0.3])
    page = render_fleet_html(result, {"errors": "data:image/png;base64,AAAA", "times": "data:image/png;base64,BBBB"})
    assert page.count('src="data:image/png;base64,') == 2 and "http" not in page
