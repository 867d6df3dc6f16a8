"""The benchmark suite: every built-in scenario x seeds, every method, one table.

For each scenario and seed it records a log, processes it with each method in
a child process of its own (so each method's time and peak memory are its
own), runs KISS-ICP on the same log as a peer (`bench/kiss_icp_peer.py`, needs
the `bench` extra), evaluates everything with `fmcwlog report`'s code (the improved
method's front end alone, `improved_frontend.tum`, as a row of its own beside the full
method), and writes one table, averaged over the seeds, as Markdown and JSON. Then it
measures how `process` scales with the log's length.

    pip install -e '.[bench]'
    python bench/suite.py              # every scenario (7) x 3 seeds x 2 min + scaling 1/5/20 min (~30 min)
    python bench/suite.py --quick      # every scenario x 1 seed x 20 s + scaling 0.25/0.5/1 min (~1.5 min)
    python bench/suite.py --scenarios warehouse crowd crowd+worse-doppler --seeds 0 1 2 --duration 60 --scaling

A case is a built-in scenario, optionally ``+SENSOR``: the sensor parameters of
bench/sensors/SENSOR.toml over the defaults (``crowd+worse-doppler``: Doppler noise 0.1 m/s,
resolution 0.25 m/s); ``--sensor SENSOR`` adds it to every case. ``warehouse`` is driven at
its own speed (3 m/s: its 343 m route in 120 s, ``SCENARIO_ROBOT``).

Writes bench/results/suite.md and suite.json (or --out DIR).
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

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from results_io import kiss_icp_available, write_results  # noqa: E402

from fmcwlog.config import read_config_file  # noqa: E402
from fmcwlog.evaluation.evaluate import evaluate  # noqa: E402
from fmcwlog.sim import scenarios  # noqa: E402
from fmcwlog.sim.config import SimConfig, apply_overrides  # noqa: E402
from fmcwlog.sim.recorder import record  # noqa: E402
from fmcwlog.sim.world import World  # noqa: E402

CHILD_PROCESS = r"""
import json, resource, sys
from fmcwlog.api import ProcessOptions, process as process_log
process_log(sys.argv[1], sys.argv[2], ProcessOptions(methods=(sys.argv[3],)))
print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

CHILD_KISS = r"""
import json, resource, sys
from pathlib import Path
sys.path.insert(0, sys.argv[3])
from kiss_icp_peer import run_kiss_icp
run_kiss_icp(Path(sys.argv[1]), Path(sys.argv[2]))
print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""

METRICS = ("ate_rmse_m", "rpe_1m_pct", "rpe_10m_pct", "feature_avg_rel_error_pct", "f1", "ms_per_sweep_median",
           "ms_per_sweep_p95", "peak_rss_mb")


SENSORS = HERE / "sensors"  # SENSOR.toml: [sensor] parameters of a case SCENARIO+SENSOR
# [robot] parameters a scenario is driven with: the warehouse's 343 m route in 120 s
SCENARIO_ROBOT = {"warehouse": {"speed": 3.0}}


def case_config(case: str, duration: float, seed: int) -> tuple[World, SimConfig]:
    """The world and the recording parameters of ``case`` (``SCENARIO`` or ``SCENARIO+SENSOR``):
    the defaults, the sensor file's values, the scenario's robot values, then ``duration`` (s) and ``seed``."""
    name, _, sensor = case.partition("+")
    if name not in scenarios.SCENARIOS:
        raise SystemExit(f"unknown scenario {name!r} in case {case!r} (known: {', '.join(scenarios.SCENARIOS)})")
    cfg = SimConfig()
    if sensor:
        path = SENSORS / f"{sensor}.toml"
        if not path.is_file():
            raise SystemExit(f"no sensor file {path} for case {case!r}")
        cfg = apply_overrides(cfg, read_config_file(path))
    overrides: dict[str, dict] = {"run": {"duration": duration, "seed": seed}}
    if name in SCENARIO_ROBOT:
        overrides["robot"] = SCENARIO_ROBOT[name]
    return scenarios.SCENARIOS[name](), apply_overrides(cfg, overrides).validate()


def _child(code: str, *args: str) -> dict:
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(res.stderr.strip().splitlines()[-1] if res.stderr.strip() else "child failed")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _row(result: dict, method: str, peak: float | None) -> dict:
    r = result["methods"][method]
    return {"ate_rmse_m": r["ate_rmse_m"], "rpe_1m_pct": r["rpe_1m_pct"], "rpe_10m_pct": r["rpe_10m_pct"],
            "feature_avg_rel_error_pct": r["feature_avg_rel_error_pct"],
            "f1": (r.get("segmentation") or {}).get("f1"), "ms_per_sweep_median": r["ms_per_sweep_median"],
            "ms_per_sweep_p95": r["ms_per_sweep_p95"], "peak_rss_mb": peak}


def run_one(scenario: str, seed: int, duration: float, tmp: Path, with_kiss: bool) -> dict[str, dict]:
    log = tmp / f"{scenario}_{seed}.mcap"
    world, cfg = case_config(scenario, duration, seed)
    record(world, cfg, log)
    rows: dict[str, dict] = {}
    for method in ("improved", "baseline"):
        out = tmp / f"{scenario}_{seed}_{method}"
        peak = _child(CHILD_PROCESS, str(log), str(out), method)["peak_rss_mb"]
        result = evaluate(out, log).result
        rows[method] = _row(result, method, peak)
        if method == "improved":
            rows["wheel_odometry"] = _row(result, "wheel_odometry", None)
            if "improved_frontend" in result["methods"]:  # the front end alone, before the back end
                rows["improved_frontend"] = _row(result, "improved_frontend", None)
    if with_kiss:
        out = tmp / f"{scenario}_{seed}_kiss"
        try:
            peak = _child(CHILD_KISS, str(log), str(out), str(HERE))["peak_rss_mb"]
            rows["kiss_icp"] = _row(evaluate(out, log).result, "kiss_icp", peak)
        except RuntimeError as exc:
            print(f"  KISS-ICP failed on {scenario}/{seed}: {exc}", file=sys.stderr)
    for f in tmp.glob(f"{scenario}_{seed}*"):  # keep the disk small
        if f.is_dir():
            import shutil

            shutil.rmtree(f)
    log.unlink(missing_ok=True)
    return rows


def _mean(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return float(np.mean(v)) if v else None


def scaling(minutes: list[float], tmp: Path) -> list[dict]:
    rows = []
    for m in minutes:
        log = tmp / f"scaling_{m}.mcap"
        record(scenarios.corridor(), apply_overrides(SimConfig(), {"run": {"duration": 60 * m}}), log)
        out = tmp / f"scaling_{m}"
        t0 = time.perf_counter()
        peak = _child(CHILD_PROCESS, str(log), str(out), "improved")["peak_rss_mb"]
        wall = time.perf_counter() - t0
        import pyarrow.parquet as pq

        table = pq.read_table(out / "trajectories.parquet", columns=["method", "ms"])
        # the improved method's rows: the file also holds wheel_odometry's, whose ms is null
        ms = table.column("ms").to_numpy(zero_copy_only=False)[table.column("method").to_numpy(zero_copy_only=False) == "improved"]
        rows.append({"minutes": m, "sweeps": int(ms.size), "ms_per_sweep_median": float(np.median(ms)),
                     "ms_per_sweep_p95": float(np.percentile(ms, 95)), "wall_s": wall, "peak_rss_mb": peak})
        print(f"  scaling {m:g} min: {rows[-1]['ms_per_sweep_median']:.2f} ms/sweep, {peak:.0f} MB", flush=True)
        log.unlink()
    return rows


def fmt(x: float | None, digits: int, scale: float = 1.0) -> str:
    return "—" if x is None else f"{x * scale:.{digits}f}"


def markdown(table: list[dict], scale_rows: list[dict], meta: dict) -> str:
    lines = [f"Suite: {meta['scenarios']} x seeds {meta['seeds']} x {meta['duration_s']:g} s, "
             f"{meta['machine']}; {meta['wall_s']:.0f} s in all. Mean over seeds.", "",
             "| scenario | method | ATE RMSE cm | RPE 1 m % | RPE 10 m % | feature error % | moving F1 | ms/sweep median | ms/sweep p95 | peak RSS MB |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in table:
        lines.append(f"| {r['scenario']} | {r['method']} | {fmt(r['ate_rmse_m'], 1, 100)} | {fmt(r['rpe_1m_pct'], 2)} | "
                     f"{fmt(r['rpe_10m_pct'], 2)} | {fmt(r['feature_avg_rel_error_pct'], 2)} | {fmt(r['f1'], 3)} | "
                     f"{fmt(r['ms_per_sweep_median'], 2)} | {fmt(r['ms_per_sweep_p95'], 2)} | {fmt(r['peak_rss_mb'], 0)} |")
    lines += ["", "Scaling of `process --method improved` with the log's length (corridor):", "",
              "| minutes | sweeps | ms/sweep median | ms/sweep p95 | wall s | peak RSS MB |", "|---|---|---|---|---|---|"]
    for r in scale_rows:
        lines.append(f"| {r['minutes']:g} | {r['sweeps']} | {r['ms_per_sweep_median']:.2f} | {r['ms_per_sweep_p95']:.2f} | "
                     f"{r['wall_s']:.1f} | {r['peak_rss_mb']:.0f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="1 seed, 20 s logs, scaling 0.25/0.5/1 min")
    ap.add_argument("--seeds", type=int, nargs="+", default=None)
    ap.add_argument("--duration", type=float, default=None, help="seconds per log")
    ap.add_argument("--scenarios", nargs="+", default=list(scenarios.SCENARIOS), help="SCENARIO or SCENARIO+SENSOR")
    ap.add_argument("--sensor", default=None, help="bench/sensors/SENSOR.toml for every case")
    ap.add_argument("--scaling", type=float, nargs="*", default=None, help="minutes")
    ap.add_argument("--no-kiss", action="store_true", help="skip the KISS-ICP peer")
    ap.add_argument("--out", type=Path, default=HERE / "results")
    args = ap.parse_args()
    seeds = args.seeds or ([0] if args.quick else [0, 1, 2])
    duration = args.duration or (20.0 if args.quick else 120.0)
    scale_minutes = args.scaling if args.scaling is not None else ([0.25, 0.5, 1.0] if args.quick else [1.0, 5.0, 20.0])
    with_kiss = kiss_icp_available(not args.no_kiss)
    if args.sensor:
        args.scenarios = [f"{c}+{args.sensor}" for c in args.scenarios]
    started = time.perf_counter()
    per_run: dict[tuple[str, str], list[dict]] = {}
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        for scenario in args.scenarios:
            for seed in seeds:
                t0 = time.perf_counter()
                for method, row in run_one(scenario, seed, duration, tmp, with_kiss).items():
                    per_run.setdefault((scenario, method), []).append(row)
                imp = per_run[(scenario, "improved")][-1]
                print(f"{scenario} seed {seed}: improved ATE {fmt(imp['ate_rmse_m'], 1, 100)} cm, "
                      f"{imp['ms_per_sweep_median']:.2f} ms/sweep ({time.perf_counter() - t0:.0f} s)", flush=True)
        scale_rows = scaling(scale_minutes, tmp)
    table = []
    for (scenario, method), rows in per_run.items():
        agg = {k: _mean([r[k] for r in rows]) for k in METRICS}
        agg["peak_rss_mb"] = max((r["peak_rss_mb"] for r in rows if r["peak_rss_mb"] is not None), default=None)
        table.append({"scenario": scenario, "method": method, "runs": len(rows), **agg,
                      "per_seed_ate_rmse_m": [r["ate_rmse_m"] for r in rows]})
    meta = {"scenarios": ", ".join(args.scenarios), "seeds": seeds, "duration_s": duration,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
            "wall_s": time.perf_counter() - started, "kiss_icp": with_kiss}
    name = "suite_quick" if args.quick else "suite"
    write_results(args.out, name, markdown(table, scale_rows, meta), {"meta": meta, "table": table, "scaling": scale_rows})


if __name__ == "__main__":
    main()
