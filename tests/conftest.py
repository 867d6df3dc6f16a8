"""Shared fixtures: short recordings made once per test session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from fmcwlog.api import ProcessOptions, process
from fmcwlog.sim import scenarios
from fmcwlog.sim.config import SimConfig, apply_overrides
from fmcwlog.sim.recorder import record

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SAMPLE_LOGS = ROOT / "sample_logs"

# Property tests draw fresh examples on each local run (that is how they find new failures), but
# CI must give the same verdict on the same commit: `.ci/run` picks the "ci" profile, which draws
# each test's examples from a seed fixed by the test itself.
settings.register_profile("ci", derandomize=True, print_blob=True)
settings.load_profile(os.environ.get("FMCWLOG_HYPOTHESIS_PROFILE", "default"))


def _record(tmp_path_factory, scenario: str, duration: float, seed: int = 0, **overrides) -> Path:
    cfg = apply_overrides(SimConfig(), {"run": {"duration": duration, "seed": seed}, **overrides})
    out = tmp_path_factory.mktemp(scenario) / f"{scenario}.mcap"
    record(scenarios.SCENARIOS[scenario](), cfg, out)
    return out


@pytest.fixture(scope="session")
def corridor_log(tmp_path_factory) -> Path:
    """26 s of the default scenario: the robot accelerates, drives 22 m and takes a corner."""
    return _record(tmp_path_factory, "corridor", 26.0)


@pytest.fixture(scope="session")
def crowd_log(tmp_path_factory) -> Path:
    return _record(tmp_path_factory, "crowd", 6.0)


@pytest.fixture(scope="session")
def shared_dir() -> Path:
    if not SHARED.is_dir():
        pytest.skip(f"{SHARED} is absent: the shared conformance logs and datasets live there")
    return SHARED


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
    return _record(tmp_path_factory, "long-corridor", 60.0)


@pytest.fixture(scope="session")
def dense_crowd_log(tmp_path_factory) -> Path:
    """25 s of the dense crowd: about half of the returns on walkers and carts, many crossing the beams."""
    return _record(tmp_path_factory, "dense-crowd", 25.0)
