"""Benchmark: `fmcwlog process` over a folder of logs, and how its wall time scales with workers.

Records N `corridor` logs (8 of 30 s by default, seeds 0..N-1), then processes the folder with
`api.process_many` (the command's own code path) once per worker count, into a fresh folder
each time (nothing skipped), and prints the wall time, sweeps per second over all workers and
the speed-up over one worker, and (local) the cores the workers kept busy: their CPU time over the
wall time, which says how much of the machine the batch actually got. `--ray` adds the same through a local Ray (its start-up is part
of the time, as it is for a user).

    python bench/bench_fleet.py                       # 8 logs x 30 s, 1 and 2 workers
    python bench/bench_fleet.py --jobs 1 2 4 8 16     # on a bigger machine
    python bench/bench_fleet.py --logs 8 --seconds 60 --ray

The speed-up is bounded by the cores that are free: on a 2-core machine shared with other
work it is below 2. `os.getloadavg()` is printed before and after each run for that reason.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fmcwlog import api
from fmcwlog.sim import scenarios
from fmcwlog.sim.config import SimConfig, apply_overrides
from fmcwlog.sim.recorder import record


def _cpu_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _run(logs: Path, out: Path, jobs: int, ray: bool) -> dict:
    load = os.getloadavg()[0]
    cpu0, t0 = _cpu_children(), time.perf_counter()
    summary = api.process_many([logs], out, jobs=jobs, ray=ray)
    wall = time.perf_counter() - t0
    cpu = _cpu_children() - cpu0  # the local workers' CPU time (Ray's workers are not our children)
    shutil.rmtree(out)
    assert not summary.failed, [o.reason for o in summary.failed]
    return {"executor": summary.executor, "jobs": jobs, "logs": len(summary.outcomes), "sweeps": summary.sweeps,
            "wall_s": round(wall, 2), "sweeps_per_s": round(summary.sweeps / wall, 1),
            "cores_used": None if ray else round(cpu / wall, 2),
            "load_before": round(load, 2), "load_after": round(os.getloadavg()[0], 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=30.0, help="length of each log")
    ap.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--ray", action="store_true", help="also through a local Ray with the largest --jobs")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each, interleaved (1 2 1 2 ...); medians shown")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        logs = Path(tmp) / "logs"
        logs.mkdir()
        for seed in range(args.logs):
            cfg = apply_overrides(SimConfig(), {"run": {"duration": args.seconds, "seed": seed}})
            record(scenarios.SCENARIOS["corridor"](), cfg, logs / f"corridor_{seed}.mcap")
        runs = [(j, False) for j in args.jobs] + ([(max(args.jobs), True)] if args.ray else [])
        for rep in range(args.repeat):
            for i, (jobs, ray) in enumerate(runs):
                rows.append(_run(logs, Path(tmp) / f"out{rep}_{i}", jobs, ray))
                print(json.dumps(rows[-1]), flush=True)
    med = {}
    for jobs, ray in runs:
        mine = [r for r in rows if r["jobs"] == jobs and (r["executor"] == "ray") == ray]
        med[(jobs, ray)] = {k: statistics.median(r[k] for r in mine) if mine[0][k] is not None else None
                            for k in ("wall_s", "sweeps_per_s", "cores_used", "load_before")}
    base = med[(min(args.jobs), False)]["wall_s"]
    print(f"\n{args.logs} corridor logs x {args.seconds:g} s, {args.repeat} run(s) each (median); {platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()}\n")
    print("| executor | workers | wall s | sweeps/s | speed-up | cores used | load avg before |")
    print("|---|---|---|---|---|---|---|")
    for (jobs, ray), m in med.items():
        cores = "—" if m["cores_used"] is None else f"{m['cores_used']:.2f}"
        print(f"| {'ray' if ray else 'local'} | {jobs} | {m['wall_s']:.1f} | {m['sweeps_per_s']:.1f} | "
              f"{base / m['wall_s']:.2f} | {cores} | {m['load_before']:.1f} |")


if __name__ == "__main__":
    main()
