"""The feature-length measurement's own floor: a map built from perfect poses, measured like a method's.

Run: ``PYTHONPATH=. python bench/feature_floor.py LOG [OUT_DIR]``. Every sweep's static points
(``/ground_truth/point_labels`` = 0) are placed with the ground-truth pose of each beam's own
time and ray-cast into fmcwlog's occupancy grid (default parameters, a scan every 0.5 m or
10 deg, as the front ends do); the map is written as ``truth_map.pgm/.yaml`` with
``truth.tum`` into OUT_DIR (default: a temporary folder) and its features are measured by
:func:`fmcwlog.evaluation.features.feature_lengths`. What remains is the error of the map
itself (cells, grazing beams, ray-cast clearing) and of the measurement, not of any pose.
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's fmcwlog, not an installed one

from fmcwlog.evaluation.features import feature_lengths
from fmcwlog.evaluation.ground_truth import read_ground_truth, read_point_labels, read_world
from fmcwlog.geometry import compose, interpolate_poses, wrap_angle
from fmcwlog.io.calibration import MOUNT_KEYS
from fmcwlog.io.mcap_log import LogReader
from fmcwlog.io.messages import pointcloud_columns
from fmcwlog.io.outputs import write_grid, write_tum
from fmcwlog.kernels.occupancy import OccupancyGrid


def truth_map(log: Path, out: Path) -> None:
    reader = LogReader(log)
    cal = reader.metadata["fmcwlog.calibration"]
    mount = np.array([float(cal[k]) for k in MOUNT_KEYS])
    gt_ns, gt = read_ground_truth(reader)
    labels = read_point_labels(reader)
    grid, last = OccupancyGrid(), None
    stamps, poses = [], []
    for m in reader.messages(["/fmcw/points"]):
        ns = m.log_time_ns
        cols = pointcloud_columns(m.msg, ("x", "y", "t"))
        static = labels[ns] == 0
        pose = interpolate_poses(np.array(ns * 1e-9), gt_ns * 1e-9, gt)
        sensor = compose(interpolate_poses(ns * 1e-9 + cols["t"][static], gt_ns * 1e-9, gt), mount)
        c, s = np.cos(sensor[:, 2]), np.sin(sensor[:, 2])
        x, y = cols["x"][static], cols["y"][static]
        world = sensor[:, :2] + np.column_stack([c * x - s * y, s * x + c * y])
        stamps.append(ns)
        poses.append(pose)
        if last is None or np.hypot(*(pose[:2] - last[:2])) >= 0.5 or abs(wrap_angle(pose[2] - last[2])) >= np.radians(10):
            grid.integrate(compose(pose, mount)[:2], world)
            last = pose
    out.mkdir(parents=True, exist_ok=True)
    write_grid(out, "truth_map", grid)
    write_tum(out / "truth.tum", np.array(stamps), np.array(poses))


def main(log: Path, out: Path) -> None:
    truth_map(log, out)
    reader = LogReader(log)
    world = read_world(reader)
    rows = feature_lengths(out, ["truth"], world.features, world.walls, *read_ground_truth(reader))["truth"]
    print("| feature | true m | measured m | rel. error % | not measurable because |\n|---|---|---|---|---|")
    rel = []
    for r in rows:
        m = r["measured_m"]
        if m is not None:
            rel.append(100 * abs(m - r["true_m"]) / r["true_m"])
        print(f"| {r['id']} | {r['true_m']:.3f} | {'—' if m is None else f'{m:.3f}'} | "
              f"{'—' if m is None else f'{rel[-1]:.2f}'} | {r['reason'] or ''} |")
    if rel:
        print(f"average relative error over {len(rel)} measured: {np.mean(rel):.2f} %  (map: {out})")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(Path(sys.argv[1]), Path(sys.argv[2]) if len(sys.argv) > 2 else Path(tempfile.mkdtemp(prefix="feature-floor-")))
