"""The compiled robust ICP against its numpy reference where many pairs lie at exactly the same
distance (points on a lattice, the source moved by a fraction of its spacing, each point's nearest target
unique).

The kernel orders the distances by their bit patterns (the median and the weights' running minimum
read that order): ties and distances spanning many binades must give the reference's iterations, pairs
kept and EM fits exactly, the pose to 1e-9.
"""

from dataclasses import replace

import numpy as np
from helpers import needs_core
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from fmcwlog.frontend import robust_icp
from fmcwlog.frontend.gmmsc import GMMSCParams
from fmcwlog.frontend.icp import ICPParams
from fmcwlog.kernels import compiled


def _lattice_scene(seed: int, spacing: float, shift: tuple[float, float], n_source: int):
    """Target: walls of a room sampled on a lattice of ``spacing`` (m); source: ``n_source`` of those
    points moved by ``shift`` (m), so that many pairs share one distance."""
    rng = np.random.default_rng(seed)
    k = np.arange(-40, 41) * spacing
    wall = 40 * spacing
    target = np.concatenate([np.c_[k, np.full_like(k, wall)], np.c_[k, np.full_like(k, -wall)],
                             np.c_[np.full_like(k, wall), k], np.c_[np.full_like(k, -wall), k]])
    pick = rng.choice(len(target), size=min(n_source, len(target)), replace=False)
    source = target[np.sort(pick)] + np.asarray(shift)
    return source, target


@needs_core
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seed=st.integers(0, 2**32 - 1), spacing=st.sampled_from([0.05, 0.1, 0.25]),
       fx=st.sampled_from([0.0, 0.25, 0.375]), fy=st.sampled_from([0.0, 0.125, -0.25]),
       n_source=st.integers(12, 320), k=st.integers(1, 3), refit=st.sampled_from([0.25, 1.0]))
def test_tied_distances_give_the_reference(use, seed, spacing, fx, fy, n_source, k, refit):
    source, target = _lattice_scene(seed, spacing, (fx * spacing, fy * spacing), n_source)
    params = replace(ICPParams(), max_correspondence_distance=0.5, gmm_start_translation=0.05,
                     gmm_start_rotation=0.05, gmm_refit_ratio=refit, gmmsc=replace(GMMSCParams(), n_components=k))
    start = np.zeros(3)
    ref = robust_icp.register_numpy(source, cKDTree(target), target, start, params)
    # a registration whose answer moves by more than 1e-10 for a start 1e-12 away is rounding's to
    # decide (a flat cost along a wall): skipped, as in test_compiled_robust_icp
    nudged = robust_icp.register_numpy(source, cKDTree(target), target, start + 1e-12, params)
    assume(nudged.iterations == ref.iterations and nudged.n_gmm_fits == ref.n_gmm_fits
           and np.abs(nudged.pose - ref.pose).max() < 1e-10)
    use("compiled")
    assert compiled.core() is not None
    fast = robust_icp._register_compiled(compiled.core(), source, compiled.MapIndex(target), target, start, params,
                                         None, None, None)
    assert fast.iterations == ref.iterations
    assert fast.n_correspondences_kept == ref.n_correspondences_kept
    assert fast.n_gmm_fits == ref.n_gmm_fits
    assert fast.converged == ref.converged
    np.testing.assert_allclose(fast.pose, ref.pose, rtol=0, atol=1e-9)

