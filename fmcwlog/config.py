"""Config files and ``--set SECTION.NAME=VALUE`` overrides, shared by every command.

Values are coerced to the type of the dataclass field they set, so a typo or a
wrong type is caught with a message naming the parameter.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
import typing
from pathlib import Path
from typing import Any

import yaml

from .errors import ConfigError


def parse_set_option(items: tuple[str, ...]) -> dict[str, dict[str, str]]:
    """``("sensor.range_sigma=0.03", ...)`` -> ``{"sensor": {"range_sigma": "0.03"}}``."""
    out: dict[str, dict[str, str]] = {}
    for item in items:
        key, sep, value = item.partition("=")
        section, dot, name = key.strip().partition(".")
        if not sep or not dot or not name:
            raise ConfigError(f"--set expects SECTION.NAME=VALUE, got {item!r}")
        out.setdefault(section, {})[name] = value.strip()
    return out


_FORMATS = {".toml": "toml", ".yaml": "yaml", ".yml": "yaml", ".json": "json"}


def read_structured_file(path: str | Path, error: type[ValueError] = ConfigError,
                         default_format: str | None = None) -> Any:
    """Parse a TOML, YAML or JSON file, by its suffix (``default_format`` for any other suffix).

    Failures raise ``error`` with one line naming the file and the problem.
    """
    path = Path(path)
    fmt = _FORMATS.get(path.suffix, default_format)
    if fmt is None:
        raise error(f"{path}: unknown file type (use .toml, .yaml or .json)")
    try:
        text = path.read_text()
    except OSError as exc:
        raise error(f"{path}: cannot read ({exc.strerror})") from None
    try:
        if fmt == "toml":
            return tomllib.loads(text)
        return yaml.safe_load(text) if fmt == "yaml" else json.loads(text)
    except (tomllib.TOMLDecodeError, yaml.YAMLError, json.JSONDecodeError) as exc:
        raise error(f"{path}: malformed: {str(exc).splitlines()[0]}") from None


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Parse a TOML (.toml), YAML (.yaml/.yml) or JSON (.json) config file into a dict."""
    data = read_structured_file(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a table of sections at the top level")
    return data


def coerce(value: Any, kind: Any, name: str) -> Any:
    """``value`` (often a string from the command line) as the field type ``kind``."""
    try:
        if kind in (bool, "bool"):
            if isinstance(value, str):
                if value.lower() in ("1", "true", "yes", "on"):
                    return True
                if value.lower() in ("0", "false", "no", "off"):
                    return False
                raise ValueError
            return bool(value)
        if kind in (int, "int"):
            if isinstance(value, str):
                value = float(value)
            if float(value) != int(value):
                raise ValueError
            return int(value)
        if kind in (float, "float"):
            return float(value)
        return str(value)
    except (TypeError, ValueError):
        what = {bool: "true or false", int: "whole number", float: "number"}.get(
            {"bool": bool, "int": int, "float": float}.get(kind, kind), "string")
        raise ConfigError(f"{name} must be a {what}, got {value!r}") from None


def apply_to_dataclass(obj: Any, values: dict[str, Any], where: str = "") -> Any:
    """A copy of dataclass ``obj`` with ``values`` set; nested dataclasses take nested tables.

    ``where`` prefixes the parameter names in error messages (``icp`` -> ``icp.huber_delta``).
    """
    hints = typing.get_type_hints(type(obj))
    known = {f.name for f in dataclasses.fields(obj)}
    changes = {}
    nested: dict[str, Any] = {}
    for key, value in values.items():  # "gmmsc.w_th" from --set is the table {"gmmsc": {"w_th": ...}}
        head, dot, rest = key.partition(".")
        if dot:
            nested.setdefault(head, {})[rest] = value
        else:
            nested[key] = value
    for key, value in nested.items():
        name = f"{where}.{key}" if where else key
        if key not in known:
            raise ConfigError(f"unknown parameter {name} (known: {', '.join(sorted(known))})")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"[{name}] must be a table of parameters")
            changes[key] = apply_to_dataclass(current, value, name)
        else:
            changes[key] = coerce(value, hints[key], name)
    return dataclasses.replace(obj, **changes)
