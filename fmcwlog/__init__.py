"""fmcwlog: record, process and evaluate FMCW LiDAR robot logs.

Data flow, one module per idea:

- ``mcap_io``      reading and writing logs (the only module that knows MCAP/CDR)
- ``sim/``         ``fmcwlog record``: world, route, chassis, encoders, FMCW LiDAR
- stage modules    ``odometry``, ``egomotion``, ``segmentation``, ``deskew``,
                   ``gmmsc``, ``robust_icp``, ``occupancy`` (pure numpy functions)
- ``cli``          the thin command-line front end
"""

__version__ = "0.1.0"
