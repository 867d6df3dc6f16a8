"""Shared fixtures: short recordings made once per test session.

Layout: ``unit/<layer>/`` (one folder per layer of the package: core, sim, io, frontend, backend,
evaluation, fleet, cli), ``integration/`` (end to end: process, report, run and fleet on logs, the
command line in a subprocess), ``fuzz/`` (generated and damaged inputs). Markers (pyproject.toml):
``slow`` (end to end, or seconds each; ``python -m pytest -m "not slow"`` is the quick run),
``needs_datasets`` and ``needs_conformance`` (data in ``../shared`` beside the checkout, read
through ``helpers.shared_file``). Constants and helpers the tests share are in helpers.py (on the
path by ``pythonpath`` in pyproject.toml): a test imports ``helpers``, never ``conftest``.
"""

from __future__ import annotations

import os
from pathlib import Path

import helpers
import pytest
from helpers import SAMPLE_LOGS, record_scenario
from hypothesis import settings

from fmcwlog.api import ProcessOptions, process

# Property tests draw fresh examples on each local run (that is how they find new failures), but
# CI must give the same verdict on the same commit: `.ci/run` picks the "ci" profile, which draws
# each test's examples from a seed fixed by the test itself.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.load_profile(os.environ.get("FMCWLOG_HYPOTHESIS_PROFILE", "default"))


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    helpers._current_test = item  # for helpers.shared_file: a test reading ../shared must be marked so


def pytest_runtest_teardown(item):
    helpers._current_test = None


@pytest.fixture
def use(monkeypatch):
    """``use("compiled")`` or ``use("numpy")``: the kernel switch as a fresh process would set it
    (the compiled module, or None)."""
    from fmcwlog.kernels import compiled

    def select(kind):
        monkeypatch.setenv(compiled.ENV, kind)
        monkeypatch.setattr(compiled, "_chosen", None)
        monkeypatch.setattr(compiled, "_core", None)
        return compiled.core()
    return select


@pytest.fixture(scope="session")
def corridor_log(tmp_path_factory) -> Path:
    """26 s of the default scenario: the robot accelerates, drives 22 m and takes a corner."""
    return record_scenario(tmp_path_factory, "corridor", 26.0)


@pytest.fixture(scope="session")
def crowd_log(tmp_path_factory) -> Path:
    return record_scenario(tmp_path_factory, "crowd", 6.0)


@pytest.fixture(scope="session")
def processed(tmp_path_factory) -> dict[str, Path]:
    """The two committed sample logs, processed once with both methods."""
    out = {}
    for name in ("corridor_30s", "crowd_30s"):
        d = tmp_path_factory.mktemp(name) / "out"
        process(SAMPLE_LOGS / f"{name}.mcap", d, ProcessOptions())
        out[name] = d
    return out


@pytest.fixture(scope="session")
def long_corridor_log(tmp_path_factory) -> Path:
    """60 s of the 100 m bare corridor: geometry alone cannot fix the position along it."""
    return record_scenario(tmp_path_factory, "long-corridor", 60.0)


@pytest.fixture(scope="session")
def dense_crowd_log(tmp_path_factory) -> Path:
    """25 s of the dense crowd: about half of the returns on walkers and carts, many crossing the beams."""
    return record_scenario(tmp_path_factory, "dense-crowd", 25.0)


@pytest.fixture(scope="session")
def coarse_doppler_log(tmp_path_factory) -> Path:
    """20 s of the ``crowd`` scenario with a coarse Doppler (seed 0): noise 0.1 m/s before 0.25 m/s
    steps (bench/sensors/worse-doppler.toml), against the default 0.02 and 0.1."""
    from fmcwlog.sim import scenarios
    from fmcwlog.sim.config import SimConfig, apply_overrides
    from fmcwlog.sim.recorder import record

    log = tmp_path_factory.mktemp("coarse") / "crowd.mcap"
    cfg = apply_overrides(SimConfig(), {"sensor": {"doppler_sigma": 0.1, "doppler_resolution": 0.25},
                                        "run": {"duration": 20.0, "seed": 0}}).validate()
    record(scenarios.SCENARIOS["crowd"](), cfg, log)
    return log
