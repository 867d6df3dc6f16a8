"""fmcwlog: record, process and evaluate FMCW LiDAR robot logs.

Layers, read from the path, lowest first; data flows one way, log -> sweeps -> stages ->
estimates -> outputs -> report, and no module imports a layer above its own
(``tests/test_layers.py``):

- ``errors``, ``config``, ``geometry``, ``allocator``: the one exception family, parameters and
                   config files, SE(2) helpers, the allocator's settings for long runs
- ``types``        the data that crosses layers (calibration, sweep, ticks, sweep result), no I/O
- ``kernels/``     what both ends share: nearest pairs, correlative search, occupancy grid, voxels
- ``frontend/``    estimation, one module per stage; never reads a file or ground truth
- ``backend/``     the pose graph both methods share: verified loop closures, optimised with gtsam
- ``io/``          every file read or written: MCAP logs, CARMEN logs, outputs, atomic writes
- ``pipeline/``    one log processed: the recipe, the runner, the method process, calibration
- ``fleet/``       many logs: worker processes on this machine or tasks on a Ray cluster
- ``evaluation/``  the only readers of ground truth: metrics, feature lengths, report pages
- ``sim/``         ``fmcwlog record``'s simulator
- ``api``          the library surface: the public functions of the layers, re-exported
- ``cli/``         the command line, one module per command
"""

__version__ = "0.1.0"
