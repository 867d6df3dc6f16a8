"""No dead code in the package: every name vulture finds unused is either gone or in the whitelist with why.

A second reader of the whole package (vulture's own analysis, not ours) at its 60 % confidence
floor: unused functions, classes, methods, attributes, variables, imports and unreachable code.
"""

from __future__ import annotations

from pathlib import Path

import pytest

vulture = pytest.importorskip("vulture", reason="vulture is in the test extras: pip install '.[test]'")

ROOT = Path(__file__).resolve().parents[1]


def test_vulture_finds_no_unused_code():
    v = vulture.Vulture()
    v.scavenge([str(ROOT / "fmcwlog"), str(Path(__file__).with_name("vulture_whitelist.py"))])
    unused = [f"{item.filename.relative_to(ROOT)}:{item.first_lineno}: {item.message}"
              for item in v.get_unused_code(min_confidence=60)]
    assert unused == []


def test_vulture_sees_dead_code(tmp_path):
    """The check finds what it should: an unused function in a module of its own."""
    (tmp_path / "m.py").write_text("def used():\n    return 1\n\n\ndef never_called():\n    return 2\n\n\nused()\n")
    v = vulture.Vulture()
    v.scavenge([str(tmp_path)])
    assert [item.name for item in v.get_unused_code(min_confidence=60)] == ["never_called"]
