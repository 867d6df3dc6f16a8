"""Accuracy cases: ATE per method, the improved method's twist against truth, and its recall split
by what Doppler can see.

For each case (``SCENARIO`` or ``SCENARIO+SENSOR``, as bench/suite.py takes them) and seed it
records a log, processes it with each method in a child process (bench/suite.py's), runs KISS-ICP
as a peer, and scores every trajectory with ``fmcwlog report``'s code. The improved method's child
also keeps, per sweep, what its front end used (``ImprovedFrontEnd.estimate_motion``):

- the fused twist ``(v, ω)`` of base_link (Doppler and wheels, :mod:`fmcwlog.frontend.twist_fusion`),
- Doppler alone: the fitted lidar velocity mapped back through the mount (``A⁻¹ v_s``; the
  sweeps where the front end had no usable Doppler fit are left out of every column),
- the wheels alone: the odometry prior's twist over the sweep,

and compares each with the truth over the same interval: ``/ground_truth/odom``'s poses at the
sweep's stamp and at ``stamp + span``, the motion between them in base_link at the start over the
span (the wheels' own definition). Errors are RMS over the sweeps where all three exist, and
again over the *steady* ones only: where the truth's yaw rate over the first half of the span is
within 0.05 rad/s of that over the second (the routes join straights and arcs with a step in
curvature, so a sweep across a joint sees two twists, and no one ``(v, ω)`` fits it).

Recall is split by the log's labels (``/ground_truth/point_labels``): a point on a mover is
*Doppler-invisible* where its measured radial velocity is within ``--invisible`` (0.25 m/s) of
what a static wall in its direction would give, with the lidar's true velocity (from the truth's
twist through the mount): ``|v_r + u·A x_true| < 0.25``; *visible* otherwise. Precision is over
all points.

    python bench/accuracy_cases.py --cases warehouse --seeds 0 1 2                  # 120 s each
    python bench/accuracy_cases.py --cases crowd crowd+worse-doppler dense-crowd --duration 60

Writes bench/results/accuracy_cases.md and .json (or --out DIR / --name NAME).
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))

from results_io import kiss_icp_available, write_results  # noqa: E402
from suite import CHILD_KISS, CHILD_PROCESS, _child, _row, case_config  # noqa: E402

from fmcwlog.evaluation.evaluate import evaluate  # noqa: E402
from fmcwlog.evaluation.ground_truth import read_ground_truth, read_point_labels  # noqa: E402
from fmcwlog.frontend.twist_fusion import doppler_design  # noqa: E402
from fmcwlog.io.calibration import load_calibration  # noqa: E402
from fmcwlog.io.logs import open_log  # noqa: E402
from fmcwlog.io.mcap_log import LogReader  # noqa: E402
from fmcwlog.io.messages import pointcloud_columns, stamp_ns  # noqa: E402
from fmcwlog.io.topic_choice import choose_topics  # noqa: E402
from fmcwlog.sim.recorder import record  # noqa: E402

DEFAULT_SECONDS = {"warehouse": 120.0}  # a case's log length unless --duration; others 60 s
STEADY_YAW_RATE = 0.05  # rad/s: a sweep whose two halves' true yaw rates differ less is steady
METHODS = ("improved", "improved_frontend", "baseline", "kiss_icp", "wheel_odometry")

# The improved method alone (no child of its own), each sweep's twists kept: stamp (ns), span (s),
# fused (v, ω), the Doppler fit's lidar velocity (lidar frame), the wheels' (v, ω); NaN where absent.
CHILD_IMPROVED = r"""
import json, resource, sys
import numpy as np
from fmcwlog.api import ProcessOptions, process as process_log
from fmcwlog.frontend import methods
rows = []
inner = methods.ImprovedFrontEnd.estimate_motion
def keep(self, sweep, prior):
    m = inner(self, sweep, prior)
    nan2 = (float("nan"), float("nan"))
    fused = tuple(m.fused.twist) if m.fused is not None else nan2
    dop = tuple(m.doppler.v_sensor) if m.doppler is not None and m.doppler.usable else nan2
    wheels = tuple(prior.twist) if prior.twist is not None else nan2
    rows.append((sweep.stamp_ns, prior.span, *fused, *dop, *wheels))
    return m
methods.ImprovedFrontEnd.estimate_motion = keep
process_log(sys.argv[1], sys.argv[2], ProcessOptions(methods=("improved",)))
np.save(sys.argv[3], np.array(rows, dtype=float))
print(json.dumps({"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def _truth_motion(stamps: np.ndarray, poses: np.ndarray, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """(N, 2) true ``(v, ω)`` of base_link from ``t0`` to ``t1`` (ns): the poses interpolated
    there, the displacement in the frame at ``t0`` (forward part) and the yaw change, over the span."""
    yaw = np.unwrap(poses[:, 2])

    def at(t: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(t, stamps, poses[:, 0]), np.interp(t, stamps, poses[:, 1]),
                         np.interp(t, stamps, yaw)], -1)

    a, b = at(t0.astype(float)), at(t1.astype(float))
    span = (t1 - t0) * 1e-9
    d = b[:, :2] - a[:, :2]
    forward = np.cos(a[:, 2]) * d[:, 0] + np.sin(a[:, 2]) * d[:, 1]
    return np.stack([forward / span, (b[:, 2] - a[:, 2]) / span], -1)


def twist_errors(kept: np.ndarray, log: Path, mount: np.ndarray) -> dict:
    """RMS and max |error| of ``v`` (m/s) and ``ω`` (rad/s): fused, Doppler alone, wheels alone."""
    reader = open_log(log)
    stamps, poses = read_ground_truth(reader)
    t0 = kept[:, 0]
    t1 = t0 + kept[:, 1] * 1e9
    truth = _truth_motion(stamps.astype(float), poses, t0, t1)
    mid = 0.5 * (t0 + t1)
    first, second = (_truth_motion(stamps.astype(float), poses, a, b) for a, b in ((t0, mid), (mid, t1)))
    steady = np.abs(first[:, 1] - second[:, 1]) < STEADY_YAW_RATE
    fused, dop_vs, wheels = kept[:, 2:4], kept[:, 4:6], kept[:, 6:8]
    dop = np.linalg.solve(doppler_design(mount), dop_vs.T).T  # A x = v_s
    ok = np.all(np.isfinite(np.hstack([fused, dop, wheels, truth])), axis=1) & (kept[:, 1] > 0)
    out: dict = {"sweeps": int(ok.sum()), "sweeps_total": len(kept), "steady_sweeps": int((ok & steady).sum())}
    for name, est in (("fused", fused), ("doppler", dop), ("wheels", wheels)):
        for key, sel in ((name, ok), (f"{name}_steady", ok & steady)):
            err = est[sel] - truth[sel]
            out[key] = {"v_rms": float(np.sqrt(np.mean(err[:, 0] ** 2))), "w_rms": float(np.sqrt(np.mean(err[:, 1] ** 2))),
                        "v_max": float(np.abs(err[:, 0]).max()), "w_max": float(np.abs(err[:, 1]).max()),
                        "v_mean": float(np.mean(err[:, 0])), "w_mean": float(np.mean(err[:, 1]))}
    return out


def split_recall(out_dir: Path, log: Path, mount: np.ndarray, invisible: float) -> dict:
    """Recall on Doppler-visible and -invisible mover points, precision over all (see the module doc)."""
    reader = open_log(log)
    labels = read_point_labels(reader)
    stamps, poses = read_ground_truth(reader)
    topics = choose_topics(reader, None, None, None)
    a = doppler_design(mount)
    sweeps = {}
    for m in reader.messages([topics.scan]):
        cols = pointcloud_columns(m.msg, ("x", "y", "velocity", "t"))
        sweeps[stamp_ns(m.msg.header.stamp)] = cols
    counts = {"tp_vis": 0, "fn_vis": 0, "tp_inv": 0, "fn_inv": 0, "fp": 0, "sweeps": 0}
    for msg in LogReader(out_dir / "processed.mcap").messages(["/improved/moving_labels"]):
        est = np.frombuffer(bytes(msg.msg.moving), np.uint8).astype(bool)
        ns = msg.log_time_ns
        ref, cols = labels.get(ns), sweeps.get(ns)
        if ref is None or cols is None or ref.shape != est.shape:
            continue
        ref = ref.astype(bool)
        span = max(float(np.nanmax(cols["t"])), 0.01)
        x_true = _truth_motion(stamps.astype(float), poses, np.array([float(ns)]), np.array([ns + span * 1e9]))[0]
        xy = np.stack([cols["x"], cols["y"]], -1).astype(float)
        r = np.linalg.norm(xy, axis=1)
        u = xy / np.where(r > 0, r, 1.0)[:, None]
        eps = cols["velocity"].astype(float) + u @ (a @ x_true)  # ~0 for a static point, m/s
        blind = np.abs(eps) < invisible
        counts["tp_vis"] += int(np.sum(est & ref & ~blind))
        counts["fn_vis"] += int(np.sum(~est & ref & ~blind))
        counts["tp_inv"] += int(np.sum(est & ref & blind))
        counts["fn_inv"] += int(np.sum(~est & ref & blind))
        counts["fp"] += int(np.sum(est & ~ref))
        counts["sweeps"] += 1
    c = counts
    tp = c["tp_vis"] + c["tp_inv"]
    return {**c, "recall_visible": c["tp_vis"] / max(c["tp_vis"] + c["fn_vis"], 1),
            "recall_invisible": c["tp_inv"] / max(c["tp_inv"] + c["fn_inv"], 1),
            "recall": tp / max(tp + c["fn_vis"] + c["fn_inv"], 1), "precision": tp / max(tp + c["fp"], 1),
            "invisible_share": (c["tp_inv"] + c["fn_inv"]) / max(tp + c["fn_vis"] + c["fn_inv"], 1)}


def run_case(case: str, seed: int, duration: float, tmp: Path, with_kiss: bool, invisible: float) -> dict:
    """One case and seed: the method rows (ATE etc.), the twist errors and the split recall."""
    log = tmp / f"{case}_{seed}.mcap"
    world, cfg = case_config(case, duration, seed)
    record(world, cfg, log)
    reader = open_log(log)
    topics = choose_topics(reader, None, None, None)
    mount = np.asarray(load_calibration(reader, log, topics.scan, topics.ticks is not None, None).cal.mount, float)
    rows: dict[str, dict] = {}
    out = tmp / f"{case}_{seed}_improved"
    kept_file = tmp / f"{case}_{seed}_twists.npy"
    peak = _child(CHILD_IMPROVED, str(log), str(out), str(kept_file))["peak_rss_mb"]
    result = evaluate(out, log).result
    for method in ("improved", "improved_frontend", "wheel_odometry"):
        if method in result["methods"]:
            rows[method] = _row(result, method, peak if method == "improved" else None)
    twists = twist_errors(np.load(kept_file), log, mount)
    recall = split_recall(out, log, mount, invisible)
    out_b = tmp / f"{case}_{seed}_baseline"
    _child(CHILD_PROCESS, str(log), str(out_b), "baseline")
    rows["baseline"] = _row(evaluate(out_b, log).result, "baseline", None)
    if with_kiss:
        out_k = tmp / f"{case}_{seed}_kiss"
        try:
            _child(CHILD_KISS, str(log), str(out_k), str(HERE))
            rows["kiss_icp"] = _row(evaluate(out_k, log).result, "kiss_icp", None)
        except RuntimeError as exc:
            print(f"  KISS-ICP failed on {case}/{seed}: {exc}", file=sys.stderr)
    for f in tmp.glob(f"{case}_{seed}*"):
        shutil.rmtree(f) if f.is_dir() else f.unlink()
    return {"case": case, "seed": seed, "duration_s": duration, "rows": rows, "twist": twists, "recall": recall}


def _cm(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.1f}"


def markdown(runs: list[dict], meta: dict) -> str:
    lines = [f"Accuracy cases, {meta['machine']}; {meta['wall_s']:.0f} s in all. Command: `{meta['command']}`", "",
             "ATE RMSE (cm) per seed and mean:", "",
             "| case | s | method | " + " | ".join(f"seed {s}" for s in meta["seeds"]) + " | mean | RPE 1 m % mean |",
             "|---|---|---|" + "---|" * len(meta["seeds"]) + "---|---|"]
    cases = list(dict.fromkeys(r["case"] for r in runs))
    for case in cases:
        mine = [r for r in runs if r["case"] == case]
        for method in METHODS:
            ates = [r["rows"].get(method, {}).get("ate_rmse_m") for r in mine]
            rpes = [r["rows"].get(method, {}).get("rpe_1m_pct") for r in mine]
            if all(a is None for a in ates):
                continue
            mean = float(np.mean([a for a in ates if a is not None]))
            rpe = [x for x in rpes if x is not None]
            rpe_cell = f"{np.mean(rpe):.2f}" if rpe else "—"
            lines.append(f"| {case} | {mine[0]['duration_s']:g} | {method} | " + " | ".join(_cm(a) for a in ates)
                         + f" | {_cm(mean)} | {rpe_cell} |")
    lines += ["", "Twist over each sweep against truth, RMS (max) over the sweeps with all three, mean over seeds: "
              "v in cm/s, ω in mrad/s:", "",
              "| case | sweeps | fused v | Doppler v | wheels v | fused ω | Doppler ω | wheels ω |",
              "|---|---|---|---|---|---|---|---|"]
    for case in cases:
        mine = [r["twist"] for r in runs if r["case"] == case]

        def cell(src: str, comp: str, scale: float, mine=mine) -> str:
            rms = np.mean([m[src][f"{comp}_rms"] for m in mine]) * scale
            mx = np.max([m[src][f"{comp}_max"] for m in mine]) * scale
            return f"{rms:.2f} ({mx:.1f})"

        for tail, count in (("", "sweeps"), ("_steady", "steady_sweeps")):
            sweeps = f"{sum(m[count] for m in mine)}/{sum(m['sweeps_total'] for m in mine)}"
            srcs = [f"{s}{tail}" for s in ("fused", "doppler", "wheels")]
            lines.append(f"| {case}{' steady' if tail else ''} | {sweeps} | " + " | ".join(cell(s, "v", 100) for s in srcs)
                         + " | " + " | ".join(cell(s, "w", 1000) for s in srcs) + " |")
    lines += ["", "Mean twist error (bias: what integrates into drift) over the steady sweeps, mean over seeds: "
              "v in cm/s, ω in mrad/s:", "",
              "| case | fused v | Doppler v | wheels v | fused ω | Doppler ω | wheels ω |", "|---|---|---|---|---|---|---|"]
    for case in cases:
        mine = [r["twist"] for r in runs if r["case"] == case]
        srcs = [f"{s}_steady" for s in ("fused", "doppler", "wheels")]
        lines.append(f"| {case} | " + " | ".join(f"{100 * np.mean([m[s]['v_mean'] for m in mine]):+.3f}" for s in srcs)
                     + " | " + " | ".join(f"{1000 * np.mean([m[s]['w_mean'] for m in mine]):+.2f}" for s in srcs) + " |")
    lines += ["", f"Moving-point recall split by Doppler visibility (invisible: |ε_true| < {meta['invisible']} m/s), "
              "per seed:", "",
              "| case | seed | mover points invisible % | recall visible | recall invisible | recall | precision |",
              "|---|---|---|---|---|---|---|"]
    for r in runs:
        c = r["recall"]
        lines.append(f"| {r['case']} | {r['seed']} | {100 * c['invisible_share']:.1f} | {c['recall_visible']:.4f} | "
                     f"{c['recall_invisible']:.4f} | {c['recall']:.4f} | {c['precision']:.4f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", nargs="+", default=["warehouse", "crowd", "crowd+worse-doppler", "dense-crowd"])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--duration", type=float, default=None, help="seconds per log (default: 120 warehouse, 60 others)")
    ap.add_argument("--invisible", type=float, default=0.25, help="m/s: a mover point this close to static is invisible")
    ap.add_argument("--no-kiss", action="store_true")
    ap.add_argument("--out", type=Path, default=HERE / "results")
    ap.add_argument("--name", default="accuracy_cases")
    args = ap.parse_args()
    with_kiss = kiss_icp_available(not args.no_kiss)
    started = time.perf_counter()
    runs = []
    with tempfile.TemporaryDirectory() as tmp_name:
        for case in args.cases:
            duration = args.duration or DEFAULT_SECONDS.get(case.partition("+")[0], 60.0)
            for seed in args.seeds:
                t0 = time.perf_counter()
                run = run_case(case, seed, duration, Path(tmp_name), with_kiss, args.invisible)
                runs.append(run)
                ate = {m: _cm(r.get("ate_rmse_m")) for m, r in run["rows"].items()}
                print(f"{case} seed {seed} ({duration:g} s): ATE cm {ate}; recall invisible "
                      f"{run['recall']['recall_invisible']:.4f} ({time.perf_counter() - t0:.0f} s)", flush=True)
    meta = {"cases": args.cases, "seeds": args.seeds, "invisible": args.invisible, "kiss_icp": with_kiss,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
            "wall_s": time.perf_counter() - started, "command": "python " + " ".join(sys.argv)}
    write_results(args.out, args.name, markdown(runs, meta), {"meta": meta, "runs": runs})


if __name__ == "__main__":
    main()
