"""The fusion's weights from the noise the sweeps show (:class:`~fmcwlog.frontend.twist_fusion.ObservedNoise`).

Ablation on a recording with a coarse Doppler (noise 0.1 m/s before 0.25 m/s steps, as
bench/sensors/worse-doppler.toml): with the nominal weights the Doppler fit's claimed covariance
(a few mm/s) takes the fused twist almost whole, and it errs like Doppler (several times the
wheels); with the weights from the observed disagreement it stays near the wheels (v below them). Each sweep's
twist is compared with the truth over the same interval, as bench/accuracy_cases.py does.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from helpers import truth_twist

from fmcwlog.api import ProcessOptions, process
from fmcwlog.frontend import methods
from fmcwlog.frontend.twist_fusion import ObservedNoise, WheelNoise, base_variances
from fmcwlog.pipeline.params import ProcessParams

START = 30  # sweeps left out at the start: the evidence is in after about 2.3 s (a vote's window, 10 sweeps compared)


def _twist_errors(log: Path, out: Path, adapt_rate: float, monkeypatch,
                  refit: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """RMS error of ``(v, ω)`` (m/s, rad/s) of the fused twist and of the wheels' over the sweeps with
    both, from the :data:`START`-th on (``refit``: the front end's ``doppler_refit``)."""
    rows = []
    inner = methods.ImprovedFrontEnd.estimate_motion

    def keep(self, sweep, prior):
        m = inner(self, sweep, prior)
        if m.fused is not None and prior.twist is not None:
            rows.append((sweep.stamp_ns, prior.span, *m.fused.twist, *prior.twist))
        return m

    monkeypatch.setattr(methods.ImprovedFrontEnd, "estimate_motion", keep)
    params = ProcessParams()
    params = dataclasses.replace(params, wheel_noise=dataclasses.replace(params.wheel_noise, adapt_rate=adapt_rate),
                                 doppler_refit=refit)
    process(log, out, ProcessOptions(methods=("improved",), backend="none", params=params))
    k = np.array(rows, float)[START:]
    truth = truth_twist(log, k[:, 0], k[:, 1])
    rms = [np.sqrt(np.mean((k[:, cols] - truth) ** 2, axis=0)) for cols in (slice(2, 4), slice(4, 6))]
    return rms[0], rms[1]


def test_observed_weights_keep_a_coarse_doppler_near_the_wheels(coarse_doppler_log, tmp_path, monkeypatch):
    # the first Doppler fit alone (no refit), which claims far less than it errs on a coarse channel:
    # measured (20 s, seed 0, from the 30th sweep): off, fused v 2.05 cm/s and ω 58.7 mrad/s against the
    # wheels' 0.41 and 5.8; on, 0.31 cm/s and 7.7 mrad/s (v below the wheels', ω 1.3 times theirs)
    off, wheels = _twist_errors(coarse_doppler_log, tmp_path / "off", 0.0, monkeypatch, refit=False)
    on, wheels_on = _twist_errors(coarse_doppler_log, tmp_path / "on", WheelNoise().adapt_rate, monkeypatch, refit=False)
    np.testing.assert_allclose(wheels, wheels_on)  # the same wheels both times
    assert off[0] > 3 * wheels[0] and off[1] > 3 * wheels[1]  # the nominal weights follow the coarse Doppler
    assert on[0] < 0.3 * off[0] and on[1] < 0.3 * off[1]  # measured 0.15, 0.13
    assert on[0] < 1.2 * wheels[0] and on[1] < 2.0 * wheels[1]  # measured 0.77, 1.32


def test_observed_noise_separates_the_sources():
    # three sources with independent errors of known spread: the hat returns each one's mean square
    rng = np.random.default_rng(1)
    noise = ObservedNoise(0.0005)
    sd = (0.02, 0.05)  # Doppler's (m/s, rad/s)
    sw = (0.008, 0.015)  # the wheels'
    ss = (0.02, 0.04)  # the scans'
    for _ in range(20000):
        truth = np.array([rng.normal(), 0.3])  # ω steady: a step in it leaves the interval out
        noise.add(tuple(truth + rng.normal(0, sd)), tuple(truth + rng.normal(0, sw)), tuple(truth + rng.normal(0, ss)))
    (dv, dw), (wv, ww) = noise.mean_squares()
    assert math.sqrt(dv) == pytest.approx(sd[0], rel=0.15) and math.sqrt(dw) == pytest.approx(sd[1], rel=0.15)
    assert math.sqrt(wv) == pytest.approx(sw[0], rel=0.3) and math.sqrt(ww) == pytest.approx(sw[1], rel=0.3)


def _fed(noise: ObservedNoise, x_d, x_w, x_s, claim, n: int) -> ObservedNoise:
    """``noise`` given the same interval ``n`` times (the first is left out: no step in ω known yet)."""
    for _ in range(n):
        noise.add(x_d, x_w, x_s, claim)
    return noise


def test_observed_weights_only_widen_doppler_and_narrow_the_wheels():
    wn = WheelNoise()
    a = [[1.0, -0.1], [0.0, 0.3]]
    c_d = [[1e-5, 2e-6], [2e-6, 3e-5]]
    claim = base_variances(c_d, a)
    assert ObservedNoise(0.1, 6.5, 3).weights(c_d, a, (0.05**2, 0.05**2), wn) == (c_d, (0.05**2, 0.05**2))
    # Doppler alone off by (0.2, 0.3), thousands of times its claim: its variance grows, the correlation kept
    noise = _fed(ObservedNoise(0.1, 6.5, 3), (1.2, 0.3), (1.0, 0.0), (1.0, 0.0), (claim[0], claim[2]), 4)
    assert noise.adapting() == (True, True)
    got_d, got_w = noise.weights(c_d, a, (0.05**2, 0.05**2), wn)
    assert got_w == (wn.speed_min**2, wn.yaw_rate_min**2)  # the wheels agree with the scans: their floors
    b = np.linalg.solve(np.array(a), np.linalg.solve(np.array(a), np.array(got_d)).T)  # A⁻¹ C A⁻ᵀ
    assert b[0, 0] == pytest.approx(0.2**2) and b[1, 1] == pytest.approx(0.3**2)
    b0 = np.linalg.solve(np.array(a), np.linalg.solve(np.array(a), np.array(c_d)).T)
    corr = b0[0, 1] / math.sqrt(b0[0, 0] * b0[1, 1])
    assert b[0, 1] / math.sqrt(b[0, 0] * b[1, 1]) == pytest.approx(corr)


def test_the_weights_move_only_on_significant_evidence():
    wn = WheelNoise()
    a = [[1.0, -0.1], [0.0, 0.3]]
    c_d = [[1e-4, 0.0], [0.0, 1e-4]]
    b = base_variances(c_d, a)
    claim = (b[0], b[2])
    sd = (math.sqrt(claim[0]), math.sqrt(claim[1]))
    # Doppler off by twice its claimed standard deviation (4 times the variance): below the gate, nominal
    noise = _fed(ObservedNoise(0.1, 6.5, 3), (1.0 + 2 * sd[0], 2 * sd[1]), (1.0, 0.0), (1.0, 0.0), claim, 20)
    assert noise.ratio() == pytest.approx(4.0)
    assert noise.adapting() == (False, False)
    assert noise.weights(c_d, a, (0.05**2, 0.05**2), wn) == (c_d, (0.05**2, 0.05**2))
    # three times (9): on; not before min_sweeps are in (the first interval is left out: no step known)
    noise = ObservedNoise(0.1, 6.5, 3)
    for i in range(4):
        assert noise.adapting() == (False, False), i
        noise.add((1.0 + 3 * sd[0], 3 * sd[1]), (1.0, 0.0), (1.0, 0.0), claim)
    assert noise.adapting() == (True, True)
    # hysteresis: it stays on at 4 (above half the gate), and goes off at 2
    _fed(noise, (1.0 + 2 * sd[0], 2 * sd[1]), (1.0, 0.0), (1.0, 0.0), claim, 100)
    assert noise.ratio() == pytest.approx(4.0, rel=1e-3) and noise.adapting() == (True, True)
    _fed(noise, (1.0 + math.sqrt(2) * sd[0], math.sqrt(2) * sd[1]), (1.0, 0.0), (1.0, 0.0), claim, 100)
    assert noise.adapting() == (False, False)


def test_a_faulty_wheel_does_not_move_the_weights():
    # the wheels off, Doppler and the scans agreeing: the hat puts the error on the wheels, Doppler keeps its
    # claim and the wheels their nominal (larger than observed is never taken)
    wn = WheelNoise()
    a = [[1.0, -0.1], [0.0, 0.3]]
    c_d = [[1e-5, 0.0], [0.0, 3e-5]]
    b = base_variances(c_d, a)
    noise = _fed(ObservedNoise(0.1, 6.5, 3), (1.0, 0.0), (0.5, 0.2), (1.0, 0.0), (b[0], b[2]), 20)
    assert noise.adapting() == (False, False)
    assert noise.weights(c_d, a, (0.05**2, 0.05**2), wn) == (c_d, (0.05**2, 0.05**2))
    assert ObservedNoise(0.1, 6.5, 3).ratio() != ObservedNoise(0.1, 6.5, 3).ratio()  # NaN before any sweep


def test_a_step_in_the_wheels_yaw_rate_leaves_the_interval_out():
    noise = ObservedNoise(0.5)
    noise.add((1.0, 0.0), (1.0, 0.0), (1.0, 0.0))
    noise.add((1.0, 0.0), (1.0, 0.0), (1.0, 0.0))
    noise.add((1.0, 0.9), (1.0, 0.5), (1.0, 0.5))  # a corner starts: the sources disagree, whatever their noise
    assert noise.mean_squares() == ((0.0, 0.0), (0.0, 0.0))
    noise.add((1.0, 0.9), (1.0, 0.5), (1.0, 0.5))  # on the arc: counted
    assert noise.mean_squares()[0][1] > 0.0
