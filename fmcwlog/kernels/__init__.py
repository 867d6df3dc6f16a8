"""Kernels both ends share: small modules of pure functions (and small stateful helpers) on numpy arrays.

- ``nearest``      nearest-neighbour pairs under successive poses (both ICPs, the back end's registration)
- ``correlative``  exhaustive branch-and-bound search of a scan over a likelihood grid
- ``occupancy``    log-odds occupancy grid by ray casting
- ``voxel``        one point per voxel
- ``growing``      arrays that grow by amortised doubling
- ``compiled``     which kernels run (``FMCWLOG_KERNELS``: the compiled ``fmcwlog._core`` or numpy)

They know nothing of logs, files or ground truth: arrays in, arrays out, in the units and frames
each docstring gives.
"""
