"""A result whose processed.mcap messages were encoded in the child writes the bytes of one encoded here."""

from __future__ import annotations

import pickle

import numpy as np

from fmcwlog.io.outputs import ProcessOutputs, sweep_messages
from fmcwlog.pipeline.method_process import EncodedResult
from fmcwlog.types import SweepResult


def _results(seed: int) -> list[SweepResult]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(12):
        n, m = int(rng.integers(0, 50)), int(rng.integers(0, 5))
        doppler, segmented = bool(k % 3), bool(k % 2)
        out.append(SweepResult(
            "improved", 10**9 + k * 10**8, rng.normal(size=3), (float(rng.normal()), float(rng.normal())),
            rng.normal(size=(2, 2)) if doppler else None, rng.normal(size=(3, 3)) if k else None,
            int(rng.integers(0, 20)), n, m, float(rng.random()), rng.normal(size=(n, 2)),
            rng.normal(size=n) if doppler else None, rng.normal(size=(m, 2)), rng.normal(size=m) if doppler else None,
            rng.random(n + m) < 0.2, segmented, bool(k % 4 == 0)))
    return out


def _written(folder, results, encoded: bool) -> bytes:
    out = ProcessOutputs(folder, ("improved",), np.array([0.3, 0.1, 0.2]), publish_period=0.3)
    for r in results:
        if encoded:
            light = pickle.loads(pickle.dumps(EncodedResult.of(r)))  # as the pipe carries it
            out.add(light, light.messages)
        else:
            out.add(r)
        out.end_sweep(r.stamp_ns, {})
    out.finish({})
    return (folder / "processed.mcap").read_bytes()


def test_same_bytes_as_encoding_here(tmp_path):
    for seed in range(3):
        results = _results(seed)
        (tmp_path / f"a{seed}").mkdir()
        (tmp_path / f"b{seed}").mkdir()
        assert _written(tmp_path / f"a{seed}", results, True) == _written(tmp_path / f"b{seed}", results, False)


def test_light_result_keeps_what_the_parent_reads():
    r = _results(0)[5]
    light = EncodedResult.of(r)
    assert light.messages == sweep_messages(r)
    assert [t for t, _, _ in light.messages] == ["/improved/odom", "/improved/points/static",
                                                  "/improved/points/moving", "/improved/moving_labels"]
    for name in ("method", "stamp_ns", "twist", "iterations", "correspondences", "moving_points", "ms", "keyframe",
                 "searched", "recovered", "segmented"):
        assert getattr(light, name) == getattr(r, name)
    assert np.array_equal(light.pose, r.pose) and light.static_map_xy.shape == (0, 2)
