"""Estimation robustness: every mount, dense crowds, a wrong calibration, in one table.

For each case it records a log, runs ``fmcwlog process`` (both methods) and the KISS-ICP peer
(``bench/kiss_icp_peer.py``, if the ``bench`` extra is installed) on it, and scores them with
``fmcwlog report``'s code. The cases:

- the suite's scenarios (``corridor``, ``static``, ``crowd``, ``long-corridor``) and
  ``dense-crowd`` (about half of the returns on movers);
- ``corridor`` with the LiDAR over the rear axle (``sensor.mount_x=0``), sideways
  (``mount_x=0``, ``mount_y=0.25``) and yawed 90°;
- ``corridor`` processed with a deliberately wrong calibration (``lidar_x`` 0.30 m too far
  forward, given as a ``--calibration`` file), then ``fmcwlog calibrate`` on the same log and
  the log processed again with the file it wrote.

Columns: ATE RMSE (SE(2)-aligned) of each method, with the back end and (the same run's
``<method>_frontend`` trajectory) without it; the improved method's moving-point precision
and recall against the simulator's labels; what the calibration check said (run.json's
``calibration_check``: the values that disagree, with the estimate).

    python bench/robustness.py                 # 10 cases x 2 min, seed 0 (~15 min on 2 cores)
    python bench/robustness.py --seeds 0 1 2   # more seeds (mean and spread per case)
    python bench/robustness.py --quick         # 30 s logs

Writes bench/results/robustness.md and .json (or --out DIR).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from results_io import kiss_icp_available, write_results  # noqa: E402

from fmcwlog import api  # noqa: E402
from fmcwlog.evaluation.evaluate import evaluate  # noqa: E402
from fmcwlog.io.mcap_log import LogReader  # noqa: E402
from fmcwlog.io.topics import CALIBRATION_KEY  # noqa: E402
from fmcwlog.sim import scenarios  # noqa: E402
from fmcwlog.sim.config import SimConfig, apply_overrides  # noqa: E402
from fmcwlog.sim.recorder import record  # noqa: E402

WRONG_LIDAR_X_OFF = 0.30  # m added to the log's lidar_x in the wrong calibration

# name, scenario, sensor overrides, calibration: None (the log's), "wrong", "calibrated"
CASES: list[tuple[str, str, dict, str | None]] = [
    ("corridor", "corridor", {}, None),
    ("static", "static", {}, None),
    ("crowd", "crowd", {}, None),
    ("long-corridor", "long-corridor", {}, None),
    ("dense-crowd", "dense-crowd", {}, None),
    ("corridor, LiDAR over the axle", "corridor", {"mount_x": 0.0}, None),
    ("corridor, LiDAR sideways", "corridor", {"mount_x": 0.0, "mount_y": 0.25}, None),
    ("corridor, LiDAR yawed 90°", "corridor", {"mount_yaw_deg": 90.0}, None),
    (f"corridor, lidar_x calibrated {WRONG_LIDAR_X_OFF:.2f} m off", "corridor", {}, "wrong"),
    ("the same after `fmcwlog calibrate`", "corridor", {}, "calibrated"),
]
METHODS = ("improved", "baseline", "wheel_odometry", "kiss_icp")
FRONT_ENDS = ("improved_frontend", "baseline_frontend")  # the same run's trajectories before the back end

CHILD_KISS = r"""
import sys
from pathlib import Path
sys.path.insert(0, sys.argv[3])
from kiss_icp_peer import run_kiss_icp
run_kiss_icp(Path(sys.argv[1]), Path(sys.argv[2]))
"""


def _kiss(log: Path, out: Path) -> float | None:
    res = subprocess.run([sys.executable, "-c", CHILD_KISS, str(log), str(out), str(HERE)], capture_output=True,
                         text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    if res.returncode != 0:
        print(f"  KISS-ICP failed: {res.stderr.strip().splitlines()[-1:]}", file=sys.stderr)
        return None
    return evaluate(out, log).result["methods"]["kiss_icp"]["ate_rmse_m"]


def _wrong_calibration(log: Path, path: Path) -> Path:
    """The log's own calibration record with lidar_x moved forward, as a calibration file."""
    values = dict(LogReader(log).metadata[CALIBRATION_KEY])
    values["lidar_x"] = repr(float(values["lidar_x"]) + WRONG_LIDAR_X_OFF)
    path.write_text("".join(f"{k}: {v}\n" for k, v in values.items()))
    return path


def _check_said(run: dict) -> str:
    check = run.get("calibration_check") or {}
    if not check.get("checked"):
        return f"not checked ({check.get('reason', '?')})"
    if not check["disagrees"]:
        return "agrees"
    parts = []
    for name in check["disagrees"]:
        v = check["values"][name]
        scale, unit = (math.degrees(1), "°") if name == "lidar_yaw" else (1e3, "mm")
        parts.append(f"{name} {v['estimate'] * scale:.0f} ± {v['sigma'] * scale:.0f} {unit}, "
                     f"not {v['calibration'] * scale:.0f}")
    return "disagrees: " + "; ".join(parts)


def run_case(name: str, scenario: str, sensor: dict, calibration: str | None, seed: int, duration: float,
             tmp: Path, logs: dict, with_kiss: bool) -> dict:
    key = (scenario, tuple(sorted(sensor.items())), seed)
    log = logs.get(key)
    if log is None:
        log = tmp / f"log{len(logs)}.mcap"
        cfg = apply_overrides(SimConfig(), {"run": {"duration": duration, "seed": seed}, "sensor": sensor})
        record(scenarios.SCENARIOS[scenario](), cfg, log)
        logs[key] = log
    cal_file = None
    if calibration in ("wrong", "calibrated"):
        cal_file = _wrong_calibration(log, tmp / "wrong.yaml")
    if calibration == "calibrated":
        fixed = tmp / "calibrated.yaml"
        api.calibrate(log, fixed, api.ProcessOptions(methods=("improved",), calibration=cal_file), force=True)
        cal_file = fixed
    out = tmp / f"out-{CASES.index(next(c for c in CASES if c[0] == name))}-{seed}"
    api.process(log, out, api.ProcessOptions(calibration=cal_file))
    run = json.loads((out / "run.json").read_text())
    result = evaluate(out, log).result
    row = {"case": name, "seed": seed}
    for m in (*METHODS[:3], *FRONT_ENDS):
        row[m] = (result["methods"].get(m) or {}).get("ate_rmse_m")
    row["kiss_icp"] = _kiss(log, out.with_name(out.name + "-kiss")) if with_kiss and calibration is None else None
    seg = result["methods"]["improved"].get("segmentation") or {}
    row["precision"], row["recall"] = seg.get("precision"), seg.get("recall")
    row["false_moving"] = seg.get("false_positives")
    row["calibration_check"] = _check_said(run)
    row["warnings"] = run.get("warnings", [])
    shutil.rmtree(out, ignore_errors=True)
    return row


def _fmt(x: float | None, digits: int, scale: float = 1.0) -> str:
    return "—" if x is None else f"{x * scale:.{digits}f}"


def _mean_row(rows: list[dict]) -> dict:
    out = dict(rows[0])
    for k in (*METHODS, *FRONT_ENDS, "precision", "recall", "false_moving"):
        v = [r[k] for r in rows if r[k] is not None]
        out[k] = float(np.mean(v)) if v else None
        out[f"{k}_max"] = float(np.max(v)) if v else None
    out["calibration_check"] = " / ".join(dict.fromkeys(r["calibration_check"] for r in rows))
    return out


def markdown(table: list[dict], meta: dict) -> str:
    lines = [f"{meta['duration_s']:g} s logs, seeds {meta['seeds']} (mean; worst in brackets when several), "
             f"{meta['machine']}; {meta['wall_s']:.0f} s in all. ATE RMSE in cm after SE(2) alignment.", "",
             "| case | improved | baseline | improved, front end alone | baseline, front end alone | wheel odometry | "
             "KISS-ICP | moving precision | moving recall | static points judged moving | calibration check |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    several = len(meta["seeds"]) > 1
    for r in table:
        def cell(k: str, digits: int = 2, scale: float = 100.0, r: dict = r) -> str:
            s = _fmt(r[k], digits, scale)
            return f"{s} ({_fmt(r[k + '_max'], digits, scale)})" if several and r[k] is not None else s
        lines.append(f"| {r['case']} | {cell('improved')} | {cell('baseline', 1)} | {cell('improved_frontend')} | "
                     f"{cell('baseline_frontend', 1)} | {cell('wheel_odometry', 0)} | "
                     f"{cell('kiss_icp', 1)} | {_fmt(r['precision'] if r['recall'] is not None else None, 4)} | "
                     f"{_fmt(r['recall'], 4)} | {_fmt(r['false_moving'], 0)} | "
                     f"{r['calibration_check']} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="30 s logs")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--duration", type=float, default=None, help="seconds per log (default 120)")
    ap.add_argument("--no-kiss", action="store_true", help="skip the KISS-ICP peer")
    ap.add_argument("--cases", nargs="+", default=None, metavar="NAME",
                    help="only the cases whose name starts with one of these (e.g. dense-crowd)")
    ap.add_argument("--out", type=Path, default=HERE / "results")
    args = ap.parse_args()
    cases = [c for c in CASES if args.cases is None or c[0].startswith(tuple(args.cases))]
    duration = args.duration or (30.0 if args.quick else 120.0)
    with_kiss = kiss_icp_available(not args.no_kiss)
    started = time.perf_counter()
    table, per_seed = [], []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for seed in args.seeds:
            logs: dict = {}
            for case in cases:
                t0 = time.perf_counter()
                row = run_case(*case, seed, duration, tmp, logs, with_kiss)
                per_seed.append(row)
                print(f"{row['case']} seed {seed}: improved {_fmt(row['improved'], 2, 100)} cm, baseline "
                      f"{_fmt(row['baseline'], 1, 100)} cm, recall {_fmt(row['recall'], 4)}; "
                      f"{row['calibration_check']} ({time.perf_counter() - t0:.0f} s)", flush=True)
            for f in logs.values():
                f.unlink(missing_ok=True)
    for case in cases:
        table.append(_mean_row([r for r in per_seed if r["case"] == case[0]]))
    meta = {"seeds": args.seeds, "duration_s": duration, "kiss_icp": with_kiss,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
            "wall_s": time.perf_counter() - started}
    name = ("robustness_quick" if args.quick else "robustness") + ("" if args.cases is None else "_" + "_".join(
        c.replace(" ", "-") for c in args.cases))
    write_results(args.out, name, markdown(table, meta), {"meta": meta, "table": table, "per_seed": per_seed})


if __name__ == "__main__":
    main()
