"""Does the back end's ground-truth-free check (the revisit distance) agree with the ground truth's ATE?

For each log it runs ``fmcwlog process`` in this process (both methods, ``jobs=1``) with the check's
verdict held back, so that both trajectories come out, and prints per method: the ATE RMSE of the
front end alone and of the optimised trajectory (cm), the two revisit distances
(:mod:`fmcwlog.backend.consistency`, cm) and whether the check would have kept the front end.

    python bench/backend_gate.py LOG.mcap ...                      # the methods as they are
    python bench/backend_gate.py --bent 0.5 LOG.mcap ...           # every verified closure moved 0.5 m off
    python bench/backend_gate.py --stamp-hold LOG.mcap ...         # without odometry: the prior as it was

``--bent M`` moves each verified closure's relative pose ``M`` m along x before it enters the graph:
wrong closures that bend the graph. ``--stamp-hold`` gives a log without odometry the prior fmcwlog
had before its scan-to-map search: the last scan-matched motion between stamps held (the improved
method) or none (the baseline), and the ICP from there; it is the case where the back end once
made trajectories worse. Writes OUT (default bench/results/backend_gate.json) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from fmcwlog import api  # noqa: E402
from fmcwlog.backend import pipeline as backend  # noqa: E402
from fmcwlog.backend.consistency import worse  # noqa: E402
from fmcwlog.evaluation.evaluate import evaluate  # noqa: E402
from fmcwlog.frontend import methods  # noqa: E402


def _bend(metres: float) -> None:
    verify = backend.verify

    def bent(*args, **kwargs):
        verdict = verify(*args, **kwargs)
        if verdict.accepted and verdict.relative is not None:
            verdict.relative = verdict.relative + np.array([metres, 0.0, 0.0])
        return verdict

    backend.verify = bent


def _stamp_hold() -> None:
    methods.FrontEnd.scan_prior = staticmethod(lambda prior, motion: False)
    methods.FrontEnd.prior_twist = lambda self, prior: prior.twist if prior.twist is not None else self.last_twist
    methods.ImprovedFrontEnd.prior_twist = (
        lambda self, prior: prior.twist if prior.twist is not None else self.scan_twist)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", nargs="+", type=Path)
    ap.add_argument("--bent", type=float, default=0.0, metavar="M", help="move every verified closure M m off")
    ap.add_argument("--stamp-hold", action="store_true", help="without odometry, the prior as it was before the search")
    ap.add_argument("--out", type=Path, default=HERE / "results" / "backend_gate.json")
    args = ap.parse_args()
    if args.bent:
        _bend(args.bent)
    if args.stamp_hold:
        _stamp_hold()
    results: dict[int, backend.BackendResult] = {}
    finish = backend.PoseGraphBackend.finish

    def both(self):  # the optimised trajectory whatever the verdict, and the verdict on the side
        res = finish(self)
        results[len(results)] = res
        return res

    backend.PoseGraphBackend.finish = both
    backend.worse = lambda r: False
    rows = []
    for log in args.logs:
        results.clear()
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "out"
            api.process(log, out, api.ProcessOptions(), jobs=1)
            ate = evaluate(out, log).result["methods"]
        for i, m in enumerate(("improved", "baseline")):
            r = results[i].revisits
            row = {"log": log.name, "method": m, "closures": results[i].accepted,
                   "ate_frontend": ate[f"{m}_frontend"]["ate_rmse_m"], "ate_backend": ate[m]["ate_rmse_m"],
                   "revisit_frontend": None if r is None else r.frontend,
                   "revisit_backend": None if r is None else r.optimised,
                   "kept_front_end": r is not None and worse(r)}
            rows.append(row)
            rev = "—" if r is None else f"{r.frontend * 100:.2f} -> {r.optimised * 100:.2f}"
            print(f"{log.name} {m}: ATE {row['ate_frontend'] * 100:.1f} -> {row['ate_backend'] * 100:.1f} cm, "
                  f"revisit distance {rev} cm, {'front end kept' if row['kept_front_end'] else 'back end used'}",
                  flush=True)
    meta = {"bent_m": args.bent, "stamp_hold": args.stamp_hold,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))


if __name__ == "__main__":
    main()
