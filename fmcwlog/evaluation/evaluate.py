"""``fmcwlog report``'s numbers: a ``process`` output folder measured against its log's ground truth.

Everything here is evaluation: it reads ``/ground_truth/*`` and ``fmcwlog.world``
(through :mod:`fmcwlog.evaluation.ground_truth`), which estimation never does. A
value that cannot be computed is ``None`` with the reason in ``notes``; nothing
is invented. Feature lengths: :mod:`fmcwlog.evaluation.features`; moving-point
scores: :mod:`fmcwlog.evaluation.segmentation_score`; per-pose and per-pair series for the
plots and the methods' disagreement (which needs no ground truth):
:mod:`fmcwlog.evaluation.along_path`.

``report.json`` (schema ``fmcwlog.report/1``; SI units: m, s, rad unless a key says
``_pct``, ``_deg``, ``_cm`` or ``ms``):

- ``header``: versions, date, log, scenario, seed, the parameters' digest;
- ``wall_seconds`` and ``wall_sweeps_per_second``: the whole run's wall-clock time (run.json's) and
  sweeps per second of it, as ``process`` printed them;
- ``methods.<name>``: ``ate_*_m`` (rmse, mean, median, std, min, max: evo_ape's statistics,
  SE(2)-aligned, evo's ``-a``; ``ate_first_aligned_rmse_m`` aligned at the first pose),
  ``rpe_{1,10}m_pct`` and ``rpe_{1,10}m_deg_per_m``, ``features``
  (each feature's length in the method's map, or why it is not measurable) and
  ``feature_avg_rel_error_pct``, ``segmentation`` (precision, recall, F1, counts),
  ``ms_per_sweep_*``, ``heading_*_deg``, and ``notes`` for what could not be computed;
- ``feature_avg_rel_error_reduction_pct`` (improved against baseline, over the features both
  measured) and ``feature_comparison`` (those features' count and each method's average over
  them), and ``paper`` (its figures);
- ``relations_*``: the benchmark relations metric where a relations file was given;
- ``motion_sources`` and ``calibration_check``: run.json's, as processing found them;
- ``disagreement``: how far the methods' trajectories differ (needs no ground truth);
- ``params``: the parameters processing used; ``notes``: the report's own remarks.
"""

from __future__ import annotations

import datetime
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .. import __version__
from ..errors import LogError, ReportError
from ..io.digest import log_sha256
from ..io.logs import Log, open_log
from ..io.messages import stamp_ns
from ..io.outputs import read_tum
from ..io.topics import GT_LABELS_TOPIC, GT_ODOM_TOPIC, SIM_KEY, WORLD_KEY
from ..types import BASELINE, IMPROVED, METHOD_NAMES, SEGMENTING_METHODS, WHEEL_ODOMETRY
from .along_path import Disagreement, RPESeries, disagreement, heading_errors, rpe_series
from .features import feature_lengths
from .ground_truth import read_ground_truth, read_point_labels, read_world
from .metrics import (
    ate,
    feature_length_errors,
    interpolate_reference,
    mean_relative_error_pct,
    relative_reduction_pct,
)
from .published import PAPER, relations_for
from .relations import read_relations, relations_error
from .segmentation_score import segmentation_scores

# fmcwlog's own, in the order the report shows them: the front ends alone (written with a back end) last
TRAJECTORIES = (*METHOD_NAMES, WHEEL_ODOMETRY, *(f"{m}_frontend" for m in METHOD_NAMES))
GROUND_TRUTH_TUM = "gt.tum"  # written by the report beside the estimates; never an estimate itself
RPE_DELTAS_M = (1.0, 10.0)
_METRIC_KEYS = ("ate_rmse_m", "ate_mean_m", "ate_median_m", "ate_std_m", "ate_min_m", "ate_max_m",
                "ate_first_aligned_rmse_m", "rpe_1m_pct",
                "rpe_10m_pct", "rpe_1m_deg_per_m", "rpe_10m_deg_per_m", "features", "feature_avg_rel_error_pct",
                "segmentation", "ms_per_sweep_median", "ms_per_sweep_p95", "sweeps_per_second",
                "heading_rmse_deg", "heading_max_deg", "ms_per_sweep_mean", "ms_per_sweep_max")


@dataclass
class Evaluation:
    """What :func:`evaluate` found: ``result`` (the report's numbers, ``report.json``; module
    docstring) and, for the plots, the ground truth and each method's aligned trajectory, heading
    errors (deg), RPE series, per-sweep times (ms) and disagreements, in the units their comments give."""

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
    heading: dict[str, np.ndarray] = field(default_factory=dict)  # signed heading error (deg) at aligned[m]'s t
    rpe: dict[str, list[RPESeries]] = field(default_factory=dict)  # per pair, one series per RPE_DELTAS_M
    sweep_ms: dict[str, np.ndarray] = field(default_factory=dict)  # time per sweep (ms), every timed sweep
    disagreements: dict[str, Disagreement] = field(default_factory=dict)  # each other trajectory vs the reference
    disagreement_reference: str | None = None


# what report reads of run.json, and the type each must have when present (peers write their own run.json)
_RUN_KEYS: dict[str, tuple[type, ...]] = {"log": (str,), "scan_topic": (str,), "stamp_shift_s": (int, float),
                                          "sweeps": (int,), "log_sha256": (str,), "params": (dict,),
                                          "doppler": (bool, type(None)), "prior": (str, type(None)),
                                          "many_skipped_sweeps": (dict,), "gaps": (list,),
                                          "jumps": (dict,)}
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
        with open(path, "rb") as fh:  # opened here: Arrow takes a path as UTF-8, which a name need not be
            # one thread: Arrow's pool, torn down at the exit after a read from a Python file, can abort the
            # process (SIGABRT, apache/arrow#34314); these tables are small
            table = pq.read_table(fh, use_threads=False)
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


def _check_log_matches(out_dir: Path, log: Path, reader: Log, run: dict, stamps: np.ndarray) -> None:
    """Refuse a log other than the one ``out_dir`` was processed from: by its sha256 where run.json
    records it (another run, scenario or seed can share every stamp), else by its sweep stamps."""
    recorded = run.get("log_sha256")
    if recorded is not None:
        try:
            digest = log_sha256(log)
        except OSError as exc:
            raise ReportError(f"{log}: cannot read ({exc.strerror})") from None
        if digest != recorded:
            raise ReportError(f"{log}: is not the log {out_dir} was processed from ({run.get('log', 'see run.json')}): "
                              f"their sha256 differ ({digest[:12]}... here, {recorded[:12]}... in run.json)")
    scan = run.get("scan_topic", "/fmcw/points")
    # a bag's log_time is when the message was received: its sweeps are matched by header.stamp
    log_stamps = np.fromiter((stamp_ns(m.msg.header.stamp) for m in reader.messages([scan])) if reader.receive_times
                             else reader.log_times(scan), dtype=np.int64)
    # a peer may stamp its poses later than the sweep (KISS-ICP: mid-sweep); run.json says by how much
    stamps = np.asarray(stamps, dtype=np.int64) - int(round(float(run.get("stamp_shift_s", 0.0)) * 1e9))
    if log_stamps.size == 0 or not np.all(np.isin(stamps, log_stamps)):
        if recorded is not None:  # the very log: its log_time differs from its header.stamp (the log format has them equal)
            raise ReportError(f"{log}: the log_time of its {scan} messages differs from their header.stamp, by "
                              f"which {out_dir} was processed (docs/log-format.md has them equal): the sweeps cannot "
                              "be matched")
        raise ReportError(f"{log}: does not belong to {out_dir} (its {scan} stamps differ from the processed sweeps)")


def evaluate(out_dir: str | Path, log: str | Path | None = None,
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
    feature_rows = feature_lengths(out_dir, [m for m in present if m in METHOD_NAMES], world.features, world.walls,
                                   gt_ns, gt) if measurable else {}
    labels = read_point_labels(reader) if GT_LABELS_TOPIC in reader.topics else None

    methods: dict[str, dict[str, Any]] = {}
    tums: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for m in present:
        r: dict[str, Any] = {k: None for k in _METRIC_KEYS}
        r["notes"] = []
        t, est = tums[m] = read_tum(out_dir / f"{m}.tum")
        if rel_table is not None and relations is not None:
            _relations(r, t, est, rel_table, relations)
        _trajectory_errors(r, m, t, est, ev)
        _features(r, m, feature_rows, measurable)
        _segmentation(r, m, out_dir, labels)
        ev.sweep_ms[m] = _speed(r, m, sweep_ms[sweep_method == m])
        methods[m] = r

    comparison = _comparison(methods)
    reduction = comparison["reduction_pct"] if comparison else None
    if comparison is None and measurable and {IMPROVED, BASELINE} <= set(methods):
        notes.append("no reduction of the average feature error: no feature was measured by both methods")
    ev.result = {
        "schema": "fmcwlog.report/1",
        "header": report_header(run, log, reader.metadata.get(SIM_KEY) or {}, present),
        "out_dir": str(out_dir),
        "log": str(log),
        "sweeps": int(run.get("sweeps", 0)),
        "wall_seconds": _wall_seconds(run),
        "wall_sweeps_per_second": _wall_rate(run),
        "doppler": run.get("doppler"),
        "prior": run.get("prior"),
        "methods": methods,
        "feature_avg_rel_error_reduction_pct": reduction,
        "feature_comparison": comparison,
        "paper": dict(PAPER),
        "relations_file": str(relations) if relations is not None else None,
        "relations_published": _published_relations(relations),
        "params": run.get("params"),
        "motion_sources": run.get("motion_sources"),
        "calibration_check": run.get("calibration_check"),
        "disagreement": _disagreements(ev, tums, notes),
        "notes": notes,
    }
    return ev


def params_digest(params: Any) -> str | None:
    """First 12 hex digits of the sha256 of ``params`` as canonical JSON (keys sorted, no spaces, ASCII)."""
    if params is None:
        return None
    text = json.dumps(params, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:12]


def report_header(run: dict, log: Path, sim: dict[str, str], present: list[str]) -> dict[str, Any]:
    """What was run: versions, date (UTC), log, scenario and seed (from the log's ``fmcwlog.sim``
    record, absent from a real log), methods and the parameters' digest; and, only where the run
    skipped more than 5 % of the log's sweeps, how many and why (run.json's ``many_skipped_sweeps``); only
    where the sweeps had gaps, run.json's ``gaps``; only where a method found a jump (a robot carried
    away), run.json's ``jumps`` of the methods that found one."""
    seed = sim.get("seed")
    jumps = run.get("jumps")
    jumps = {m: js for m, js in jumps.items() if js} if isinstance(jumps, dict) else {}
    skipped = run.get("many_skipped_sweeps")
    gaps = run.get("gaps")
    return {
        "fmcwlog_version_processed": run.get("fmcwlog_version"),
        "fmcwlog_version_report": __version__,
        "report_date_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "log": str(log),
        "scenario": sim.get("scenario"),
        "seed": int(seed) if seed is not None and str(seed).lstrip("-").isdigit() else None,
        "methods": list(run.get("methods") or [m for m in present if m in METHOD_NAMES]),
        "trajectories": list(present),
        "params_sha256_12": params_digest(run.get("params")),
        **({"many_skipped_sweeps": skipped} if skipped is not None else {}),
        **({"gaps": gaps} if gaps else {}),
        **({"jumps": jumps} if jumps else {}),
    }


def _disagreements(ev: Evaluation, tums: dict[str, tuple[np.ndarray, np.ndarray]], notes: list[str]) -> dict:
    """Each trajectory SE(2)-aligned onto the improved one (else the first method), and the gap between them."""
    reference = next((m for m in (*METHOD_NAMES, *tums) if m in tums and len(tums[m][0]) >= 2), None)
    out: dict[str, Any] = {"reference": reference, "methods": {}}
    if reference is None:
        return out
    ev.disagreement_reference = reference
    t_ref, ref = tums[reference]
    for m, (t, est) in tums.items():
        if m == reference:
            continue
        try:
            d = disagreement(t_ref, ref, t, est)
        except ValueError as exc:
            notes.append(f"disagreement of {m} with {reference}: {exc}")
            continue
        ev.disagreements[m] = d
        out["methods"][m] = d.summary()
    return out


def _open_log(out_dir: Path, run: dict, log: str | Path | None) -> tuple[Path, Log]:
    """The log the folder was processed from: ``log`` if given, else the one run.json names."""
    named = log if log is not None else run.get("log")
    if named is None or not str(named).strip():
        raise ReportError(f"{out_dir}: its run.json names no log; name it with --log")
    path = Path(named)
    if not path.exists():
        raise ReportError(f"{out_dir}: its log {path} is not there; name it with --log")
    try:
        reader = open_log(path)
        return reader.path, reader
    except LogError as exc:
        raise ReportError(str(exc)) from None


def _sweep_times(out_dir: Path, log: Path, reader: Log, run: dict) -> tuple[np.ndarray, np.ndarray]:
    """Method and ms of every row of trajectories.parquet, once its stamps are checked against the log."""
    with open(out_dir / "trajectories.parquet", "rb") as fh:  # Arrow takes a path as UTF-8; a name need not be
        table = pq.read_table(fh, columns=["method", "stamp_ns", "ms"], use_threads=False)  # one thread: _check_parquet
    _check_log_matches(out_dir, log, reader, run, np.unique(table.column("stamp_ns").to_numpy()))
    return table.column("method").to_numpy(zero_copy_only=False), table.column("ms").to_numpy()


def _published_relations(relations: str | Path | None) -> list[dict]:
    rows = relations_for(relations) if relations is not None else []
    return [{"method": n, "trans_mean_m": a, "trans_std_m": b} for n, a, b in rows]


def _trajectories_in(out_dir: Path) -> list[str]:
    """fmcwlog's trajectories first, then any other dropped in the folder (a peer, e.g. kiss_icp.tum)."""
    present = [m for m in TRAJECTORIES if (out_dir / f"{m}.tum").is_file()]
    return present + sorted(p.stem for p in out_dir.glob("*.tum")
                            if p.stem not in TRAJECTORIES and p.name != GROUND_TRUTH_TUM)


def _ground_truth(reader: Log, log: Path, ev: Evaluation, notes: list[str]) -> tuple[np.ndarray, np.ndarray]:
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
    if not np.any((t >= ev.gt_t[0]) & (t <= ev.gt_t[-1])):
        r["notes"].append(f"no pose falls within the ground truth's time span ({ev.gt_t[0]:.3f} to {ev.gt_t[-1]:.3f} s; "
                          f"this trajectory: {t[0]:.3f} to {t[-1]:.3f} s): trajectory errors cannot be computed")
        return
    idx, ref = interpolate_reference(t, ev.gt_t, ev.gt)
    a = ate(est[idx], ref, "se2")
    f = ate(est[idx], ref, "first")
    r.update(ate_rmse_m=a.rmse, ate_mean_m=a.mean, ate_median_m=a.median, ate_std_m=a.std, ate_min_m=a.min,
             ate_max_m=a.max, ate_first_aligned_rmse_m=f.rmse)
    ev.aligned[method] = (t[idx], a.est_aligned, a.errors)
    heading = ev.heading[method] = heading_errors(a.est_aligned, ref)
    r["heading_rmse_deg"] = float(np.sqrt(np.mean(heading**2)))
    r["heading_max_deg"] = float(np.max(np.abs(heading)))
    ev.rpe[method] = []
    for delta in RPE_DELTAS_M:
        try:
            s = rpe_series(est[idx], ref, delta)
        except ValueError as exc:
            r["notes"].append(f"RPE over {delta:g} m: {exc}")
            continue
        ev.rpe[method].append(s)
        r[f"rpe_{delta:g}m_pct"] = float(np.mean(s.trans_pct))
        r[f"rpe_{delta:g}m_deg_per_m"] = float(np.mean(s.rot_deg_per_m))


def _features(r: dict, method: str, feature_rows: dict[str, list[dict]], measurable: bool) -> None:
    """The method's feature rows (measured in its map: :mod:`.features`) with their errors, and
    their average over the features its map shows."""
    if method == WHEEL_ODOMETRY:
        r["notes"].append("builds no map: no feature lengths")
        return
    if method not in feature_rows:
        if measurable and method.endswith("_frontend") and method.removesuffix("_frontend") in METHOD_NAMES:
            r["notes"].append(f"its map is the {method.removesuffix('_frontend')} method's, measured there")
        elif measurable:
            r["notes"].append("not one of fmcwlog's methods: its map is not measured")
        return
    rows = feature_rows[method]
    seen = [row for row in rows if row["measured_m"] is not None]
    errs = dict(zip([row["id"] for row in seen],
                    feature_length_errors(np.array([row["true_m"] for row in seen]),
                                          np.array([row["measured_m"] for row in seen]))))
    r["features"] = [{**row, "abs_error_m": errs[row["id"]].abs_error_m if row["id"] in errs else None,
                      "rel_error_pct": errs[row["id"]].rel_error_pct if row["id"] in errs else None}
                     for row in rows]
    if seen:
        r["feature_avg_rel_error_pct"] = mean_relative_error_pct(list(errs.values()))
    missing = [str(row["id"]) for row in rows if row["measured_m"] is None]
    if missing:
        r["notes"].append(f"features {', '.join(missing)} are not measurable in this method's map (each row "
                          f"says why): the average is over the other {len(seen)}")


def _segmentation(r: dict, method: str, out_dir: Path, labels: dict[int, np.ndarray] | None) -> None:
    if method in SEGMENTING_METHODS:
        r["segmentation"] = segmentation_scores(out_dir, method, labels, r["notes"])
    elif method.removesuffix("_frontend") in SEGMENTING_METHODS:
        r["notes"].append(f"its moving points are the {method.removesuffix('_frontend')} method's, scored there")
    elif method != WHEEL_ODOMETRY:
        r["notes"].append("does not segment moving points: no moving-point scores")


def _speed(r: dict, method: str, ms: np.ndarray) -> np.ndarray:
    """Speed statistics into ``r``; returns the timed sweeps' ms."""
    ms = ms[np.isfinite(ms)]  # the motion prior's rows carry no time
    if len(ms):
        r["ms_per_sweep_median"] = float(np.median(ms))
        r["ms_per_sweep_p95"] = float(np.percentile(ms, 95))
        r["ms_per_sweep_mean"] = float(np.mean(ms))
        r["ms_per_sweep_max"] = float(np.max(ms))
        r["sweeps_per_second"] = float(1000.0 / np.mean(ms))
    elif method == WHEEL_ODOMETRY:
        r["notes"].append("the motion prior itself: its time is not measured per sweep")
    return ms


def _wall_seconds(run: dict) -> float | None:
    """run.json's ``wall_seconds`` (the whole run: reading, both methods side by side, writing), or None."""
    wall = run.get("wall_seconds")
    if not isinstance(wall, int | float) or isinstance(wall, bool) or not np.isfinite(wall) or wall <= 0:
        return None
    return float(wall)


def _wall_rate(run: dict) -> float | None:
    """Sweeps per second of wall-clock time over the whole run, as ``process`` printed it (None without
    run.json's ``wall_seconds``)."""
    wall = _wall_seconds(run)
    return float(run.get("sweeps") or 0) / wall if wall is not None else None


def _comparison(methods: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """The two methods' average relative feature errors over the features *both* measured, and
    the % by which the improved method cuts the baseline's (None when no feature is in both, or
    the baseline's average is 0). Each method's own ``feature_avg_rel_error_pct`` averages over
    the features its map shows, which may be a different set: a static 30 s log had the
    baseline's 1.31 % over one feature beside the improved method's 4.45 % over three."""
    imp = (methods.get(IMPROVED) or {}).get("features") or []
    base = (methods.get(BASELINE) or {}).get("features") or []
    pairs = [(a["rel_error_pct"], b["rel_error_pct"]) for a, b in zip(imp, base)
             if a["rel_error_pct"] is not None and b["rel_error_pct"] is not None]
    if not pairs:
        return None
    mi, mb = float(np.mean([p[0] for p in pairs])), float(np.mean([p[1] for p in pairs]))
    return {"features": len(pairs), "baseline_avg_rel_error_pct": mb, "improved_avg_rel_error_pct": mi,
            "reduction_pct": float(relative_reduction_pct(mb, mi)) if mb > 0 else None}
