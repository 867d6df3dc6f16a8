"""Speed benchmark: fmcwlog's methods against KISS-ICP, one thread each, in the same run.

For each scenario it records a log (timing ``record``), then, each in a child process of its own
with BLAS/OpenMP pinned to one thread:

- ``process --method improved`` and ``--method baseline``: median and p95 ms per sweep;
- ``process`` with both methods and every output: the wall time of a whole run, the second method
  in a process of its own where two cores are usable (:mod:`fmcwlog.pipeline.method_process`); its CPU
  time counts both processes (``RUSAGE_CHILDREN``), its peak memory is the two peaks added;
- KISS-ICP 1.3 (``bench/kiss_icp_peer.py``, ``max_num_threads = 1``): ms per sweep and the wall
  time of its whole run (reading the log and registering every sweep);

and prints the ratio table: improved and baseline ms per sweep over KISS-ICP's (targets: ≤ 0.5),
p95 over median (target < 3), the whole ``process`` run in times real time (target ≥ 50) and over
KISS-ICP's whole run (target ≤ 1.0), ``record`` in times real time (target ≥ 100); and the same
per-sweep and whole-run comparisons in CPU time (``time.process_time``), which a busy machine's
time-slicing does not inflate: on a shared 2-core machine at load 6 the wall-time ratios moved
by up to 2x between runs of unchanged code. It also checks
that accuracy did not move: the improved method's ATE on each scenario against the reference in
``bench/results/speed_reference.json`` (within 10 %; ``--write-reference`` records it).

    pip install -e '.[bench]'
    python bench/speed.py --quick          # 4 scenarios x 20 s, about a minute
    python bench/speed.py                  # the suite's scenarios x 2 min, + memory for 1/5/20 min

Machines are shared and noisy: a ratio is a result, a time alone is not.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))

from fmcwlog.evaluation.evaluate import evaluate  # noqa: E402

ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
                               "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")}
REFERENCE = HERE / "results" / "speed_reference.json"

CHILD_PROCESS = r"""
import json, resource, sys, time
import numpy as np, pyarrow.parquet as pq
from fmcwlog.api import ProcessOptions, process
from fmcwlog.frontend.methods import FrontEnd
log, out, methods = sys.argv[1], sys.argv[2], tuple(sys.argv[3].split(","))
cpu = {m: [] for m in methods}
step = FrontEnd.step
def timed_step(self, sweep, prior):  # CPU time of a sweep beside the wall time the method records
    c0 = time.process_time()
    r = step(self, sweep, prior)
    cpu[self.name].append((time.process_time() - c0) * 1e3)
    return r
FrontEnd.step = timed_step
def children_cpu():  # the process that runs the second method (fmcwlog.pipeline.method_process), once ended
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime
t0, c0, k0 = time.perf_counter(), time.process_time(), children_cpu()
process(log, out, ProcessOptions(methods=methods))
wall, cpu_s = time.perf_counter() - t0, time.process_time() - c0 + children_cpu() - k0
t = pq.read_table(out + "/trajectories.parquet", columns=["method", "ms"]).to_pydict()
ms = {m: [x for mm, x in zip(t["method"], t["ms"]) if mm == m] for m in methods}
print(json.dumps({"wall_s": wall, "cpu_s": cpu_s, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "child_peak_rss_mb": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
                  "ms": {m: {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
                             "max": float(np.max(v)),
                             # a method run in the child process has its per-sweep CPU times there
                             "cpu_median": float(np.median(cpu[m])) if cpu[m] else None} for m, v in ms.items()}}))
"""

CHILD_KISS = r"""
import json, resource, sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[3])
from kiss_icp_peer import run_kiss_icp
t0, c0 = time.perf_counter(), time.process_time()
r = run_kiss_icp(Path(sys.argv[1]), Path(sys.argv[2]), threads=1)
r["wall_s"], r["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
r["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(r))
"""

CHILD_RECORD = r"""
import json, sys, time
from fmcwlog import api
from fmcwlog.sim.config import SimConfig, apply_overrides
scenario, duration, seed, out = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
cfg = apply_overrides(SimConfig(), {"run": {"duration": duration, "seed": seed}})
t0 = time.perf_counter()
api.record(api.scenario(scenario), cfg, out)
print(json.dumps({"wall_s": time.perf_counter() - t0}))
"""


def _child(code: str, *args: str) -> dict:
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         env={**os.environ, **ONE_THREAD}, cwd=ROOT)
    if res.returncode != 0:
        raise RuntimeError(res.stderr.strip().splitlines()[-1] if res.stderr.strip() else "child failed")
    return json.loads(res.stdout.strip().splitlines()[-1])


def run_scenario(name: str, duration: float, seed: int, tmp: Path, with_kiss: bool) -> dict:
    log = tmp / f"{name}.mcap"
    rec = _child(CHILD_RECORD, name, str(duration), str(seed), str(log))
    row: dict = {"scenario": name, "duration_s": duration, "record_x_realtime": duration / rec["wall_s"]}
    for method in ("improved", "baseline"):
        r = _child(CHILD_PROCESS, str(log), str(tmp / f"{name}_{method}"), method)
        row[f"{method}_ms_median"] = r["ms"][method]["median"]
        row[f"{method}_ms_p95"] = r["ms"][method]["p95"]
        row[f"{method}_ms_max"] = r["ms"][method]["max"]
        row[f"{method}_cpu_ms_median"] = r["ms"][method]["cpu_median"]
        if method == "improved":
            row["improved_ate_m"] = evaluate(tmp / f"{name}_{method}", log).result["methods"]["improved"]["ate_rmse_m"]
    both = _child(CHILD_PROCESS, str(log), str(tmp / f"{name}_both"), "improved,baseline")
    row["process_wall_s"], row["process_cpu_s"] = both["wall_s"], both["cpu_s"]
    row["process_x_realtime"] = duration / both["wall_s"]
    row["process_peak_rss_mb"] = both["peak_rss_mb"] + both["child_peak_rss_mb"]
    if with_kiss:
        k = _child(CHILD_KISS, str(log), str(tmp / f"{name}_kiss"), str(HERE))
        row["kiss_ms_median"], row["kiss_wall_s"] = k["ms_median"], k["wall_s"]
        row["kiss_cpu_ms_median"], row["kiss_cpu_s"] = k["cpu_ms_median"], k["cpu_s"]
        row["improved_over_kiss"] = row["improved_ms_median"] / k["ms_median"]
        row["baseline_over_kiss"] = row["baseline_ms_median"] / k["ms_median"]
        row["process_wall_over_kiss_wall"] = both["wall_s"] / k["wall_s"]
        row["improved_over_kiss_cpu"] = row["improved_cpu_ms_median"] / k["cpu_ms_median"]
        row["baseline_over_kiss_cpu"] = row["baseline_cpu_ms_median"] / k["cpu_ms_median"]
        row["process_cpu_over_kiss_cpu"] = both["cpu_s"] / k["cpu_s"]
    return row


def memory(minutes: list[float], tmp: Path) -> list[dict]:
    rows = []
    for m in minutes:
        log = tmp / f"mem_{m}.mcap"
        _child(CHILD_RECORD, "corridor", str(60 * m), "0", str(log))
        r = _child(CHILD_PROCESS, str(log), str(tmp / f"mem_{m}"), "improved,baseline")
        rows.append({"minutes": m, "peak_rss_mb": r["peak_rss_mb"] + r["child_peak_rss_mb"], "wall_s": r["wall_s"],
                     "improved_ms_median": r["ms"]["improved"]["median"]})
        print(f"  memory {m:g} min: {r['peak_rss_mb']:.0f} MB peak, {r['wall_s']:.1f} s", flush=True)
        log.unlink()
    return rows


def _f(x, d=2):
    return "—" if x is None else f"{x:.{d}f}"


def table(rows: list[dict]) -> str:
    lines = ["| scenario | improved ms/sweep | baseline ms/sweep | KISS-ICP ms/sweep | improved / KISS | baseline / KISS "
             "| improved p95 / median | process wall s | x real time | KISS wall s | process / KISS wall | record x real time |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scenario']} | {_f(r['improved_ms_median'])} | {_f(r['baseline_ms_median'])} | "
                     f"{_f(r.get('kiss_ms_median'))} | {_f(r.get('improved_over_kiss'))} | {_f(r.get('baseline_over_kiss'))} | "
                     f"{_f(r['improved_ms_p95'] / r['improved_ms_median'])} | {_f(r['process_wall_s'], 1)} | "
                     f"{_f(r['process_x_realtime'], 0)} | {_f(r.get('kiss_wall_s'), 1)} | "
                     f"{_f(r.get('process_wall_over_kiss_wall'))} | {_f(r['record_x_realtime'], 0)} |")
    return "\n".join(lines)


def cpu_table(rows: list[dict]) -> str:
    """The same comparison in CPU time (process_time): what a busy machine's time-slicing leaves out."""
    lines = ["| scenario | improved CPU ms/sweep | baseline CPU ms/sweep | KISS-ICP CPU ms/sweep | improved / KISS | "
             "baseline / KISS | process CPU s | KISS CPU s | process / KISS CPU |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scenario']} | {_f(r['improved_cpu_ms_median'])} | {_f(r['baseline_cpu_ms_median'])} | "
                     f"{_f(r.get('kiss_cpu_ms_median'))} | {_f(r.get('improved_over_kiss_cpu'))} | "
                     f"{_f(r.get('baseline_over_kiss_cpu'))} | {_f(r['process_cpu_s'], 1)} | {_f(r.get('kiss_cpu_s'), 1)} | "
                     f"{_f(r.get('process_cpu_over_kiss_cpu'))} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="4 scenarios x 20 s, no memory scaling (about a minute)")
    ap.add_argument("--scenarios", nargs="+", default=None)
    ap.add_argument("--duration", type=float, default=None, help="seconds per log (default 120; quick 20)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--memory", type=float, nargs="*", default=None, help="minutes (default 1 5 20; quick none)")
    ap.add_argument("--no-kiss", action="store_true")
    ap.add_argument("--write-reference", action="store_true", help="store these ATEs as the accuracy reference")
    ap.add_argument("--out", type=Path, default=HERE / "results")
    args = ap.parse_args()
    names = args.scenarios or ["corridor", "static", "crowd", "long-corridor"]
    duration = args.duration or (20.0 if args.quick else 120.0)
    mem_minutes = args.memory if args.memory is not None else ([] if args.quick else [1.0, 5.0, 20.0])
    with_kiss = not args.no_kiss
    try:
        import kiss_icp  # noqa: F401
    except ImportError:
        print("kiss-icp is not installed (pip install -e '.[bench]'): no peer", file=sys.stderr)
        with_kiss = False
    started = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as name:
        tmp = Path(name)
        for s in names:
            rows.append(run_scenario(s, duration, args.seed, tmp, with_kiss))
            print(f"{s}: improved {rows[-1]['improved_ms_median']:.2f} ms/sweep, "
                  f"KISS-ICP {rows[-1].get('kiss_ms_median', float('nan')):.2f}", flush=True)
        mem = memory(mem_minutes, tmp)
    key = f"{duration:g}s_seed{args.seed}"
    ref = json.loads(REFERENCE.read_text()) if REFERENCE.is_file() else {}
    accuracy = []
    for r in rows:
        base = ref.get(key, {}).get(r["scenario"])
        ok = None if base is None else r["improved_ate_m"] <= 1.1 * base
        accuracy.append(f"| {r['scenario']} | {r['improved_ate_m'] * 100:.2f} | "
                        f"{'—' if base is None else f'{base * 100:.2f}'} | {'—' if ok is None else ('yes' if ok else 'NO')} |")
    if args.write_reference:
        ref.setdefault(key, {}).update({r["scenario"]: r["improved_ate_m"] for r in rows})
        REFERENCE.parent.mkdir(parents=True, exist_ok=True)
        REFERENCE.write_text(json.dumps(ref, indent=2) + "\n")
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    md = [f"Speed: {', '.join(names)} x {duration:g} s, seed {args.seed}; {machine}; one thread each; "
          f"{time.perf_counter() - started:.0f} s in all; load average {os.getloadavg()[0]:.1f} at the end.", "",
          "Wall time (what the targets are stated in):", "", table(rows), "",
          "CPU time of the same runs (steadier than wall time when other processes share the cores):", "",
          cpu_table(rows), "",
          "| scenario | improved ATE cm | reference cm | within 10 % |", "|---|---|---|---|", *accuracy]
    if mem:
        md += ["", "| minutes | peak RSS MB (both processes, their peaks added) | wall s | improved ms/sweep |", "|---|---|---|---|"]
        md += [f"| {m['minutes']:g} | {m['peak_rss_mb']:.0f} | {m['wall_s']:.1f} | {m['improved_ms_median']:.2f} |"
               for m in mem]
    text = "\n".join(md) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    name = "speed_quick" if args.quick else "speed"
    (args.out / f"{name}.md").write_text(text)
    (args.out / f"{name}.json").write_text(json.dumps({"machine": machine, "rows": rows, "memory": mem}, indent=2) + "\n")
    print()
    print(text)


if __name__ == "__main__":
    main()
