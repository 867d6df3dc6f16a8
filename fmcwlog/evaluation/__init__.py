"""Evaluation: the only code that reads ground truth.

- ``ground_truth``        the readers of ``/ground_truth/*`` and ``fmcwlog.world``
- ``metrics``             ATE, RPE (evo's definitions), feature-length errors
- ``features``            feature lengths measured in the map each method built (the paper's Tables 2 and 3)
- ``map_geometry``        walls fitted in a map near a given place: their ends and corners
- ``segmentation_score``  moving-point precision and recall
- ``along_path``          per-pose and per-pair series (heading error, RPE per pair) and the
                          methods' disagreement, which needs no ground truth
- ``relations``           the relations metric of Kümmerle et al. 2009 (real logs)
- ``published``           the paper's and the literature's figures, once
- ``evaluate``            an output folder measured against its log
- ``plots``               the report's figures
- ``pages``               report.html, report.md, report.json and the terminal tables
"""
