"""``run.json``: what one ``fmcwlog process`` run read, assumed, found and wrote, as one typed record.

:meth:`RunRecord.to_json` gives the document ``run.json`` holds (written with sorted keys):
report, the fleet's resume check and the user's own tools read it back.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..frontend.self_calibration import CalibrationCheck


@dataclass(frozen=True)
class RunRecord:
    """One run of ``fmcwlog process`` on one log.

    log: the log's absolute path; log_size_bytes, log_sha256: its size and SHA-256, which
        ``fmcwlog report --log`` and a resumed batch check. options_sha256: the digest of every
        option (:func:`fmcwlog.pipeline.options.options_digest`).
    methods: the front ends run. scan_topic: the scan topic read. prior: the motion prior as the
        summary says it (``wheel ticks (/wheel/ticks)``, ``odometry (/odom)``, or without either what
        guessed each sweep's pose and why, e.g. ``scan-to-map correlative search (no odometry, no
        wheel ticks, no Doppler in /scan)``). doppler: whether the scans carried Doppler velocity.
    mount: the lidar's pose in the base frame (m, m, rad); lidar_upside_down: the lidar is rolled by π
        about its x axis, its sweeps mirrored back (y -> -y) as read; calibration_source: where the calibration
        came from: one source (a file's path, ``log record fmcwlog.calibration``, ``tf /tf_static
        base_link->laser``, ``none (assumed 0, 0, 0)``) where it gave every value used, else
        ``mount from ...; wheels from ...``; calibration_sources: the same per group (``mount``,
        ``wheels``, and ``upside_down`` where a source gives ``lidar_upside_down``),
        :class:`fmcwlog.io.calibration.CalibrationSources`.
    motion_sources: per method, where its twist came from and what the sensor checks found.
    calibration_check: the calibration check's findings, where it ran (absent otherwise).
    frames: each trajectory's odometry frame. params: every parameter (``dataclasses.asdict`` of
        :class:`~fmcwlog.pipeline.params.ProcessParams`), loadable again with ``--config``.
    sweeps: sweeps processed; skipped_sweeps: sweeps left out as damaged; repeated_prior_stamps:
        motion-prior messages with a stamp already seen; skipped_inputs: messages skipped per kind.
    truncated_log: the log ends without its summary (a recording cut off).
    gaps: each gap in the sweeps (:mod:`fmcwlog.frontend.gaps`: no sweep, or none with a usable point,
        for more than ``frontend.gaps.min_periods`` sweep periods): ``start_s`` (log time, s, where the
        first missing sweep was due), ``length_s`` (s) and ``bridged_by`` (what bridged it).
    jumps: per method, each jump it found (:mod:`fmcwlog.frontend.relocalise`: a robot carried away, its
        sweeps no longer fitting the map where the motion prior put them): ``start_s`` (log time, s, the
        first sweep that did not fit), ``found_s`` (the sweep that ended it), ``kind`` (``relocalised``
        or ``new piece``) and, where relocalised, ``distance_m`` and ``rotation_deg`` from the prior's pose.
    warnings: every warning of the run, one line each.
    ms_per_sweep_median: per method, the median CPU time of a sweep (ms).
    correlative_searches: per method, ``run`` (searches run), ``kept`` (matches they replaced), ``sweeps``.
    backend: ``kind`` (``pose-graph`` or ``none``) and, per method, the back end's summary.
    wall_seconds: the run's wall-clock time (s).
    many_skipped_sweeps: only where more than ``limit`` (5 %) of the log's sweeps were skipped as
        damaged: ``skipped`` of ``read``, their ``share``, the ``limit``, the share above which a run
        is refused (``refused_above``), whether it went on past it (``kept_going``), and the kind most
        of them were skipped as (``main_kind``) with its warning (``main_reason``).
    """

    fmcwlog_version: str
    log: str
    log_size_bytes: int
    log_sha256: str
    options_sha256: str
    methods: tuple[str, ...]
    scan_topic: str
    prior: str
    doppler: bool
    mount: tuple[float, float, float]
    calibration_source: str
    calibration_sources: dict[str, str]
    motion_sources: dict[str, dict[str, Any]]
    frames: dict[str, str]
    params: dict[str, Any]
    sweeps: int
    skipped_sweeps: int
    repeated_prior_stamps: int
    skipped_inputs: dict[str, int]
    truncated_log: bool
    warnings: list[str]
    ms_per_sweep_median: dict[str, float]
    correlative_searches: dict[str, dict[str, int]]
    backend: dict[str, Any]
    wall_seconds: float
    calibration_check: CalibrationCheck | None = field(default=None)
    many_skipped_sweeps: dict[str, Any] | None = field(default=None)
    gaps: list[dict[str, float | str]] = field(default_factory=list)
    jumps: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    lidar_upside_down: bool = False

    def to_json(self) -> dict[str, Any]:
        """The document ``run.json`` holds (plain JSON types; lists for tuples)."""
        diagnostics: dict[str, Any] = {"motion_sources": self.motion_sources}
        if self.calibration_check is not None:
            diagnostics["calibration_check"] = self.calibration_check.to_json()
        skipped = {"many_skipped_sweeps": self.many_skipped_sweeps} if self.many_skipped_sweeps is not None else {}
        return {
            "fmcwlog_version": self.fmcwlog_version,
            "log": self.log,
            "log_size_bytes": self.log_size_bytes,
            "log_sha256": self.log_sha256,
            "options_sha256": self.options_sha256,
            "methods": list(self.methods),
            "scan_topic": self.scan_topic,
            "prior": self.prior,
            "doppler": self.doppler,
            "mount": list(self.mount),
            "lidar_upside_down": self.lidar_upside_down,
            "calibration_source": self.calibration_source,
            "calibration_sources": self.calibration_sources,
            **diagnostics,
            "frames": self.frames,
            "params": self.params,
            "sweeps": self.sweeps,
            "skipped_sweeps": self.skipped_sweeps,
            "repeated_prior_stamps": self.repeated_prior_stamps,
            "skipped_inputs": self.skipped_inputs,
            **skipped,
            "truncated_log": self.truncated_log,
            "gaps": self.gaps,
            "jumps": self.jumps,
            "warnings": self.warnings,
            "ms_per_sweep_median": self.ms_per_sweep_median,
            "correlative_searches": self.correlative_searches,
            "backend": self.backend,
            "wall_seconds": self.wall_seconds,
        }
