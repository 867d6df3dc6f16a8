"""Benchmark: how long `fmcwlog record` takes for a long log, and its peak memory.

Targets: 10 minutes of `corridor` in under 30 s on a 2-core machine, and 100x real
time. Runs the real CLI in a child process so peak RSS is that of the recording alone; reports its
CPU seconds (user + system) beside the wall time, since on a shared machine wall time measures the
neighbours too.

    python bench/bench_record.py                 # 600 s of corridor
    python bench/bench_record.py --duration 120 --scenario crowd
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenario", default="corridor")
    ap.add_argument("--duration", type=float, default=600.0, help="simulated seconds")
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeat):
            out = os.path.join(tmp, f"bench{i}.mcap")
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-m", "fmcwlog", "record", "--scenario", args.scenario,
                            "--duration", str(args.duration), "-o", out], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            wall = time.perf_counter() - t0
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
            rows.append({"wall_s": round(wall, 2), "cpu_s": round(cpu, 2),
                         "size_mb": round(os.path.getsize(out) / 1e6, 1)})
    peak_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    result = {
        "scenario": args.scenario,
        "simulated_s": args.duration,
        "runs": rows,
        "best_wall_s": min(r["wall_s"] for r in rows),
        "realtime_factor": round(args.duration / min(r["wall_s"] for r in rows), 1),
        "best_cpu_s": min(r["cpu_s"] for r in rows),
        "realtime_factor_cpu": round(args.duration / min(r["cpu_s"] for r in rows), 1),
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "peak_rss_mb": round(peak_mb, 1),
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
