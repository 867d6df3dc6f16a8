"""The runner gives the heap's freed pages back to the system as a long log goes by, and the
estimates do not depend on it."""

from __future__ import annotations

from pathlib import Path

from fmcwlog.api import ProcessOptions, process
from fmcwlog.pipeline import runner

LOG = Path(__file__).resolve().parents[3] / "sample_logs" / "corridor_30s.mcap"  # 300 sweeps at 10 Hz


def _run(out: Path) -> dict[str, bytes]:
    process(LOG, out, ProcessOptions(methods=("baseline",), backend="none"), jobs=1)
    return {p.name: p.read_bytes() for p in sorted(out.iterdir()) if p.suffix == ".tum"}


def test_freed_memory_is_given_back_every_so_many_sweeps(tmp_path, monkeypatch):
    calls: list[int] = []
    monkeypatch.setattr(runner, "release_freed_memory", lambda: calls.append(1) or True)
    monkeypatch.setattr(runner, "RELEASE_EVERY_SWEEPS", 70)
    released = _run(tmp_path / "released")
    assert len(calls) == 300 // 70  # after sweeps 70, 140, 210 and 280
    monkeypatch.setattr(runner, "RELEASE_EVERY_SWEEPS", 10**9)
    assert _run(tmp_path / "kept") == released  # the same estimates, byte for byte
