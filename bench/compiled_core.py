"""Benchmark: the baseline's registration with the compiled kernels against the numpy reference,
and both against KISS-ICP's whole sweep, in one process, one thread.

1. Every registration the baseline makes on the log is captured (processing it with the numpy
   kernels), then replayed with numpy and compiled alternately, registration by registration
   (CPU time, the best of ``--repeat`` runs of each): per-registration time.
2. The baseline's whole sweep (``FrontEnd.step``: deskew, registration, recovery check, map),
   processing the log once per kernel choice: per-sweep time.
3. KISS-ICP (``bench/kiss_icp_peer.py``) on the same log: its whole frame.

    python -m fmcwlog record --duration 120 -o corridor120.mcap   # the log fmcwlog run makes
    python bench/compiled_core.py corridor120.mcap                 # writes bench/results/compiled_core.{json,md}
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's fmcwlog
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"

import numpy as np
from scipy.spatial import cKDTree

from fmcwlog import __version__
from fmcwlog.api import ProcessOptions, process
from fmcwlog.frontend import methods
from fmcwlog.frontend import point_to_point_icp as p2p
from fmcwlog.kernels import compiled


def select(kind: str):
    os.environ[compiled.ENV] = kind
    compiled._chosen = None
    return compiled.core()


def capture(log: str) -> list[tuple]:
    seen, original = [], methods.register_point_to_point

    def recording(source, tree, target, start, params):
        seen.append((source.copy(), target.copy(), np.array(start, float), params))
        return p2p.register_point_to_point_numpy(source, tree, target, start, params)

    methods.register_point_to_point = recording
    try:
        with tempfile.TemporaryDirectory() as tmp:
            process(log, tmp + "/out", ProcessOptions(methods=("baseline",)), jobs=1)
    finally:
        methods.register_point_to_point = original
    return seen


def per_registration(cases: list[tuple], repeat: int) -> dict[str, np.ndarray]:
    """CPU µs of each registration, numpy and compiled, alternating; the tree is built outside the timing
    (the map keeps it), the compiled kernel's grid inside."""
    out = {"numpy": np.empty(len(cases)), "compiled": np.empty(len(cases))}
    for i, (source, target, start, params) in enumerate(cases):
        tree = cKDTree(target)
        for kind in ("numpy", "compiled"):
            select(kind)
            best = np.inf
            for _ in range(repeat):
                c0 = time.process_time_ns()
                p2p.register_point_to_point(source, tree, target, start, params)
                best = min(best, time.process_time_ns() - c0)
            out[kind][i] = best / 1e3
    return out


def per_sweep(log: str, kind: str) -> np.ndarray:
    """CPU ms of the baseline's FrontEnd.step, each sweep, with ``kind`` kernels."""
    select(kind)
    times, step = [], methods.FrontEnd.step

    def timed(self, sweep, prior):
        c0 = time.process_time_ns()
        try:
            return step(self, sweep, prior)
        finally:
            times.append((time.process_time_ns() - c0) / 1e6)

    methods.FrontEnd.step = timed  # type: ignore[method-assign]
    try:
        with tempfile.TemporaryDirectory() as tmp:
            process(log, tmp + "/out", ProcessOptions(methods=("baseline",)), jobs=1)
    finally:
        methods.FrontEnd.step = step  # type: ignore[method-assign]
    return np.array(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each registration; the best counts")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "compiled_core"))
    args = ap.parse_args()
    if select("compiled") is None:
        sys.exit("fmcwlog._core is not built: pip install . first")

    cases = capture(args.log)
    reg = per_registration(cases, args.repeat)
    sweep = {kind: per_sweep(args.log, kind) for kind in ("numpy", "compiled")}
    sys.path.insert(0, str(ROOT / "bench"))
    from kiss_icp_peer import run_kiss_icp

    with tempfile.TemporaryDirectory() as tmp:
        kiss = run_kiss_icp(Path(args.log), Path(tmp))
    kiss_ms = kiss["cpu_ms_median"]
    rows = {
        "registration numpy (µs, median)": float(np.median(reg["numpy"])),
        "registration compiled (µs, median)": float(np.median(reg["compiled"])),
        "registration numpy / compiled (median of ratios)": float(np.median(reg["numpy"] / reg["compiled"])),
        "baseline sweep numpy (ms, median)": float(np.median(sweep["numpy"])),
        "baseline sweep compiled (ms, median)": float(np.median(sweep["compiled"])),
        "baseline sweep numpy (ms, p95)": float(np.percentile(sweep["numpy"], 95)),
        "baseline sweep compiled (ms, p95)": float(np.percentile(sweep["compiled"], 95)),
        "KISS-ICP frame (ms, median)": kiss_ms,
        "registration compiled / KISS-ICP frame": float(np.median(reg["compiled"])) / 1e3 / kiss_ms,
        "registration numpy / KISS-ICP frame": float(np.median(reg["numpy"])) / 1e3 / kiss_ms,
        "baseline sweep compiled / KISS-ICP frame": float(np.median(sweep["compiled"])) / kiss_ms,
        "baseline sweep numpy / KISS-ICP frame": float(np.median(sweep["numpy"])) / kiss_ms,
    }
    info = {"log": args.log, "registrations": len(cases), "sweeps": int(len(sweep["numpy"])), "fmcwlog": __version__,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
            "rows": rows}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out + ".json").write_text(json.dumps(info, indent=2))
    md = ["| measure | value |", "|---|---|"] + [f"| {k} | {v:.3g} |" for k, v in rows.items()]
    Path(args.out + ".md").write_text("\n".join(md) + "\n")
    print(json.dumps(info, indent=2))


if __name__ == "__main__":
    main()
