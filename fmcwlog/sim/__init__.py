"""``fmcwlog record``: a planar world, a car-like robot with rear-wheel encoders and an FMCW LiDAR.

- ``config``     parameters (the paper's Table 1 as defaults) and their overrides
- ``world``      walls, labelled features, movers and the route; world files
- ``scenarios``  the built-in worlds
- ``route``      the smooth path the robot follows and its speed profile
- ``movers``     where people and carts are, and how fast they go
- ``chassis``    Ackermann rear axle and quantised wheel encoders (paper eq. 9)
- ``lidar``      ray casting, range noise and per-point Doppler
- ``recorder``   runs the simulation and writes the log
"""
