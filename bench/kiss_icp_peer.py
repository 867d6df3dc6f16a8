"""KISS-ICP (Vizzo et al., RA-L 2023) as a peer on fmcwlog logs, measured like fmcwlog's own methods.

Each sweep is fed to ``kiss_icp.kiss_icp.KissICP`` as 3-D points with z = 0 and
per-point times. KISS-ICP expects times normalised to the scan period and
deskews to the middle of the period (0.5), so the times given are
``t / period`` and its pose is that of the lidar at ``stamp + period / 2``;
it is converted to ``base_link`` with the calibration's mounting
(``base = lidar ⊕ mount⁻¹``) and written to ``kiss_icp.tum`` with that time,
where the report interpolates the ground truth. KISS-ICP's configuration is
its default for the sensor's 30 m range (voxel 0.3 m, adaptive threshold); it
uses no wheel odometry and no Doppler.

    python bench/kiss_icp_peer.py LOG.mcap OUT_DIR     # then: fmcwlog report OUT_DIR
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's fmcwlog, not an installed one

from fmcwlog.geometry import compose, inverse
from fmcwlog.io.calibration import load_calibration
from fmcwlog.io.logs import open_log
from fmcwlog.io.outputs import write_tum
from fmcwlog.io.sweeps import sweep_from_pointcloud
from fmcwlog.io.topics import CALIBRATION_KEY, POINTS_TOPIC


def run_kiss_icp(log: Path, out_dir: Path, max_range: float = 30.0, min_range: float = 0.3,
                 voxel_size: float | None = None, threads: int = 1) -> dict:
    from kiss_icp.config import load_config
    from kiss_icp.kiss_icp import KissICP

    reader = open_log(log)
    cal = load_calibration(reader, log, POINTS_TOPIC, False, None).cal  # the mount as process finds it
    period = 1.0 / float(reader.metadata.get(CALIBRATION_KEY, {}).get("scan_rate", 10.0))
    config = load_config(None)
    config.data.max_range, config.data.min_range = max_range, min_range
    config.mapping.voxel_size = voxel_size or max_range / 100.0  # KISS-ICP's own rule by default
    config.registration.max_num_threads = threads  # one thread, like fmcwlog's methods, unless asked
    odometry = KissICP(config)
    mount_inv = inverse(np.asarray(cal.mount))
    stamps, poses, ms, cpu_ms = [], [], [], []
    for m in reader.messages([POINTS_TOPIC]):
        sweep, _ = sweep_from_pointcloud(reader.path, m.msg)
        frame = np.column_stack([sweep.xy, np.zeros(len(sweep.xy))])
        t0, c0 = time.perf_counter(), time.process_time()
        odometry.register_frame(frame, sweep.t / period)
        ms.append((time.perf_counter() - t0) * 1e3)
        cpu_ms.append((time.process_time() - c0) * 1e3)
        T = odometry.last_pose
        lidar = np.array([T[0, 3], T[1, 3], np.arctan2(T[1, 0], T[0, 0])])
        poses.append(compose(lidar, mount_inv))
        stamps.append(sweep.stamp_ns + int(round(0.5 * period * 1e9)))
    out_dir.mkdir(parents=True, exist_ok=True)
    stamps_a = np.asarray(stamps, dtype=np.int64)
    write_tum(out_dir / "kiss_icp.tum", stamps_a, np.asarray(poses))
    pq.write_table(pa.table({"method": ["kiss_icp"] * len(ms), "stamp_ns": stamps_a, "ms": np.asarray(ms)}),
                   out_dir / "trajectories.parquet")
    info = {"log": str(reader.path.resolve()), "sweeps": len(ms), "scan_topic": POINTS_TOPIC, "prior": "none (KISS-ICP)",
            "doppler": False, "params": {"kiss_icp": config.model_dump()}, "stamp_shift_s": 0.5 * period}
    # report checks the sweeps against the log: the shifted stamps are the sweeps' own plus half a period
    (out_dir / "run.json").write_text(json.dumps(info, indent=2, default=str))
    return {"sweeps": len(ms), "ms_median": float(np.median(ms)), "ms_p95": float(np.percentile(ms, 95)),
            "cpu_ms_median": float(np.median(cpu_ms))}


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log", type=Path, help="an fmcwlog log (.mcap) with /fmcw/points")
    ap.add_argument("out_dir", type=Path, help="folder for kiss_icp.tum, trajectories.parquet and run.json")
    args = ap.parse_args()
    print(json.dumps(run_kiss_icp(args.log, args.out_dir)))
