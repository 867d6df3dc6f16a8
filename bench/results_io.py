"""What the benchmark scripts share: whether the KISS-ICP peer can run, and writing a result table."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def kiss_icp_available(wanted: bool) -> bool:
    """True if the peer is wanted and kiss-icp imports; says why it is skipped otherwise."""
    if not wanted:
        return False
    try:
        import kiss_icp  # noqa: F401
    except ImportError:
        print("kiss-icp is not installed (pip install -e '.[bench]'): the peer is skipped", file=sys.stderr)
        return False
    return True


def write_results(out: Path, name: str, markdown: str, doc: dict) -> None:
    """``out/name.md`` and ``out/name.json``, and the table printed."""
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.md").write_text(markdown)
    (out / f"{name}.json").write_text(json.dumps(doc, indent=2))
    print()
    print(markdown)
    print(f"wrote {out / (name + '.md')} and .json")
