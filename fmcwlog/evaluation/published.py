"""Published figures fmcwlog compares itself with, each written once, with its source.

The paper (``shared/paper.txt``, Tables 2 and 3): the average relative error of the
nine feature lengths in the map before improvement (the classic ICP baseline) and
after, and the reduction between them.

The relations metric (Kümmerle et al. 2009, "On measuring the accuracy of SLAM
algorithms", Table 2; Hess et al. 2016, "Real-Time Loop Closure in 2D LIDAR SLAM",
Table I): translation error in metres, mean ± std, per dataset.
"""

from __future__ import annotations

from pathlib import Path

PAPER_BASELINE_FEATURE_ERROR_PCT = 6.0505
PAPER_IMPROVED_FEATURE_ERROR_PCT = 3.5919
PAPER_FEATURE_ERROR_REDUCTION_PCT = 40.6


def paper_summary() -> str:
    return (f"the paper: {PAPER_BASELINE_FEATURE_ERROR_PCT:.2f} % -> {PAPER_IMPROVED_FEATURE_ERROR_PCT:.2f} %, "
            f"{PAPER_FEATURE_ERROR_REDUCTION_PCT:.1f} %")


PAPER = {"baseline_avg_rel_error_pct": PAPER_BASELINE_FEATURE_ERROR_PCT,
         "improved_avg_rel_error_pct": PAPER_IMPROVED_FEATURE_ERROR_PCT,
         "reduction_pct": PAPER_FEATURE_ERROR_REDUCTION_PCT}

# (method, translation mean m, translation std m) per dataset, keyed by the relations file's stem
RELATIONS = {
    "intel": [
        ("scan matching (Kümmerle et al. 2009)", 0.220, 0.296),
        ("GMapping / RBPF (Kümmerle et al. 2009)", 0.070, 0.083),
        ("graph mapping (Kümmerle et al. 2009)", 0.031, 0.026),
        ("Cartographer (Hess et al. 2016)", 0.0229, 0.0239),
    ],
}


def relations_for(path: str | Path) -> list[tuple[str, float, float]]:
    """The published rows for a relations file, by its name (``intel.relations`` -> intel)."""
    return RELATIONS.get(Path(path).name.split(".")[0], [])
