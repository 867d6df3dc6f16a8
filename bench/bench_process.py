"""Benchmark: `fmcwlog process` speed and memory per method, and how they scale with log length.

Records `corridor` logs (2 minutes by default), processes each with one method
at a time in a child process (so peak RSS is that method's alone), and prints
the median and 95th-percentile milliseconds per sweep from
trajectories.parquet, the wall time and the peak RSS.

    python bench/bench_process.py                      # 2-minute corridor, both methods
    python bench/bench_process.py --minutes 1 5 20     # scaling: cost per sweep should stay flat

Target: improved under 5 ms per sweep median on a 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile

CHILD = r"""
import json, resource, sys, time
import numpy as np, pyarrow.parquet as pq
from fmcwlog.api import ProcessOptions, process as process_log
log, out, method = sys.argv[1:4]
t0 = time.perf_counter()
process_log(log, out, ProcessOptions(methods=(method,)))
wall = time.perf_counter() - t0
table = pq.read_table(out + "/trajectories.parquet", columns=["method", "ms"])
# the method's own rows: the file also holds wheel_odometry's, whose ms is null
ms = table.column("ms").to_numpy(zero_copy_only=False)[table.column("method").to_numpy(zero_copy_only=False) == method]
print(json.dumps({"sweeps": int(ms.size), "ms_median": float(np.median(ms)), "ms_p95": float(np.percentile(ms, 95)),
                  "wall_s": wall, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="corridor")
    ap.add_argument("--minutes", type=float, nargs="+", default=[2.0])
    ap.add_argument("--methods", nargs="+", default=["improved", "baseline"])
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for minutes in args.minutes:
            log = os.path.join(tmp, f"{args.scenario}_{minutes}.mcap")
            subprocess.run([sys.executable, "-m", "fmcwlog", "record", "--scenario", args.scenario,
                            "--duration", str(60 * minutes), "-o", log], check=True, stdout=subprocess.DEVNULL)
            for method in args.methods:
                out = os.path.join(tmp, f"out_{minutes}_{method}")
                res = subprocess.run([sys.executable, "-c", CHILD, log, out, method], check=True,
                                     capture_output=True, text=True)
                r = json.loads(res.stdout.strip().splitlines()[-1])
                rows.append({"scenario": args.scenario, "minutes": minutes, "method": method,
                             **{k: round(v, 2) if isinstance(v, float) else v for k, v in r.items()}})
                print(json.dumps(rows[-1]), flush=True)
    print()
    print("| scenario | minutes | method | sweeps | ms/sweep median | ms/sweep p95 | wall s | peak RSS MB |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scenario']} | {r['minutes']:g} | {r['method']} | {r['sweeps']} | {r['ms_median']:.2f} | "
              f"{r['ms_p95']:.2f} | {r['wall_s']:.1f} | {r['peak_rss_mb']:.0f} |")
    print(f"\nmachine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}")


if __name__ == "__main__":
    main()
