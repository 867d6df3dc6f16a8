"""Logs in and outputs out: every file fmcwlog reads or writes goes through here.

- ``topics``           the names the log format fixes (topics, metadata records, frames)
- ``schemas``          the ``ros2msg`` schema texts from ``schemas/``
- ``messages``         ROS 2 messages as dicts and numpy arrays (PointCloud2, Odometry, ...)
- ``mcap_log``         the MCAP container: :class:`LogReader`, :class:`LogWriter`
- ``mcap_scan``        reading an MCAP file's records in one time-ordered pass
- ``bag_log``          rosbag2 folders and ROS 1 bags read through rosbags: :class:`BagReader`
- ``logs``             :func:`open_log`: an MCAP log or a bag, told apart by its first bytes
- ``topic_choice``     which topics a run reads: a scan topic and at most one motion prior
- ``sweeps``           a scan message decoded into a sweep, checked against physical bounds
- ``prior_gates``      the motion prior's impossible jumps, caught as they are read
- ``inputs``           what estimation reads, in time order: damaged messages skipped and counted
- ``calibration``      the calibration: a file, the ``fmcwlog.calibration`` record, the tf, in that order
- ``calibration_file`` calibration files, read and written
- ``tf_tree``          the LiDAR's mount from a log's ``/tf_static`` (and ``/tf``), frames chained
- ``carmen``           real 2-D laser logs (CARMEN, CMU course format), parsed
- ``carmen_import``    those logs written as fmcwlog logs
- ``outputs``          TUM, parquet, map_server maps, ``processed.mcap``
- ``map_files``        map_server maps read back as occupied and free cells
- ``atomic``           a temporary name, then a rename: nothing is seen half-written
- ``digest``           a log's SHA-256 (a file's, or a rosbag2 folder's files')
"""
