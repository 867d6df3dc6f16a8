"""The front ends: estimation from what the log's sensors saw, never from ground truth.

One module per stage, each pure functions on numpy arrays (KISS-ICP's layout). They take the
types of :mod:`fmcwlog.types` and the kernels of :mod:`fmcwlog.kernels`, and import no file
format, no back end and no evaluation:

- ``odometry``            wheel odometry of the rear axle (paper eq. 9, 13)
- ``motion_prior``        the odometry (ticks or an Odometry topic) as poses readable at any time
- ``egomotion``           the sensor's velocity from one sweep's Doppler field (docs/physics.md)
- ``twist_fusion``        the robot's twist from Doppler and the wheels, at any mount
- ``sensor_checks``       Doppler against the wheels, the scans as arbiter; faulty sources dropped
- ``self_calibration``    the lidar's mount and the wheels' radii estimated from the log itself
- ``segmentation``        moving points by DBSCAN over position and compensated Doppler (eq. 17-19)
- ``tracking``            movers followed over time and seen in the map's free space, across the beams too
- ``recent_grid``         the free space the tracker reads: recent scans' casts
- ``deskew``              every point to the sweep's stamp under a constant twist
- ``keyframe_map``        the map scans are matched against: recent keyframes' points
- ``gmmsc``               false-match rejection by a mixture on pair distances (eq. 20-21)
- ``icp``                 what both ICPs share: parameters, result, a Gauss-Newton step
- ``robust_icp``          GMMSC x Huber Gauss-Newton ICP (eq. 22-26), the improved method's
- ``point_to_point_icp``  classic closed-form ICP, the baseline's
- ``recovery``            a correlative search where the ICP's fit is poor (not in the paper)

and what chains them:

- ``params``   every parameter of a front end, with its unit, range and default
- ``methods``  the two methods, :class:`ImprovedFrontEnd` and :class:`BaselineFrontEnd`, sweep by sweep

The loop over a log's inputs, the methods side by side, is :mod:`fmcwlog.pipeline.runner`.
"""
