"""``fmcwlog report``'s numbers: a ``process`` output folder measured against its log's ground truth.

Everything here is evaluation: it reads ``/ground_truth/*`` and ``fmcwlog.world``,
which estimation never does. A value that cannot be computed is ``None`` with
the reason in ``notes``; nothing is invented.

Feature lengths (the paper's Tables 2 and 3) are measured in the map each
method built, from the points it kept: every static point the method placed
in its map (``/<method>/points/static`` in ``processed.mcap``, already placed
with that method's poses) is also placed with the ground-truth pose of its
sweep; the points that land within ``end_radius`` of a feature's end in the
true world are "the points that saw that end". A feature's measured length is
the distance between the means of its two ends' points as the method placed
them, corrected by the same distance with the ground-truth placement (which
removes the few-centimetre offset of averaging points near a corner, the same
for every method):

    measured = true + |m_b(est) − m_a(est)| − |m_b(gt) − m_a(gt)|

so a method with perfect poses measures every feature at its true length, and
a drifting or sliding one stretches or shrinks the map between the ends.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

from .geometry import interpolate_poses, inverse, transform_points
from .mcap_io import (
    GT_LABELS_TOPIC,
    GT_ODOM_TOPIC,
    WORLD_KEY,
    LogError,
    LogReader,
    odometry_pose_twist,
    pointcloud_columns,
    read_ground_truth,
    read_point_labels,
    stamp_ns,
)
from .metrics import ate, feature_length_errors, interpolate_reference, mean_relative_error_pct, rpe
from .outputs import read_tum
from .relations import RelationsError, published_for, read_relations, relations_error

METHODS = ("improved", "baseline", "wheel_odometry")


class ReportError(Exception):
    """An output folder or log cannot be evaluated; the message says which and why."""


@dataclass
class Evaluation:
    out_dir: Path
    log: Path
    run: dict[str, Any]
    result: dict[str, Any] = field(default_factory=dict)
    # for the plots
    gt_t: np.ndarray | None = None
    gt: np.ndarray | None = None
    aligned: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)  # t, est, errors
    walls: np.ndarray | None = None  # (M, 4) the world's walls, for the plots


def load_run(out_dir: Path) -> dict[str, Any]:
    run_json = out_dir / "run.json"
    if not out_dir.is_dir():
        raise ReportError(f"{out_dir}: no such folder")
    if not run_json.is_file() or not (out_dir / "trajectories.parquet").is_file():
        raise ReportError(f"{out_dir}: not a 'fmcwlog process' output (no run.json or trajectories.parquet)")
    try:
        return json.loads(run_json.read_text())
    except json.JSONDecodeError as exc:
        raise ReportError(f"{run_json}: malformed ({exc.msg})") from None


def _check_log_matches(out_dir: Path, log: Path, reader: LogReader, run: dict, stamps: np.ndarray) -> None:
    scan = run.get("scan_topic", "/fmcw/points")
    log_stamps = np.fromiter(reader.log_times(scan), dtype=np.int64)
    # a peer may stamp its poses later than the sweep (KISS-ICP: mid-sweep); run.json says by how much
    stamps = np.asarray(stamps, dtype=np.int64) - int(round(float(run.get("stamp_shift_s", 0.0)) * 1e9))
    if log_stamps.size == 0 or not np.all(np.isin(stamps, log_stamps)):
        raise ReportError(f"{log}: does not belong to {out_dir} (its {scan} stamps differ from the processed sweeps)")


def evaluate(out_dir: str | Path, log: str | Path | None = None, end_radius: float = 0.15,
             relations: str | Path | None = None) -> Evaluation:
    out_dir = Path(out_dir)
    run = load_run(out_dir)
    log = Path(log) if log is not None else Path(run.get("log", ""))
    if not log.is_file():
        raise ReportError(f"{out_dir}: its log {log} is not there; name it with --log")
    try:
        reader = LogReader(log)
    except LogError as exc:
        raise ReportError(str(exc)) from None
    table = pq.read_table(out_dir / "trajectories.parquet", columns=["method", "stamp_ns", "ms"])
    sweep_method = table.column("method").to_numpy(zero_copy_only=False)
    sweep_ms = table.column("ms").to_numpy()
    ev = Evaluation(out_dir, log, run)
    notes: list[str] = []
    _check_log_matches(out_dir, log, reader, run, np.unique(table.column("stamp_ns").to_numpy()))

    gt_ns, gt = (read_ground_truth(reader) if GT_ODOM_TOPIC in reader.topics else (np.zeros(0, np.int64), np.zeros((0, 3))))
    has_gt = len(gt_ns) >= 2
    if not has_gt:
        notes.append(f"{log} has no {GT_ODOM_TOPIC}: trajectory errors and feature lengths cannot be computed")
    else:
        ev.gt_t, ev.gt = gt_ns * 1e-9, gt
    world = reader.metadata.get(WORLD_KEY)
    features = json.loads(world["features"]) if world and "features" in world else []
    if world and "walls" in world:
        ev.walls = np.asarray(json.loads(world["walls"]), dtype=float).reshape(-1, 4)
    if has_gt and not features:
        notes.append(f"{log} has no {WORLD_KEY} features: map feature lengths cannot be computed")

    methods: dict[str, dict[str, Any]] = {}
    rel_table = None
    if relations is not None:
        try:
            rel_table = read_relations(relations)
        except RelationsError as exc:
            raise ReportError(str(exc)) from None
    # fmcwlog's methods first, then any other trajectory dropped in the folder (a peer, e.g. kiss_icp.tum)
    present = [m for m in METHODS if (out_dir / f"{m}.tum").is_file()]
    present += sorted(p.stem for p in out_dir.glob("*.tum") if p.stem not in METHODS)
    feature_sums = _feature_points(out_dir, [m for m in present if m in ("improved", "baseline")], features, gt_ns,
                                   gt, end_radius) if (has_gt and features) else {}
    labels = read_point_labels(reader) if GT_LABELS_TOPIC in reader.topics else None
    for m in present:
        r: dict[str, Any] = {k: None for k in ("ate_rmse_m", "ate_mean_m", "ate_median_m", "ate_max_m",
                                               "ate_first_aligned_rmse_m", "rpe_1m_pct", "rpe_10m_pct",
                                               "rpe_1m_deg_per_m", "rpe_10m_deg_per_m", "features",
                                               "feature_avg_rel_error_pct", "segmentation",
                                               "ms_per_sweep_median", "ms_per_sweep_p95", "sweeps_per_second")}
        r["notes"] = []
        t, est = read_tum(out_dir / f"{m}.tum")
        if rel_table is not None:
            rr = relations_error(t, est, rel_table)
            r["relations"] = rr.as_dict()
            if rr.n == 0:
                r["notes"].append(f"no relation of {relations} falls within this trajectory's time span")
        if has_gt and len(t) >= 2:
            idx, ref = interpolate_reference(t, ev.gt_t, gt)
            a = ate(est[idx], ref, "se2")
            f = ate(est[idx], ref, "first")
            r.update(ate_rmse_m=a.rmse, ate_mean_m=a.mean, ate_median_m=a.median, ate_max_m=a.max,
                     ate_first_aligned_rmse_m=f.rmse)
            ev.aligned[m] = (t[idx], a.est_aligned, a.errors)
            for delta, key in ((1.0, "1m"), (10.0, "10m")):
                try:
                    e = rpe(est[idx], ref, delta)
                    r[f"rpe_{key}_pct"] = e.trans_pct.mean
                    r[f"rpe_{key}_deg_per_m"] = e.rot_deg_per_m.mean
                except ValueError as exc:
                    r["notes"].append(f"RPE over {delta:g} m: {exc}")
        if m == "wheel_odometry":
            r["notes"].append("wheel odometry builds no map: no feature lengths")
        elif m not in feature_sums:
            if has_gt and features:
                r["notes"].append("no map points of this method in processed.mcap: no feature lengths")
        else:
            rows = feature_sums[m]
            seen = [row for row in rows if row["measured_m"] is not None]
            errs = dict(zip([row["id"] for row in seen],
                            feature_length_errors([row["true_m"] for row in seen], [row["measured_m"] for row in seen])))
            r["features"] = [{"id": row["id"], "name": row["name"], "true_m": row["true_m"],
                              "measured_m": row["measured_m"],
                              "abs_error_m": errs[row["id"]].abs_error_m if row["id"] in errs else None,
                              "rel_error_pct": errs[row["id"]].rel_error_pct if row["id"] in errs else None}
                             for row in rows]
            if seen:
                r["feature_avg_rel_error_pct"] = mean_relative_error_pct(list(errs.values()))
            missing = [str(row["id"]) for row in rows if row["measured_m"] is None]
            if missing:
                r["notes"].append(f"features {', '.join(missing)} were not seen at both ends (the log does not "
                                  f"pass them): the average is over the other {len(seen)}")
        if m == "improved":
            r["segmentation"] = _segmentation(out_dir, labels, r["notes"])
        elif m != "wheel_odometry":
            r["notes"].append(f"{m} does not segment moving points")
        d = sweep_ms[sweep_method == m]
        if len(d):
            r["ms_per_sweep_median"] = float(np.median(d))
            r["ms_per_sweep_p95"] = float(np.percentile(d, 95))
            r["sweeps_per_second"] = float(1000.0 / np.mean(d))
        elif m == "wheel_odometry":
            r["notes"].append("wheel odometry is the motion prior itself; its time is not measured per sweep")
        methods[m] = r

    reduction = _reduction(methods)
    if reduction is None and "improved" in methods and "baseline" in methods and has_gt and features:
        notes.append("no reduction of the average feature error: no feature was measured by both methods")
    ev.result = {
        "schema": "fmcwlog.report/1",
        "out_dir": str(out_dir),
        "log": str(log),
        "sweeps": int(run.get("sweeps", 0)),
        "doppler": run.get("doppler"),
        "prior": run.get("prior"),
        "methods": methods,
        "feature_avg_rel_error_reduction_pct": reduction,
        "paper": {"baseline_avg_rel_error_pct": 6.0505, "improved_avg_rel_error_pct": 3.5919, "reduction_pct": 40.6},
        "relations_file": str(relations) if relations is not None else None,
        "relations_published": [{"method": n, "trans_mean_m": a, "trans_std_m": b} for n, a, b in
                                (published_for(relations) if relations is not None else [])],
        "params": run.get("params"),
        "notes": notes,
    }
    return ev


def _reduction(methods: dict[str, dict[str, Any]]) -> float | None:
    """% by which the improved method cuts the baseline's average relative feature error,
    over the features both measured."""
    imp = (methods.get("improved") or {}).get("features") or []
    base = (methods.get("baseline") or {}).get("features") or []
    pairs = [(a["rel_error_pct"], b["rel_error_pct"]) for a, b in zip(imp, base)
             if a["rel_error_pct"] is not None and b["rel_error_pct"] is not None]
    if not pairs:
        return None
    mi, mb = np.mean([p[0] for p in pairs]), np.mean([p[1] for p in pairs])
    return float(100.0 * (mb - mi) / mb) if mb > 0 else None


def _feature_points(out_dir: Path, methods: list[str], features: list[dict], gt_ns: np.ndarray, gt: np.ndarray,
                    radius: float) -> dict[str, list[dict]]:
    """Per method and feature, the measured length from the points that saw its ends (module docstring)."""
    ends = np.array([[f["a"], f["b"]] for f in features], dtype=float).reshape(-1, 2)  # (2F, 2): a0, b0, a1, ...
    proc = out_dir / "processed.mcap"
    if not proc.is_file():
        return {}
    reader = LogReader(proc)
    poses: dict[str, dict[int, np.ndarray]] = {m: {} for m in methods}
    sums = {m: {"est": np.zeros((len(ends), 2)), "gt": np.zeros((len(ends), 2)), "n": np.zeros(len(ends))} for m in methods}
    topics = [f"/{m}/odom" for m in methods] + [f"/{m}/points/static" for m in methods]
    gt_t = gt_ns * 1e-9
    for msg in reader.messages(topics):
        method = msg.topic.split("/")[1]
        ns = stamp_ns(msg.msg.header.stamp)
        if msg.topic.endswith("/odom"):
            poses[method][ns] = odometry_pose_twist(msg.msg)[0]
            continue
        pose = poses[method].get(ns)
        if pose is None:
            continue
        cols = pointcloud_columns(msg.msg, ("x", "y"))
        est = np.column_stack([cols["x"], cols["y"]])
        if len(est) == 0:
            continue
        base = transform_points(inverse(pose), est)
        true_pose = interpolate_poses(np.array(ns * 1e-9), gt_t, gt)
        in_world = transform_points(true_pose, base)
        d = np.linalg.norm(in_world[:, None, :] - ends[None, :, :], axis=2)  # (N, 2F)
        near = d < radius
        s = sums[method]
        s["n"] += near.sum(axis=0)
        s["est"] += near.T.astype(float) @ est
        s["gt"] += near.T.astype(float) @ in_world
        poses[method].pop(ns, None)
    out: dict[str, list[dict]] = {}
    for m in methods:
        s = sums[m]
        rows = []
        for i, f in enumerate(features):
            a, b = 2 * i, 2 * i + 1
            true = float(np.hypot(*(np.subtract(f["b"], f["a"]))))
            if s["n"][a] == 0 or s["n"][b] == 0:
                measured = None
            else:
                mean_est = s["est"][[a, b]] / s["n"][[a, b], None]
                mean_gt = s["gt"][[a, b]] / s["n"][[a, b], None]
                measured = true + float(np.linalg.norm(mean_est[1] - mean_est[0]) - np.linalg.norm(mean_gt[1] - mean_gt[0]))
            rows.append({"id": f.get("id", i + 1), "name": f.get("name", ""), "true_m": true, "measured_m": measured,
                         "points_a": int(s["n"][a]), "points_b": int(s["n"][b])})
        out[m] = rows
    return out


def _segmentation(out_dir: Path, labels: dict[int, np.ndarray] | None, notes: list[str]) -> dict[str, float] | None:
    if labels is None:
        notes.append("the log has no /ground_truth/point_labels: segmentation cannot be scored")
        return None
    proc = out_dir / "processed.mcap"
    tp = fp = fn = 0
    seen = 0
    for msg in LogReader(proc).messages(["/improved/moving_labels"]):
        est = np.frombuffer(bytes(msg.msg.moving), np.uint8).astype(bool)
        ref = labels.get(msg.log_time_ns)
        if ref is None or ref.shape != est.shape:
            continue
        ref = ref.astype(bool)
        tp += int(np.sum(est & ref))
        fp += int(np.sum(est & ~ref))
        fn += int(np.sum(~est & ref))
        seen += 1
    if seen == 0:
        notes.append("no per-point moving verdicts in processed.mcap (Doppler was off): segmentation not scored")
        return None
    precision = tp / (tp + fp) if tp + fp else None
    recall = tp / (tp + fn) if tp + fn else None
    f1 = 2 * precision * recall / (precision + recall) if precision and recall else None
    if tp + fn == 0:
        notes.append("no point of the log hit a mover: recall is undefined")
    return {"precision": precision, "recall": recall, "f1": f1, "true_positives": tp, "false_positives": fp,
            "false_negatives": fn}
