"""``fmcwlog report``'s numbers: a ``process`` output folder measured against its log's ground truth.

Everything here is evaluation: it reads ``/ground_truth/*`` and ``fmcwlog.world``
(through :mod:`fmcwlog.evaluation.ground_truth`), which estimation never does. A
value that cannot be computed is ``None`` with the reason in ``notes``; nothing
is invented. Feature lengths: :mod:`fmcwlog.evaluation.features`; moving-point
scores: :mod:`fmcwlog.evaluation.segmentation_score`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..errors import LogError, ReportError
from ..frontend.methods import METHOD_NAMES, METHODS, WHEEL_ODOMETRY, BaselineFrontEnd, ImprovedFrontEnd
from ..io.digest import file_sha256
from ..io.mcap_log import LogReader
from ..io.outputs import read_tum
from ..io.topics import GT_LABELS_TOPIC, GT_ODOM_TOPIC, WORLD_KEY
from .features import feature_lengths
from .ground_truth import read_ground_truth, read_point_labels, read_world
from .metrics import (
    ate,
    feature_length_errors,
    interpolate_reference,
    mean_relative_error_pct,
    relative_reduction_pct,
    rpe,
)
from .published import PAPER, relations_for
from .relations import read_relations, relations_error
from .segmentation_score import segmentation_scores

TRAJECTORIES = (*METHOD_NAMES, WHEEL_ODOMETRY)  # fmcwlog's own, in the order the report shows them
_METRIC_KEYS = ("ate_rmse_m", "ate_mean_m", "ate_median_m", "ate_max_m", "ate_first_aligned_rmse_m", "rpe_1m_pct",
                "rpe_10m_pct", "rpe_1m_deg_per_m", "rpe_10m_deg_per_m", "features", "feature_avg_rel_error_pct",
                "segmentation", "ms_per_sweep_median", "ms_per_sweep_p95", "sweeps_per_second")


@dataclass
class Evaluation:
    out_dir: Path
    log: Path
    run: dict[str, Any]
    result: dict[str, Any] = field(default_factory=dict)
    # for the plots
    gt_ns: np.ndarray | None = None  # ground-truth stamps (ns) and poses (N, 3) of base_link in map
    gt_t: np.ndarray | None = None
    gt: np.ndarray | None = None
    aligned: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)  # t, est, errors
    walls: np.ndarray | None = None  # (M, 4) the world's walls, for the plots


# what report reads of run.json, and the type each must have when present (peers write their own run.json)
_RUN_KEYS: dict[str, tuple[type, ...]] = {"log": (str,), "scan_topic": (str,), "stamp_shift_s": (int, float),
                                          "sweeps": (int,), "log_sha256": (str,), "params": (dict,),
                                          "doppler": (bool, type(None)), "prior": (str, type(None))}
_PARQUET_COLUMNS = {"method": pa.types.is_string, "stamp_ns": pa.types.is_integer, "ms": pa.types.is_floating}


def load_run(out_dir: Path) -> dict[str, Any]:
    """``out_dir``'s run.json, once it and trajectories.parquet are checked to be readable and whole."""
    run_json = out_dir / "run.json"
    if not out_dir.is_dir():
        raise ReportError(f"{out_dir}: no such folder")
    if not run_json.is_file() or not (out_dir / "trajectories.parquet").is_file():
        raise ReportError(f"{out_dir}: not a 'fmcwlog process' output (no run.json or trajectories.parquet)")
    try:
        run = json.loads(run_json.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ReportError(f"{run_json}: malformed ({exc.msg})") from None
    except (UnicodeDecodeError, RecursionError):
        raise ReportError(f"{run_json}: malformed (not UTF-8 JSON text)") from None
    except OSError as exc:
        raise ReportError(f"{run_json}: cannot read ({exc.strerror})") from None
    if not isinstance(run, dict):
        raise ReportError(f"{run_json}: malformed (expected a JSON object)")
    for key, kinds in _RUN_KEYS.items():
        value = run.get(key)
        if key in run and (not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds)
                           or (isinstance(value, float) and not np.isfinite(value))):
            raise ReportError(f"{run_json}: {key!r} is {value!r}, not a {' or '.join(k.__name__ for k in kinds)}")
    if isinstance(run.get("sweeps"), int) and run["sweeps"] < 0:
        raise ReportError(f"{run_json}: 'sweeps' is negative")
    if abs(run.get("stamp_shift_s", 0.0)) > 3600.0:  # a shift within a sweep's period, not hours
        raise ReportError(f"{run_json}: 'stamp_shift_s' of {run['stamp_shift_s']} s is beyond an hour")
    _check_parquet(out_dir / "trajectories.parquet")
    return run


def _check_parquet(path: Path) -> None:
    """A trajectories.parquet that can be read whole, with the columns report needs."""
    try:
        table = pq.read_table(path)
    except (pa.ArrowException, OSError, ValueError) as exc:
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise ReportError(f"{path}: damaged, cannot be read ({first})") from None
    for name, is_kind in _PARQUET_COLUMNS.items():
        if name not in table.column_names:
            raise ReportError(f"{path}: has no column {name!r}")
        if not is_kind(table.schema.field(name).type):
            raise ReportError(f"{path}: column {name!r} is {table.schema.field(name).type}, not what fmcwlog writes")
    if table.column("stamp_ns").null_count or table.column("method").null_count:
        raise ReportError(f"{path}: a row has no stamp_ns or method")


def _check_log_matches(out_dir: Path, log: Path, reader: LogReader, run: dict, stamps: np.ndarray) -> None:
    """Refuse a log other than the one ``out_dir`` was processed from: by its sha256 where run.json
    records it (another run, scenario or seed can share every stamp), else by its sweep stamps."""
    recorded = run.get("log_sha256")
    if recorded is not None:
        try:
            digest = file_sha256(log)
        except OSError as exc:
            raise ReportError(f"{log}: cannot read ({exc.strerror})") from None
        if digest != recorded:
            raise ReportError(f"{log}: is not the log {out_dir} was processed from ({run.get('log', 'see run.json')}): "
                              f"their sha256 differ ({digest[:12]}... here, {recorded[:12]}... in run.json)")
    scan = run.get("scan_topic", "/fmcw/points")
    log_stamps = np.fromiter(reader.log_times(scan), dtype=np.int64)
    # a peer may stamp its poses later than the sweep (KISS-ICP: mid-sweep); run.json says by how much
    stamps = np.asarray(stamps, dtype=np.int64) - int(round(float(run.get("stamp_shift_s", 0.0)) * 1e9))
    if log_stamps.size == 0 or not np.all(np.isin(stamps, log_stamps)):
        raise ReportError(f"{log}: does not belong to {out_dir} (its {scan} stamps differ from the processed sweeps)")


def evaluate(out_dir: str | Path, log: str | Path | None = None, end_radius: float = 0.15,
             relations: str | Path | None = None) -> Evaluation:
    """Measure the trajectories and maps in ``out_dir`` against the ground truth of ``log``
    (default: the log ``run.json`` names); ``relations``: a Freiburg relations file."""
    out_dir = Path(out_dir)
    run = load_run(out_dir)
    log, reader = _open_log(out_dir, run, log)
    sweep_method, sweep_ms = _sweep_times(out_dir, log, reader, run)

    ev = Evaluation(out_dir, log, run)
    notes: list[str] = []
    gt_ns, gt = _ground_truth(reader, log, ev, notes)
    world = read_world(reader)
    ev.walls = world.walls
    if ev.gt is not None and not world.features:
        notes.append(f"{log} has no {WORLD_KEY} features: map feature lengths cannot be computed")
    rel_table = read_relations(relations) if relations is not None else None
    present = _trajectories_in(out_dir)
    measurable = ev.gt is not None and bool(world.features)
    feature_rows = feature_lengths(out_dir, [m for m in present if m in METHODS], world.features, gt_ns, gt,
                                   end_radius) if measurable else {}
    labels = read_point_labels(reader) if GT_LABELS_TOPIC in reader.topics else None

    methods: dict[str, dict[str, Any]] = {}
    for m in present:
        r: dict[str, Any] = {k: None for k in _METRIC_KEYS}
        r["notes"] = []
        t, est = read_tum(out_dir / f"{m}.tum")
        if rel_table is not None and relations is not None:
            _relations(r, t, est, rel_table, relations)
        _trajectory_errors(r, m, t, est, ev)
        _features(r, m, feature_rows, measurable)
        _segmentation(r, m, out_dir, labels)
        _speed(r, m, sweep_ms[sweep_method == m])
        methods[m] = r

    reduction = _reduction(methods)
    if reduction is None and measurable and {ImprovedFrontEnd.name, BaselineFrontEnd.name} <= set(methods):
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
        "paper": dict(PAPER),
        "relations_file": str(relations) if relations is not None else None,
        "relations_published": _published_relations(relations),
        "params": run.get("params"),
        "notes": notes,
    }
    return ev


def _open_log(out_dir: Path, run: dict, log: str | Path | None) -> tuple[Path, LogReader]:
    """The log the folder was processed from: ``log`` if given, else the one run.json names."""
    named = log if log is not None else run.get("log")
    if named is None or not str(named).strip():
        raise ReportError(f"{out_dir}: its run.json names no log; name it with --log")
    path = Path(named)
    if not path.is_file():
        raise ReportError(f"{out_dir}: its log {path} is not there; name it with --log")
    try:
        return path, LogReader(path)
    except LogError as exc:
        raise ReportError(str(exc)) from None


def _sweep_times(out_dir: Path, log: Path, reader: LogReader, run: dict) -> tuple[np.ndarray, np.ndarray]:
    """Method and ms of every row of trajectories.parquet, once its stamps are checked against the log."""
    table = pq.read_table(out_dir / "trajectories.parquet", columns=["method", "stamp_ns", "ms"])
    _check_log_matches(out_dir, log, reader, run, np.unique(table.column("stamp_ns").to_numpy()))
    return table.column("method").to_numpy(zero_copy_only=False), table.column("ms").to_numpy()


def _published_relations(relations: str | Path | None) -> list[dict]:
    rows = relations_for(relations) if relations is not None else []
    return [{"method": n, "trans_mean_m": a, "trans_std_m": b} for n, a, b in rows]


def _trajectories_in(out_dir: Path) -> list[str]:
    """fmcwlog's trajectories first, then any other dropped in the folder (a peer, e.g. kiss_icp.tum)."""
    present = [m for m in TRAJECTORIES if (out_dir / f"{m}.tum").is_file()]
    return present + sorted(p.stem for p in out_dir.glob("*.tum") if p.stem not in TRAJECTORIES)


def _ground_truth(reader: LogReader, log: Path, ev: Evaluation, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """The log's ground-truth stamps (ns) and poses; set on ``ev`` when there are at least two."""
    if GT_ODOM_TOPIC in reader.topics:
        gt_ns, gt = read_ground_truth(reader)
    else:
        gt_ns, gt = np.zeros(0, np.int64), np.zeros((0, 3))
    if len(gt_ns) >= 2:
        ev.gt_ns, ev.gt_t, ev.gt = gt_ns, gt_ns * 1e-9, gt
    else:
        notes.append(f"{log} has no {GT_ODOM_TOPIC}: trajectory errors and feature lengths cannot be computed")
    return gt_ns, gt


def _relations(r: dict, t: np.ndarray, est: np.ndarray, table: np.ndarray, relations: str | Path) -> None:
    rr = relations_error(t, est, table)
    r["relations"] = rr.as_dict()
    if rr.n == 0:
        r["notes"].append(f"no relation of {relations} falls within this trajectory's time span")


def _trajectory_errors(r: dict, method: str, t: np.ndarray, est: np.ndarray, ev: Evaluation) -> None:
    """ATE (SE(2)- and first-pose-aligned) and RPE over 1 m and 10 m, as evo defines them."""
    if ev.gt_t is None or ev.gt is None or len(t) < 2:
        return
    idx, ref = interpolate_reference(t, ev.gt_t, ev.gt)
    a = ate(est[idx], ref, "se2")
    f = ate(est[idx], ref, "first")
    r.update(ate_rmse_m=a.rmse, ate_mean_m=a.mean, ate_median_m=a.median, ate_max_m=a.max,
             ate_first_aligned_rmse_m=f.rmse)
    ev.aligned[method] = (t[idx], a.est_aligned, a.errors)
    for delta, key in ((1.0, "1m"), (10.0, "10m")):
        try:
            e = rpe(est[idx], ref, delta)
            r[f"rpe_{key}_pct"] = e.trans_pct.mean
            r[f"rpe_{key}_deg_per_m"] = e.rot_deg_per_m.mean
        except ValueError as exc:
            r["notes"].append(f"RPE over {delta:g} m: {exc}")


def _features(r: dict, method: str, feature_rows: dict[str, list[dict]], measurable: bool) -> None:
    if method == WHEEL_ODOMETRY:
        r["notes"].append("wheel odometry builds no map: no feature lengths")
        return
    if method not in feature_rows:
        if measurable:
            r["notes"].append("no map points of this method in processed.mcap: no feature lengths")
        return
    rows = feature_rows[method]
    seen = [row for row in rows if row["measured_m"] is not None]
    errs = dict(zip([row["id"] for row in seen],
                    feature_length_errors(np.array([row["true_m"] for row in seen]),
                                          np.array([row["measured_m"] for row in seen]))))
    r["features"] = [{"id": row["id"], "name": row["name"], "true_m": row["true_m"], "measured_m": row["measured_m"],
                      "abs_error_m": errs[row["id"]].abs_error_m if row["id"] in errs else None,
                      "rel_error_pct": errs[row["id"]].rel_error_pct if row["id"] in errs else None}
                     for row in rows]
    if seen:
        r["feature_avg_rel_error_pct"] = mean_relative_error_pct(list(errs.values()))
    missing = [str(row["id"]) for row in rows if row["measured_m"] is None]
    if missing:
        r["notes"].append(f"features {', '.join(missing)} were not seen at both ends (the log does not "
                          f"pass them): the average is over the other {len(seen)}")


def _segmentation(r: dict, method: str, out_dir: Path, labels: dict[int, np.ndarray] | None) -> None:
    if method in METHODS and METHODS[method].segments:
        r["segmentation"] = segmentation_scores(out_dir, method, labels, r["notes"])
    elif method != WHEEL_ODOMETRY:
        r["notes"].append(f"{method} does not segment moving points")


def _speed(r: dict, method: str, ms: np.ndarray) -> None:
    ms = ms[np.isfinite(ms)]  # the motion prior's rows carry no time
    if len(ms):
        r["ms_per_sweep_median"] = float(np.median(ms))
        r["ms_per_sweep_p95"] = float(np.percentile(ms, 95))
        r["sweeps_per_second"] = float(1000.0 / np.mean(ms))
    elif method == WHEEL_ODOMETRY:
        r["notes"].append("wheel odometry is the motion prior itself; its time is not measured per sweep")


def _reduction(methods: dict[str, dict[str, Any]]) -> float | None:
    """% by which the improved method cuts the baseline's average relative feature error,
    over the features both measured."""
    imp = (methods.get(ImprovedFrontEnd.name) or {}).get("features") or []
    base = (methods.get(BaselineFrontEnd.name) or {}).get("features") or []
    pairs = [(a["rel_error_pct"], b["rel_error_pct"]) for a, b in zip(imp, base)
             if a["rel_error_pct"] is not None and b["rel_error_pct"] is not None]
    if not pairs:
        return None
    mi, mb = np.mean([p[0] for p in pairs]), np.mean([p[1] for p in pairs])
    return float(relative_reduction_pct(mb, mi)) if mb > 0 else None
