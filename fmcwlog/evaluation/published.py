"""Published figures fmcwlog compares itself with, each written once, with its source.

The paper (Wang et al., "Automatic Positioning of Intelligent Mobile Robot Based on Improved
Front-End Scanning Matching", 2024; Tables 2 and 3): the average relative error of the
nine feature lengths in the map before improvement (the classic ICP baseline) and
after, and the reduction between them.

The relations metric: translation error in metres, mean ± std, per dataset, keyed by the
relations file's name (``intel.relations`` -> ``intel``), each row naming its source:

- Kümmerle et al. 2009, "On measuring the accuracy of SLAM algorithms" (Autonomous Robots
  27(4)), the table of absolute translational errors: scan matching, RBPF (GMapping) and graph
  mapping on ACES, Intel, MIT Killian Court, MIT CSAIL and Freiburg bldg 79. The paper itself
  could not be read from here; these figures are checked against a public transcription of that
  table.
- Hess et al. 2016, "Real-Time Loop Closure in 2D LIDAR SLAM" (ICRA), Cartographer: only the
  Intel figure; the paper could not be read from here to check the rows for the other datasets,
  so they are left out.

The published figures are over the full logs' relations; fmcwlog scores only the relations whose
stamps fall on the processed log's scans (97 of Intel's 2,984 for the 910-scan subset, within the
metric's 1 ms), so the comparison is indicative, not like for like.
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

_K = "Kümmerle et al. 2009, Table 2"


def _kummerle(sm: tuple[float, float], rbpf: tuple[float, float], gm: tuple[float, float]) -> list[tuple[str, float, float]]:
    return [(f"scan matching ({_K})", *sm), (f"GMapping / RBPF ({_K})", *rbpf), (f"graph mapping ({_K})", *gm)]


# (method and source, translation mean m, translation std m) per dataset, keyed by the relations file's stem
RELATIONS = {
    "aces": _kummerle((0.173, 0.614), (0.060, 0.049), (0.044, 0.044)),
    "intel": _kummerle((0.220, 0.296), (0.070, 0.083), (0.031, 0.026))
    + [("Cartographer (Hess et al. 2016, Table I)", 0.0229, 0.0239)],
    "mit-killian": _kummerle((1.651, 4.138), (0.122, 0.386), (0.050, 0.056)),
    "mit-csail": _kummerle((0.106, 0.325), (0.049, 0.049), (0.004, 0.009)),
    "fr079": _kummerle((0.258, 0.427), (0.061, 0.044), (0.056, 0.042)),
}


def relations_for(path: str | Path) -> list[tuple[str, float, float]]:
    """The published rows for a relations file, by its name (``intel.relations`` -> intel)."""
    return RELATIONS.get(Path(path).name.split(".")[0], [])
