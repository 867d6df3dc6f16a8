"""The Doppler fit again without the movers, its gate from the sweep's spread (:func:`~fmcwlog.frontend.egomotion.refit_static`).

A coarse Doppler (noise 0.1 m/s before 0.25 m/s steps, as bench/sensors/worse-doppler.toml) biases
the first fit two ways: movers close to static pass its fixed 0.15 m/s gate, and a gate narrower
than the residuals' spread truncates their quantised clumps unevenly. The ablation compares the
Doppler velocity alone (``A⁻¹ v_s``) with the truth's motion over each sweep, as
bench/accuracy_cases.py does, with the refit on and off.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from helpers import truth_twist

from fmcwlog.api import ProcessOptions, process
from fmcwlog.frontend import methods
from fmcwlog.frontend.egomotion import fit_sensor_velocity_numpy, refit_static, unit_bearings_numpy
from fmcwlog.pipeline.params import ProcessParams


def _sweep(rng: np.random.Generator, v_true: np.ndarray, n_static: int = 800, n_movers: int = 60):
    """A sweep's bearings (N, 2) and coarse Doppler (N,) seen at lidar velocity ``v_true`` (m/s): static
    points all round, and a walker's points ahead-left whose own velocity makes them look 0.1 m/s off
    static (inside the first fit's gate). Returns (u, v_r, moving)."""
    ang = np.concatenate([rng.uniform(-np.pi, np.pi, n_static), rng.uniform(0.3, 0.5, n_movers)])
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    v_r = -(u @ v_true) + rng.normal(0.0, 0.1, len(ang))
    moving = np.arange(len(ang)) >= n_static
    v_r[moving] += 0.1
    return u, np.round(v_r / 0.25) * 0.25, moving


def test_refit_without_movers_and_with_the_sweeps_spread_removes_the_bias():
    rng = np.random.default_rng(3)
    v_true = np.array([1.0, 0.3])
    errs_first, errs_refit, errs_fixed_gate = [], [], []
    for _ in range(200):
        u, v_r, moving = _sweep(rng, v_true)
        xy = u * 5.0
        first = fit_sensor_velocity_numpy(xy, v_r, bearings=u, prior=v_true)
        errs_first.append(first.v_sensor - v_true)
        errs_refit.append(refit_static(u, v_r, first, moving).v_sensor - v_true)
        # the movers left out, the gate kept at 0.15 m/s: the truncation's part of the bias stays
        errs_fixed_gate.append(refit_static(u, v_r, first, moving, scale_gate=1e-6).v_sensor - v_true)
    first_bias, refit_bias = np.abs(np.mean(errs_first, 0)), np.abs(np.mean(errs_refit, 0))
    assert np.hypot(*refit_bias) < 0.3 * np.hypot(*first_bias)
    assert np.hypot(*refit_bias) < 0.004  # m/s; the 800 points' noise alone averages to ~0.0004 over 200 sweeps
    assert np.sqrt(np.mean(np.square(errs_refit))) < np.sqrt(np.mean(np.square(errs_first)))
    assert np.sqrt(np.mean(np.square(errs_refit))) < np.sqrt(np.mean(np.square(errs_fixed_gate)))


def test_a_doppler_fine_enough_for_the_first_gate_keeps_the_first_fit():
    # the paper's Table 1 channel (noise 0.02 m/s, 0.1 m/s steps): 3 robust sigmas stay under 0.15 m/s
    rng = np.random.default_rng(5)
    ang = rng.uniform(-np.pi, np.pi, 800)
    u = np.stack([np.cos(ang), np.sin(ang)], -1)
    v_r = np.round((-(u @ np.array([1.0, 0.3])) + rng.normal(0.0, 0.02, 800)) / 0.1) * 0.1
    first = fit_sensor_velocity_numpy(u * 5.0, v_r, bearings=u)
    assert refit_static(u, v_r, first, np.zeros(800, bool)) is first


def test_refit_keeps_a_failed_fit_and_a_sweep_without_static_points():
    rng = np.random.default_rng(0)
    u, v_r, moving = _sweep(rng, np.array([0.5, 0.0]))
    first = fit_sensor_velocity_numpy(u * 5.0, v_r, bearings=u)
    assert refit_static(u, v_r, first, np.ones(len(v_r), bool)) is first  # everything moving: nothing to refit
    failed = fit_sensor_velocity_numpy(u[:2] * 5.0, v_r[:2])
    assert refit_static(u[:2], v_r[:2], failed, np.zeros(2, bool)) is failed
    assert unit_bearings_numpy(u * 5.0) == pytest.approx(u)


def _doppler_errors(log: Path, out: Path, refit: bool, monkeypatch) -> np.ndarray:
    """(N, 2) error of Doppler's ``(v, ω)`` alone (m/s, rad/s) against the truth over each sweep."""
    rows = []
    inner = methods.ImprovedFrontEnd.estimate_motion

    def keep(self, sweep, prior):
        m = inner(self, sweep, prior)
        if m.doppler is not None and m.doppler.usable and prior.twist is not None:
            rows.append((sweep.stamp_ns, prior.span, *np.linalg.solve(self.design, m.doppler.v_sensor)))
        return m

    monkeypatch.setattr(methods.ImprovedFrontEnd, "estimate_motion", keep)
    params = dataclasses.replace(ProcessParams(), doppler_refit=refit)
    process(log, out, ProcessOptions(methods=("improved",), backend="none", params=params))
    k = np.array(rows, float)
    return k[:, 2:4] - truth_twist(log, k[:, 0], k[:, 1])


def test_the_refit_takes_the_bias_out_of_a_coarse_doppler(coarse_doppler_log, tmp_path, monkeypatch):
    off = _doppler_errors(coarse_doppler_log, tmp_path / "off", False, monkeypatch)
    on = _doppler_errors(coarse_doppler_log, tmp_path / "on", True, monkeypatch)
    bias_off, bias_on = np.mean(off, 0), np.mean(on, 0)
    rms_off, rms_on = np.sqrt(np.mean(off**2, 0)), np.sqrt(np.mean(on**2, 0))
    # measured (20 s, seed 0): off, bias +1.03 cm/s and +35 mrad/s, RMS 2.26 cm/s and 60 mrad/s;
    # on, -0.09 cm/s and +4.8 mrad/s, RMS 1.26 cm/s and 22 mrad/s
    assert bias_off[0] > 0.005 and bias_off[1] > 0.015  # the fault: a coarse Doppler's fit leans one way
    assert np.all(np.abs(bias_on) < 0.3 * np.abs(bias_off))  # measured 0.09, 0.14
    assert np.all(rms_on < 0.8 * rms_off)  # measured 0.56, 0.37
