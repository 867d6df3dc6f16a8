"""The back end's targets, measured: each figure beside its target, met or not.

    python bench/backend_targets.py                 # Intel subset, ring and corridor (two laps each)
    python bench/backend_targets.py --only intel    # one of: intel, ring, corridor, long-corridor

Intel (``../shared/datasets/intel_lab_subset910``, default parameters, both methods): the Freiburg
relations error overall, on relations spanning < 20 s and ≥ 20 s, with the back end and for the
front end alone (the ``<method>_frontend`` trajectory of the same run; ``--backend none`` gives the
same). Simulated scenarios (seed 0): the ATE RMSE of each method with the back end and without.

Each run is one ``fmcwlog process`` and one ``fmcwlog report`` in this process, into a temporary
folder. On this shared 2-core machine the Intel run takes about 2.5 minutes, a 200 s scenario 2.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's fmcwlog, not an installed one

from fmcwlog.api import ProcessOptions, import_carmen, process, report  # noqa: E402
from fmcwlog.sim import scenarios  # noqa: E402
from fmcwlog.sim.config import SimConfig, apply_overrides  # noqa: E402
from fmcwlog.sim.recorder import record  # noqa: E402

DATASETS = ROOT.parent / "shared" / "datasets"
# (figure, target, at most?) for the improved method on Intel
INTEL_TARGETS = {("improved", "trans_mean_m"): 0.05, ("improved", "long_trans_mean_m"): 0.15,
                 ("improved", "short_trans_mean_m"): 0.03, ("improved_frontend", "trans_mean_m"): 0.25}
SCENARIO_SECONDS = {"ring": 200.0, "corridor": 200.0, "long-corridor": 240.0}  # two laps; out and back
UNDER_1_CM = ("ring", "corridor")


def _verdict(value: float, target: float) -> str:
    return f"{'met' if value <= target else 'NOT met'} (target <= {target:g})"


def intel(work: Path, datasets: Path = DATASETS) -> None:
    log = work / "intel.mcap"
    import_carmen(datasets / "intel_lab_subset910" / "intel_subset910_rawodom.clf.xz", log)
    out = work / "intel"
    process(log, out, ProcessOptions())
    ev = report(out, relations=datasets / "freiburg_relations" / "intel.relations")
    print("Intel subset: relations translation error (m): all / < 20 s / >= 20 s")
    for m in ("improved", "improved_frontend", "baseline", "baseline_frontend", "wheel_odometry"):
        r = ev.result["methods"][m]["relations"]
        print(f"  {m:18s} {r['trans_mean_m']:.3f} / {r['short_trans_mean_m']:.3f} / {r['long_trans_mean_m']:.3f}")
    for (m, key), target in INTEL_TARGETS.items():
        value = ev.result["methods"][m]["relations"][key]
        print(f"  target {m} {key}: {value:.3f} {_verdict(value, target)}")


def scenario(work: Path, name: str) -> None:
    log = work / f"{name}.mcap"
    cfg = apply_overrides(SimConfig(), {"run": {"duration": SCENARIO_SECONDS[name], "seed": 0}})
    record(scenarios.SCENARIOS[name](), cfg, log)
    out = work / name
    summary = process(log, out, ProcessOptions())
    ev = report(out)
    ate = {m: v["ate_rmse_m"] for m, v in ev.result["methods"].items()}
    print(f"{name} ({SCENARIO_SECONDS[name]:.0f} s): ATE RMSE with the back end / front end alone (cm)")
    for m in ("improved", "baseline"):
        worse = "" if ate[m] <= ate[f"{m}_frontend"] else "  (back end WORSE)"
        print(f"  {m:9s} {100 * ate[m]:.2f} / {100 * ate[f'{m}_frontend']:.2f}{worse}; "
              f"back end {summary.backend[m]['closures_accepted']} closures, {summary.backend[m]['seconds']:.1f} s")
    if name in UNDER_1_CM:
        print(f"  target improved under 1 cm: {100 * ate['improved']:.2f} cm "
              f"{'met' if ate['improved'] < 0.01 else 'NOT met'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", choices=["intel", *SCENARIO_SECONDS])
    ap.add_argument("--datasets", type=Path, default=DATASETS,
                    help="folder holding intel_lab_subset910/ and freiburg_relations/ (default: %(default)s)")
    args = ap.parse_args()
    if args.only in (None, "intel") and not args.datasets.is_dir():
        sys.exit(f"backend_targets: error: {args.datasets}: no such folder (the Intel subset is read from "
                 "--datasets, by default ../shared/datasets beside this checkout); "
                 "--only ring, corridor or long-corridor need none")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        if args.only in (None, "intel"):
            intel(work, args.datasets)
        for name in SCENARIO_SECONDS:
            if args.only == name or (args.only is None and name in UNDER_1_CM):
                scenario(work, name)


if __name__ == "__main__":
    main()
