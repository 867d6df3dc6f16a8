"""Per-sweep cost of the improved method's Doppler stages (ego-motion + segmentation + tracking) on real logs.

Runs the improved front end over each log (no outputs written) and prints, per log, the
median and 95th percentile of the CPU milliseconds per sweep of the whole front end
(``ImprovedFrontEnd.step``), of ``ImprovedFrontEnd.doppler_stages`` (ego-motion fit,
segmentation and, where the code has it, the tracker), and of ``ImprovedFrontEnd.segment``
alone when it exists. CPU time, not wall time, so that runs on a loaded machine compare. Run it from a checkout's root so that its ``fmcwlog`` is measured:

    python bench/bench_segmentation.py LOG.mcap [LOG.mcap ...] [--set tracking.enabled=false]

Logs: ``python -m fmcwlog record --scenario dense-crowd --duration 120 --seed 0 -o dense.mcap``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path.cwd()))

from fmcwlog.config import parse_set_option  # noqa: E402
from fmcwlog.frontend import methods  # noqa: E402
from fmcwlog.io.calibration import load_calibration  # noqa: E402
from fmcwlog.io.inputs import LogInputs  # noqa: E402
from fmcwlog.io.logs import open_log  # noqa: E402
from fmcwlog.io.topic_choice import choose_topics  # noqa: E402
from fmcwlog.pipeline.params import load_params  # noqa: E402
from fmcwlog.pipeline.runner import LogRunner  # noqa: E402


def timed(cls: type, name: str, into: list[float]) -> None:
    """Wrap ``cls.name`` so that each call's CPU milliseconds (this process, all threads) are
    appended to ``into``: on a shared machine CPU time moves far less with the load than wall time."""
    inner = getattr(cls, name)

    def wrapper(self, *args, **kwargs):
        t0 = time.process_time()
        out = inner(self, *args, **kwargs)
        into.append((time.process_time() - t0) * 1e3)
        return out

    setattr(cls, name, wrapper)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", type=Path)
    ap.add_argument("--set", dest="sets", action="append", default=[], help="SECTION.NAME=VALUE, as for process")
    args = ap.parse_args()
    params = load_params(parse_set_option(tuple(args.sets)))
    total: list[float] = []
    stages: list[float] = []
    segment: list[float] = []
    timed(methods.ImprovedFrontEnd, "step", total)
    timed(methods.ImprovedFrontEnd, "doppler_stages", stages)
    if hasattr(methods.ImprovedFrontEnd, "segment"):
        timed(methods.ImprovedFrontEnd, "segment", segment)
    for log in args.logs:
        total.clear()
        stages.clear()
        segment.clear()
        reader = open_log(log)
        topics = choose_topics(reader, None, None, None)
        cal = load_calibration(reader, log, topics.scan, topics.ticks is not None, None).cal
        runner = LogRunner(["improved"], params, cal, topics, log)
        for _ in runner.run(LogInputs(reader, topics, cal)):
            pass
        row = [f"{log.name}: {len(total)} sweeps, ms per sweep median / p95: front end {np.median(total):.2f} / "
               f"{np.percentile(total, 95):.2f}, doppler_stages {np.median(stages):.2f} / {np.percentile(stages, 95):.2f}"]
        if segment:
            row.append(f"segment {np.median(segment):.2f} / {np.percentile(segment, 95):.2f}")
        print(", ".join(row), flush=True)


if __name__ == "__main__":
    main()
