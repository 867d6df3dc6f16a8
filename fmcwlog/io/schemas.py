"""The ``ros2msg`` schema texts of the log format, from the ``.msg`` files in ``schemas/``.

A schema is the type's own .msg text followed by each dependency, depth first,
after a line of 80 ``=`` and ``MSG: pkg/msg/Type``, the way ROS 2's MCAP
storage plugin (rosbag2) writes them, so logs open in Foxglove and rosbags.
"""

from __future__ import annotations

import re
from pathlib import Path

SCHEMA_DIR = Path(__file__).resolve().parents[1] / "schemas"

_SEPARATOR = "=" * 80
_FIELD_TYPE = re.compile(r"^\s*([A-Za-z_][\w/]*)(\[\d*\])?\s+\w+")
_PRIMITIVES = {
    "bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32",
    "int64", "uint64", "float32", "float64", "string", "wstring",
}


def _msg_path(datatype: str) -> Path:
    pkg, _, name = datatype.split("/")
    return SCHEMA_DIR / pkg / "msg" / f"{name}.msg"


def _dependencies(datatype: str, text: str) -> list[str]:
    """Full names of the non-primitive types a .msg text refers to."""
    pkg = datatype.split("/")[0]
    deps = []
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        if "=" in line:  # a constant
            continue
        m = _FIELD_TYPE.match(line)
        if not m:
            continue
        t = m.group(1)
        if t in _PRIMITIVES:
            continue
        if t == "Header":
            t = "std_msgs/Header"
        parts = t.split("/")
        full = f"{pkg}/msg/{t}" if len(parts) == 1 else f"{parts[0]}/msg/{parts[-1]}"
        deps.append(full)
    return deps


def message_definition(datatype: str) -> str:
    """The ``ros2msg`` schema text of ``datatype`` (e.g. ``sensor_msgs/msg/PointCloud2``).

    The type's own .msg text followed by each dependency, depth first, after a
    line of 80 ``=`` and ``MSG: pkg/msg/Type``, as ``rosbag2`` writes them.
    """
    own = _msg_path(datatype).read_text()
    seen: list[str] = []

    def visit(t: str, text: str) -> None:
        for dep in _dependencies(t, text):
            if dep not in seen:
                seen.append(dep)
                visit(dep, _msg_path(dep).read_text())

    visit(datatype, own)
    parts = [own.rstrip("\n")]
    for dep in seen:
        parts.append(f"{_SEPARATOR}\nMSG: {dep}\n{_msg_path(dep).read_text().rstrip(chr(10))}")
    return "\n".join(parts) + "\n"
