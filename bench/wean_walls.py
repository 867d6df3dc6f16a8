"""CMU Wean Hall: are the walls drawn once? A measure of doubled walls that needs no ground truth.

The five Wean Hall logs (``../shared/datasets/cmu_wean_hall``) have no ground truth and no
relations, so the measure asked of them is "maps with single walls". A wall drawn twice is a wall seen again
from a pose that has drifted: its new points lie beside the old ones, parallel, some centimetres to
a metre away. So for every scan, each of its points (the raw CMU ranges, placed with the
trajectory's pose at the scan and the laser's own offset, not with anything fmcwlog computed from
them) is compared with the wall drawn by every scan taken at least ``--gap`` seconds earlier: the
line through its 5 nearest earlier points (thinned to one per 5 cm cell), where those lie on a line
(within 2 cm across, spread along) and within 0.5 m; a point-to-line distance, so that the spacing
of earlier beams along the wall does not count. Per trajectory:

- ``median`` of that distance, and
- ``doubled``: the fraction of points 10 cm to 0.5 m off the earlier wall — a second wall beside
  the first. People walking by and door jambs (where the earlier line is another wall's) count
  too: plotted on robotdata1, they are what the improved method's fraction holds.

Each log is imported, processed with the defaults (both methods with their back ends) and
measured for the optimised trajectories, the front ends' own and the raw odometry (the contrast).

    python bench/wean_walls.py                 # all five logs, a few minutes
    python bench/wean_walls.py --logs 1 4      # some of them
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's fmcwlog, not an installed one

from fmcwlog.api import ProcessOptions, import_carmen, process  # noqa: E402
from fmcwlog.io.carmen import parse_log  # noqa: E402

WEAN = ROOT.parent / "shared" / "datasets" / "cmu_wean_hall"
TRAJECTORIES = ("improved", "improved_frontend", "baseline", "baseline_frontend", "wheel_odometry")
MAX_RANGE_M = 15.0  # beyond it the beams are too sparse and too grazing to say where a wall is
NEAR_M = 0.5  # a point with fewer than K earlier points this near sees something new
K = 5
WALL_THICKNESS_M = 0.02  # earlier points this close to their line draw one wall
DOUBLED_M = 0.10


def _tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    rows = np.loadtxt(path, ndmin=2)
    yaw = 2.0 * np.arctan2(rows[:, 6], rows[:, 7])
    return rows[:, 0], np.column_stack([rows[:, 1], rows[:, 2], yaw])


def scan_points(log: Path, stamps: np.ndarray, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points (n, 2) m and their scan's time (n,) s: each scan at the pose of its stamp."""
    pts, times = [], []
    for scan in parse_log(log).scans:
        i = int(np.argmin(np.abs(stamps - scan.stamp)))
        if abs(stamps[i] - scan.stamp) > 1e-3:
            continue  # a scan the trajectory has no pose for (skipped by the front end)
        r = scan.ranges
        a = scan.angle_min + scan.angle_increment * np.arange(r.size)
        ok = np.isfinite(r) & (r < min(MAX_RANGE_M, 0.99 * scan.range_max))
        lx, ly, lyaw = scan.laser_pose
        x, y, yaw = poses[i]
        # laser frame -> robot frame -> world
        px = lx + r[ok] * np.cos(lyaw + a[ok])
        py = ly + r[ok] * np.sin(lyaw + a[ok])
        c, s = np.cos(yaw), np.sin(yaw)
        pts.append(np.column_stack([x + c * px - s * py, y + s * px + c * py]))
        times.append(np.full(ok.sum(), scan.stamp))
    return np.concatenate(pts), np.concatenate(times)


def _to_line(p: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """Distance (m) of each point p (m, 2) to the line through its neighbours nbrs (m, k, 2); NaN
    where those neighbours do not lie on one line."""
    centred = nbrs - nbrs.mean(axis=1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", centred, centred) / nbrs.shape[1]
    vals, vecs = np.linalg.eigh(cov)
    normal = vecs[:, :, 0]  # smallest eigenvalue: across the wall
    dist = np.abs(np.einsum("mi,mi->m", p - nbrs.mean(axis=1), normal))
    # only where the earlier points draw a wall: thin across (a person, a corner or a wall already
    # drawn twice is not a line to measure against) and spread along
    wall = (np.sqrt(np.maximum(vals[:, 0], 0.0)) < WALL_THICKNESS_M) & (np.sqrt(vals[:, 1]) > 2 * WALL_THICKNESS_M)
    return np.where(wall, dist, np.nan)


def _thin(points: np.ndarray, cell_m: float = 0.05) -> np.ndarray:
    """One point per ``cell_m`` cell (the mean of those in it), so that K neighbours span a wall."""
    keys = np.floor(points / cell_m).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    sums = np.zeros((counts.size, 2))
    np.add.at(sums, inverse, points)
    return sums / counts[:, None]


def doubled_walls(points: np.ndarray, times: np.ndarray, gap_s: float, step_s: float = 5.0) -> dict:
    """Distance of each point to the wall drawn by the points seen at least ``gap_s`` earlier.

    The wall near a point is the line through its ``K`` nearest earlier points (within ``NEAR_M``):
    a point-to-line distance, so that the spacing of earlier beams along the wall does not count.
    """
    d_all = []
    for t0 in np.arange(times.min() + gap_s, times.max() + step_s, step_s):
        now = (times >= t0) & (times < t0 + step_s)
        before = times < t0 - gap_s  # every point at least gap_s older than any of the block's
        if not now.any() or before.sum() < K:
            continue
        old = _thin(points[before])
        d, idx = cKDTree(old).query(points[now], k=K, distance_upper_bound=NEAR_M)
        seen = np.isfinite(d).all(axis=1)  # K earlier points within NEAR_M: a wall seen before
        if seen.any():
            d_all.append(_to_line(points[now][seen], old[idx[seen]]))
    d = np.concatenate(d_all) if d_all else np.empty(0)
    d = d[np.isfinite(d)]
    return {"points": int(d.size), "median_m": float(np.median(d)) if d.size else float("nan"),
            "doubled": float(np.mean(d > DOUBLED_M)) if d.size else float("nan")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--logs", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--gap", type=float, default=10.0, help="seconds between a point and the earlier ones")
    ap.add_argument("--keep", type=Path, help="keep the processed outputs here (maps to look at)")
    ap.add_argument("--datasets", type=Path, default=WEAN.parent,
                    help="folder holding cmu_wean_hall/robotdata1.log.xz ... (default: %(default)s)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        print(f"gap {args.gap:g} s; per trajectory: median distance to an earlier point (cm) / "
              f"fraction {DOUBLED_M * 100:.0f} cm-{NEAR_M:g} m off (doubled walls)")
        print("| log | " + " | ".join(TRAJECTORIES) + " |")
        print("|---" * (len(TRAJECTORIES) + 1) + "|")
        for n in args.logs:
            source = args.datasets / WEAN.name / f"robotdata{n}.log.xz"
            log, out = work / f"wean{n}.mcap", work / f"wean{n}"
            if not (out / "run.json").exists():
                import_carmen(source, log)
                process(log, out, ProcessOptions())
            cells = []
            for name in TRAJECTORIES:
                stamps, poses = _tum(out / f"{name}.tum")
                pts, times = scan_points(source, stamps, poses)
                r = doubled_walls(pts, times, args.gap)
                cells.append(f"{r['median_m'] * 100:.1f} / {r['doubled']:.3f}")
            print(f"| robotdata{n} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
