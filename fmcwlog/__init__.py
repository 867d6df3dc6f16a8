"""fmcwlog: record, process and evaluate FMCW LiDAR robot logs.

Layers, read from the path; data flows one way, log -> sweeps -> stages ->
estimates -> outputs -> report:

- ``io/``          every file read or written: MCAP logs, CARMEN logs, outputs (TUM,
                   parquet, map_server, processed.mcap), atomic writes
- ``frontend/``    estimation, one module per stage (pure numpy functions), the two
                   methods and the loop over a log; never reads ground truth
- ``backend/``     the pose graph both methods share: verified loop closures,
                   optimised with gtsam; reads only what a front end made (estimation too)
- ``evaluation/``  the only readers of ground truth: metrics, feature lengths,
                   relations, report pages
- ``sim/``         ``fmcwlog record``'s simulator
- ``api``          the library surface: record, process, report, compare, import
- ``cli``          the command line, thin over ``api``
- ``config``, ``errors``, ``geometry``: parameters and config files, the one exception
                   family, SE(2) helpers
"""

__version__ = "0.1.0"
