"""The mount check's nearest distances: the compiled kernels' grid against the KD-tree (the reference),
on generated sweeps and motions, to the rounding of the moved points; and the same verdicts."""

import numpy as np
from helpers import needs_core, wall_scene
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmcwlog.frontend.mirror_check import Witness


@needs_core
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(10, 400), dx=st.floats(-1.0, 1.0), dy=st.floats(-1.0, 1.0),
       dth=st.floats(-3.2, 3.2), cap=st.sampled_from([0.05, 0.3, 1.0]))
def test_grid_distances_are_the_trees(use, seed, n, dx, dy, dth, cap):
    pts, target = wall_scene(seed, 6, 800, n, (0.0, 0.0, 0.0), n // 10)
    motion = np.array([dx, dy, dth])
    use("numpy")
    ref = Witness(target, cap).distances(pts, motion)
    use("compiled")
    fast = Witness(target, cap).distances(pts, motion)
    # beyond the cap both say inf; within it the same distance but for a point within rounding of the cap
    near = np.isfinite(ref) & (ref < cap * (1 - 1e-9))
    np.testing.assert_allclose(fast[near], ref[near], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.minimum(fast, cap) >= cap * (1 - 1e-9), np.minimum(ref, cap) >= cap * (1 - 1e-9))
