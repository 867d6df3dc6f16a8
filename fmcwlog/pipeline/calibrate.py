"""The lidar's mount and the wheels' radii estimated from a log itself: ``fmcwlog calibrate``.

The improved method runs over the log and its calibration check
(:mod:`fmcwlog.frontend.self_calibration`) estimates the values; those that disagree with the
calibration are adopted and the check runs again until they no longer move. The result is
written as a calibration file that ``process --calibration`` takes.
"""

from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass
from pathlib import Path

from .. import __version__
from ..errors import LogError, OutputError
from ..frontend.self_calibration import CalibrationCheck, adopt, converged, recheck, with_estimate
from ..io.atomic import check_output_file, reported_write_errors
from ..io.calibration import CalibrationSources, load_calibration, wheels_hint, wheels_missing
from ..io.calibration_file import write_calibration_file
from ..io.inputs import LogInputs
from ..io.logs import Log, open_log
from ..io.topic_choice import choose_topics
from ..types import Calibration, InputTopics
from .options import ProcessOptions
from .runner import LogRunner


@dataclass(frozen=True)
class CalibrateSummary:
    """What :func:`calibrate` found: the file written; the last pass's check, each value against the
    calibration the run started from; the names whose estimate was written (adopted); how many
    passes ran; the warnings."""

    output: Path
    check: CalibrationCheck
    adopted: list[str]
    passes: int
    warnings: list[str]


def calibrate(log: str | Path, output: str | Path, opts: ProcessOptions | None = None,
              force: bool = False) -> CalibrateSummary:
    """Estimate the lidar's mount and the wheels from ``log`` itself and write them as a calibration file.

    Runs the improved method over the log (nothing else is written), then
    :mod:`fmcwlog.frontend.self_calibration`. The file holds the calibration's keys, each group
    from its source (``opts.calibration``, the log's record, the mount from the log's tf:
    :func:`fmcwlog.io.calibration.load_calibration`), with the estimated values in place of their
    own, each value's standard deviation in a comment; values the log cannot fix keep theirs.
    """
    opts = opts or ProcessOptions()
    opts.cloud_reading()  # a --time-field that is not NAME:UNIT, before any work
    log, output = Path(log), Path(output)
    check_output_file(output, force, (log, opts.calibration))  # --force never overwrites the log it reads
    if not output.parent.is_dir():
        raise OutputError(f"{output}: no folder {output.parent} to write it in")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        reader = open_log(log)
        topics = choose_topics(reader, opts.scan_topic, opts.ticks_topic, opts.odom_topic)
        if topics.ticks is None:
            raise LogError(f"{log}: no wheel ticks: the wheels' radii and the mount are estimated against them")
        loaded = load_calibration(reader, log, topics.scan, True, opts.calibration, opts.base_frame)
        cal0 = loaded.cal
        if cal0.wheels is None:  # nothing to start the wheels from: /odom cannot stand in here
            raise LogError(f"{log}: {wheels_missing(topics.ticks, opts.calibration)}: {wheels_hint(log)}")
        check, adopted, passes, notes = _self_calibrate(reader, topics, cal0, opts)
    first = recheck(check.values, cal0, opts.params.self_calibration)  # against the calibration we started from
    values: dict[str, str | float] = dict(loaded.values)
    lines = [f"fmcwlog {__version__} calibrate: estimated from {log.name} ({check.sweeps_used[0]} moving "
             f"sweeps, {check.sweeps_used[1]} scan-matched heading changes, {passes} "
             f"pass{'es' if passes > 1 else ''}), "
             f"starting from the {_starting_point(loaded.sources)}"]
    for name, c in first.items():
        if name in adopted:
            values[name] = c.estimate
        kept = "" if name in adopted else "; kept the calibration's: it agrees within 3 standard deviations"
        lines.append(f"{name}: {c.estimate:.6g} +- {c.sigma:.2g} (was {c.calibration:.6g}){kept}")
    lines += [f"{name}: kept the calibration's: {why}" for name, why in check.not_estimated.items()]
    with reported_write_errors(output):
        write_calibration_file(output, values, lines)
    return CalibrateSummary(output, dataclasses.replace(check, values=first), sorted(adopted), passes,
                            [str(w.message) for w in caught] + notes)


def _starting_point(sources: CalibrationSources) -> str:
    """The calibration a run started from, for the file's first comment: ``log record fmcwlog.calibration``
    (as before the tf), or each group's source where they differ."""
    return sources.describe() if sources.wheels in (None, sources.mount) else \
        f"mount of {sources.mount} and the wheels of {sources.wheels}"


def _self_calibrate(reader: Log, topics: InputTopics, cal: Calibration,
                    opts: ProcessOptions) -> tuple[CalibrationCheck, set[str], int, list[str]]:
    """The calibration check over the whole log, repeated with the values it adopts
    (:func:`fmcwlog.frontend.self_calibration.adopt`) until they no longer move (at most
    ``self_calibration.passes`` times); returns the last check, the adopted names, the passes, the notes."""
    prm = opts.params.self_calibration
    passes, adopted = 0, set[str]()
    while True:
        passes += 1
        runner = LogRunner(("improved",), opts.params, cal, topics, reader.path)
        for _ in runner.run(LogInputs(reader, topics, cal, opts.cloud_reading())):
            pass
        diagnostics, notes = runner.diagnostics()
        check = diagnostics.get("calibration_check") or CalibrationCheck(False, "no Doppler")
        if not check.checked:
            raise LogError(f"{reader.path}: cannot estimate the calibration: {check.reason}")
        adopted = adopt(check.values, adopted)
        if not adopted or converged(check.values, adopted) or passes >= prm.passes:
            return check, adopted, passes, notes
        cal = with_estimate(cal, {n: check.values[n] for n in adopted})
