"""The library surface: what the command line does, as functions (evo's ``main_*`` entries).

    from fmcwlog import api
    api.record(api.scenario("corridor"), api.SimConfig(), "corridor.mcap")
    summary = api.process("corridor.mcap", "out/")
    ev = api.report("out/")                  # ev.result["methods"]["improved"]["ate_rmse_m"]
    batch = api.process_many(["logs/"], "results/", jobs=4)   # results/<log>/; batch.failed: their reasons
    fleet = api.report_fleet("results/")     # fleet["flagged"]; results/fleet.html
    cmp = api.compare_runs(["runA/", "runB/"], "cmp/")  # cmp["metrics"]; cmp/compare.html

Every function raises :class:`fmcwlog.errors.FmcwlogError` (with a one-line message
naming the file and the problem) for input it cannot use, and leaves nothing
half-written behind. This module only gathers the names; each lives in its layer.
"""

from __future__ import annotations

from .evaluation.compare import compare_runs
from .evaluation.compare_fleets import compare_fleets
from .evaluation.evaluate import Evaluation, evaluate
from .evaluation.report import compare, report, report_fleet
from .fleet.batch import BatchSummary, process_many
from .fleet.imports import ImportOutcome, import_carmen_many
from .fleet.state import is_batch_folder
from .fleet.tasks import Limits
from .frontend.params import FrontEndParams
from .io.carmen_import import ImportSummary, import_carmen
from .pipeline.calibrate import CalibrateSummary, calibrate
from .pipeline.options import ProcessOptions
from .pipeline.params import ProcessParams
from .pipeline.process import ProcessSummary, process
from .sim.config import SimConfig
from .sim.recorder import RecordSummary, record
from .sim.scenarios import scenario

__all__ = ["SimConfig", "ProcessParams", "FrontEndParams", "ProcessOptions", "ProcessSummary", "Evaluation", "Limits",
           "BatchSummary", "RecordSummary", "ImportSummary", "ImportOutcome", "CalibrateSummary",
           "scenario", "record", "process", "process_many", "evaluate", "report", "report_fleet", "is_batch_folder",
           "compare", "compare_runs", "compare_fleets", "import_carmen", "import_carmen_many", "calibrate"]
