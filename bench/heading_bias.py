"""Heading bias of a trajectory: how far its heading sits from its direction of travel, and how
fast its heading drifts, against the log's ground truth.

    python bench/heading_bias.py OUT_DIR [LOG] [--trajectory improved_frontend]

For each pair of consecutive poses of the trajectory (a ``<name>.tum`` in ``OUT_DIR``, as
``fmcwlog process`` writes it; ``LOG`` defaults to the one run.json names) and of the ground
truth at the same stamps:

- ``crab_deg``: the step's direction of travel seen from the robot (``atan2`` of the step in the
  earlier pose's frame), estimate minus truth, averaged over the steps weighted by their length
  (steps under 5 mm left out). Positive: the estimate travels to the left of where it heads, i.e.
  its heading sits to the right (clockwise) of its direction of travel by that much.
- ``drift_deg_per_m``: the sum of the steps' yaw changes, estimate minus truth, over the path
  length (deg per metre travelled, positive counter-clockwise).

A registration that is biased in rotation on straight walls shows as a nonzero ``crab_deg`` on
a corridor (both walls straight, the robot driving along them).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from fmcwlog.evaluation.ground_truth import read_ground_truth  # noqa: E402
from fmcwlog.evaluation.metrics import interpolate_reference  # noqa: E402
from fmcwlog.geometry import wrap_angle  # noqa: E402
from fmcwlog.io.logs import open_log  # noqa: E402
from fmcwlog.io.outputs import read_tum  # noqa: E402

MIN_STEP_M = 0.005


def _steps(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per consecutive pair of poses (N, 3): the step's length (m), its direction in the earlier
    pose's frame (rad) and the yaw change (rad)."""
    d = np.diff(poses[:, :2], axis=0)
    yaw = poses[:-1, 2]
    local_x = np.cos(yaw) * d[:, 0] + np.sin(yaw) * d[:, 1]
    local_y = -np.sin(yaw) * d[:, 0] + np.cos(yaw) * d[:, 1]
    return np.hypot(d[:, 0], d[:, 1]), np.arctan2(local_y, local_x), wrap_angle(np.diff(poses[:, 2]))


def heading_bias(t_est: np.ndarray, est: np.ndarray, t_gt: np.ndarray, gt: np.ndarray) -> dict[str, float]:
    """``crab_deg``, ``drift_deg_per_m`` and ``path_m`` of the estimate (stamps s, poses (N, 3))
    against the ground truth (module docstring)."""
    idx, ref = interpolate_reference(t_est, t_gt, gt)
    est = est[idx]
    length_e, dir_e, dyaw_e = _steps(est)
    length_g, dir_g, dyaw_g = _steps(ref)
    moving = (length_g > MIN_STEP_M) & (length_e > MIN_STEP_M)
    crab = wrap_angle(dir_e - dir_g)[moving]
    path = float(length_g.sum())
    # the estimate placed on the truth at its first pose: its heading error along the path
    yaw_err = wrap_angle((est[:, 2] - est[0, 2]) - (ref[:, 2] - ref[0, 2]))
    return {"crab_deg": float(np.degrees(np.average(crab, weights=length_g[moving]))) if moving.any() else float("nan"),
            "crab_1m_deg": _crab_over(est, ref, 1.0),
            "heading_deg": float(np.degrees(np.mean(yaw_err))),
            "drift_deg_per_m": float(np.degrees(np.sum(wrap_angle(dyaw_e - dyaw_g))) / path) if path > 0 else float("nan"),
            "path_m": path}


def _crab_over(est: np.ndarray, ref: np.ndarray, span_m: float) -> float:
    """``crab_deg`` over steps of at least ``span_m`` of true path (each pose to the first one
    that far on), where a sweep-to-sweep step's direction is mostly noise (deg)."""
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(ref[:, :2], axis=0).T))])
    j = np.searchsorted(along, along + span_m)
    i = np.flatnonzero(j < len(ref))
    if i.size == 0:
        return float("nan")
    j = j[i]

    def direction(p: np.ndarray) -> np.ndarray:
        d = p[j, :2] - p[i, :2]
        c, s = np.cos(p[i, 2]), np.sin(p[i, 2])
        return np.arctan2(-s * d[:, 0] + c * d[:, 1], c * d[:, 0] + s * d[:, 1])

    return float(np.degrees(np.mean(wrap_angle(direction(est) - direction(ref)))))


def measure(out_dir: Path, log: Path | None, trajectory: str) -> dict[str, float]:
    """:func:`heading_bias` of ``out_dir/<trajectory>.tum`` against ``log``'s ground truth."""
    if log is None:
        log = Path(json.loads((out_dir / "run.json").read_text())["log"])
    gt_ns, gt = read_ground_truth(open_log(log))
    t_est, est = read_tum(out_dir / f"{trajectory}.tum")
    return heading_bias(t_est, est, gt_ns * 1e-9, gt)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("log", type=Path, nargs="?")
    ap.add_argument("--trajectory", default="improved_frontend")
    args = ap.parse_args()
    r = measure(args.out_dir, args.log, args.trajectory)
    print(f"{args.trajectory}: crab {r['crab_deg']:+.4f} deg (over 1 m {r['crab_1m_deg']:+.4f}), "
          f"heading {r['heading_deg']:+.4f} deg, drift {r['drift_deg_per_m']:+.5f} deg/m "
          f"over {r['path_m']:.1f} m")


if __name__ == "__main__":
    main()
