"""Ablation on a log: the end of an aisle at 3 m/s, with and without the wheels' motion within a sweep.

The warehouse's first U-turn comes after 40 s of aisle at 3 m/s. Its sweeps that start or end the turn
see a yaw-rate step of 1.5 rad/s inside them; de-skewed with one twist they are matched with their far
points decimetres off, and the front end's pose at such a sweep jumps by tens of mrad and back at the
next. Asserted: the largest error of the front end's yaw change from one sweep to the next (against the
log's ground truth), which the wheels' motion takes from tens of mrad to a few.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import ground_truth, record_scenario, tum

from fmcwlog.api import ProcessOptions, process
from fmcwlog.pipeline.params import load_params

pytestmark = pytest.mark.slow  # a 46 s log recorded and processed twice


@pytest.fixture(scope="module")
def u_turn_log(tmp_path_factory):
    return record_scenario(tmp_path_factory, "warehouse", 46.0, robot={"speed": 3.0})


def _worst_yaw_step_error(log, out, motion: str) -> float:
    """The largest |error| (rad) of the front end's yaw change between consecutive sweeps."""
    process(log, out, ProcessOptions(methods=("improved",), backend="none",
                                     params=load_params({"deskew_motion": motion})), force=True)
    est, gt = tum(out / "improved.tum"), ground_truth(log)
    true_yaw = np.interp(est[:, 0], gt[:, 0], np.unwrap(gt[:, 3]))
    err = np.diff(np.unwrap(est[:, 3])) - np.diff(true_yaw)
    return float(np.abs(err).max())


def test_wheels_motion_takes_out_the_yaw_step_at_a_u_turn(u_turn_log, tmp_path):
    wheels = _worst_yaw_step_error(u_turn_log, tmp_path / "wheels", "wheels")
    twist = _worst_yaw_step_error(u_turn_log, tmp_path / "twist", "twist")
    assert wheels < 0.006 and twist > 0.015, (wheels, twist)  # measured 2.7 mrad with the wheels, 33.7 without
