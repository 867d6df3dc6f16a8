"""What ``fmcwlog process`` runs on a log: methods, topics, parameters, back end; and their digest."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

from .. import __version__
from ..io.clouds import CloudReading, parse_time_field
from ..io.digest import file_sha256
from ..io.topics import BASE_FRAME
from ..types import METHOD_NAMES
from .params import ProcessParams


@dataclass
class ProcessOptions:
    """What :func:`process` runs: which methods, on which topics, with which parameters.

    scan_topic: default ``/fmcw/points``, else ``/scan``, else the log's only scan topic.
    ticks_topic: default ``/wheel/ticks`` when present.
    odom_topic: an Odometry topic as the motion prior instead of ticks (default ``/odom``
        when the log has no ticks).
    publish_period: paths and occupancy grids go into ``processed.mcap`` every this many
        seconds of log (s), and once more at the end.
    backend: ``pose-graph`` (loop closures for every method, :mod:`fmcwlog.backend`; the outputs
        come from the optimised poses) or ``none`` (the front ends alone).
    calibration: a calibration file (:mod:`fmcwlog.io.calibration_file`) whose values go before
        the log's ``fmcwlog.calibration`` record and its tf (:mod:`fmcwlog.io.calibration`).
    base_frame: the robot's frame the mount is looked up in through the log's tf, from the scan's
        ``header.frame_id`` (where neither the file nor the record gives the mount).
    params: every parameter of the run (:class:`fmcwlog.pipeline.params.ProcessParams`).
    keep_going: process a log that lost more than half its sweeps as damaged
        (:data:`fmcwlog.io.inputs.MOST_SKIPPED_SHARE`) instead of refusing it.
    time_field: ``NAME:UNIT``, the PointCloud2 field holding each point's time and its unit
        (:func:`fmcwlog.io.clouds.parse_time_field`); None: read by name and type.
    """

    methods: tuple[str, ...] = METHOD_NAMES
    scan_topic: str | None = None
    ticks_topic: str | None = None
    odom_topic: str | None = None
    params: ProcessParams = field(default_factory=ProcessParams)
    publish_period: float = 5.0
    calibration: Path | None = None
    backend: str = "pose-graph"
    base_frame: str = BASE_FRAME
    keep_going: bool = False
    time_field: str | None = None

    def cloud_reading(self) -> CloudReading:
        """How the scan topic's clouds are read (:mod:`fmcwlog.io.clouds`); a ``time_field`` that
        is not ``NAME:UNIT`` raises :class:`~fmcwlog.errors.ConfigError`."""
        return CloudReading(self.params.inputs, parse_time_field(self.time_field))


BACKENDS = ("pose-graph", "none")


def options_digest(opts: ProcessOptions) -> str:
    """SHA-256 of everything that shapes the results: methods, topics, every parameter, the
    publishing period, the calibration file's bytes (``--calibration``: a file edited in place
    gives other results; the same bytes elsewhere, the same) and fmcwlog's version (new code
    may give different results). The base frame counts where it is not ``base_link``, so that the
    default's digest is that of runs made before the option. Not ``keep_going``: it decides whether a
    run writes its results, never what they are."""
    doc = {"fmcwlog_version": __version__, **dataclasses.asdict(opts)}
    if doc["base_frame"] == BASE_FRAME:
        del doc["base_frame"]
    del doc["keep_going"]
    if opts.calibration is not None:
        doc["calibration"] = _file_digest(Path(opts.calibration))
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def _file_digest(path: Path) -> str:
    try:
        return "sha256:" + file_sha256(path)
    except OSError:  # unreadable: processing says so, naming the file; the digest only has to differ
        return f"unreadable: {path}"
