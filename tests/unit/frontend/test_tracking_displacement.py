"""Free space from the last sweeps' rays: a walker crossing the beams broadside far ahead, which
Doppler never sees and the map has never seen free, is caught from its displacement alone; a static
room seen from a robot driving and turning through it gets no label.

Sweeps and truth come from the simulator's ray caster (:class:`fmcwlog.sim.lidar.FmcwLidar`); the
robot drives at a known twist, so its pose and ``ε = v_r + uᵀv_s`` are known exactly; the tracker is
never handed a scan (:meth:`MoverTracker.add_scan`), so the map's free space cannot fire.
"""

from __future__ import annotations

import numpy as np
import pytest

from fmcwlog.frontend.segmentation import SegmentationParams
from fmcwlog.frontend.tracking import MoverTracker, TrackingParams
from fmcwlog.sim.chassis import BodyState
from fmcwlog.sim.config import SensorConfig
from fmcwlog.sim.lidar import FmcwLidar
from fmcwlog.sim.movers import Mover

HALL = [[-4, -8, 24, -8], [24, -8, 24, 8], [24, 8, -4, 8], [-4, 8, -4, -8]]  # walls, m
V_TH = SegmentationParams().v_th


def _drive(movers, params, omega=0.0, sweeps=60, walls=HALL):
    """Per sweep (truth, labelled, ε) for a robot at 1 m/s (yaw rate ``omega``, rad/s) from (-2, 0)."""
    lidar = FmcwLidar(SensorConfig(mount_x=0.0), np.array(walls, float), movers)
    rng = np.random.default_rng(3)
    tracker = MoverTracker(params)
    n = lidar.beam_time.size
    out = []
    for k in range(sweeps):
        t = 0.1 * k + lidar.beam_time
        yaw = omega * t
        if omega:
            x, y = -2.0 + np.sin(yaw) / omega, (1.0 - np.cos(yaw)) / omega
        else:
            x, y = t - 2.0, 0.0 * t
        state = BodyState(t, x, y, yaw, np.ones(n), np.full(n, omega), t)
        sweep = lidar.sweep(state, t, rng)
        xy, truth = np.column_stack([sweep.x, sweep.y]), sweep.moving.astype(bool)
        eps = sweep.velocity + xy[:, 0] / np.hypot(*xy.T)  # ε = v_r + uᵀv_s, v_s = (1, 0) m/s
        s = 0.1 * k
        pose = np.array([-2.0 + np.sin(omega * s) / omega if omega else s - 2.0,
                         (1.0 - np.cos(omega * s)) / omega if omega else 0.0, omega * s])
        labelled = tracker.segment(xy, sweep.t, eps, s, pose, (1.0, omega), np.zeros(3), None, SegmentationParams())
        out.append((truth, labelled, eps))
    return out


# broadside 10-14 m ahead at 0.8 m/s: |uᵀv| stays under v_th for the whole crossing (checked)
WALKER = Mover("person", [[12.0, -2.5], [12.0, 2.5]], 0.8)


@pytest.mark.parametrize("on", [True, False])
def test_walker_crossing_unseen_is_caught_from_its_displacement(on):
    params = TrackingParams() if on else TrackingParams(displacement_sweeps=0)
    sweeps = _drive([WALKER], params, sweeps=40)
    assert all(np.all(np.abs(eps[truth]) < V_TH) for truth, _, eps in sweeps)  # Doppler never sees it
    share = [labelled[truth].mean() for truth, labelled, _ in sweeps if truth.any()]
    assert len(share) == len(sweeps)
    assert not any(labelled[~truth].any() for truth, labelled, _ in sweeps)
    if on:  # from 0.5 s on (the first comparison is 0.2 s back), every sweep
        assert min(share[5:]) >= 0.9, np.round(share, 2)
    else:  # no map, no Doppler: nothing labels it
        assert max(share) == 0.0


@pytest.mark.parametrize("omega", [0.0, 0.5])
def test_static_hall_seen_driving_and_turning_gets_no_label(omega):
    # a pillar and the hall's walls, seen from 1 m/s straight or on a 2 m circle: the rays of the
    # sweeps before pass beside the pillar and along the walls at grazing incidence, never through them
    walls = HALL + [[6.0, 2.0, 6.6, 2.0], [6.6, 2.0, 6.6, 2.6], [6.6, 2.6, 6.0, 2.6], [6.0, 2.6, 6.0, 2.0]]
    sweeps = _drive([], TrackingParams(), omega=omega, walls=walls)
    assert sum(int(labelled.sum()) for _, labelled, _ in sweeps) == 0
