"""Parameters with declared ranges, config files, ``--set SECTION.NAME=VALUE``, and TOML to print them.

Every user-settable parameter is a field of a frozen dataclass declared with :func:`param`,
which stores its unit and its valid values (an interval, open or closed at each end, or a
set of choices) beside the default. One validator, :func:`check_params`, walks a dataclass
and its nested ones and refuses NaN, infinities, wrong types and values out of range with
one line naming the parameter, its value and its range (``icp.huber_delta = -1 is out of
range: (0, 1] m``). A dataclass that inherits :class:`Checked` runs it on construction,
so no code path (config file, ``--set``, a library call) builds parameters it would refuse.

Values from files and the command line are coerced to the type of the field they set, so a
typo or a wrong type is caught with a message naming the parameter. :func:`toml_table`
writes the parameters back as TOML, each with its unit and range as a comment, in the same
structure the readers take, so whatever ``--show-config`` prints, ``--config`` takes back.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import tomllib
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .errors import ConfigError, excerpt

_RANGE_KEY = "fmcwlog.range"


@dataclasses.dataclass(frozen=True)
class Range:
    """A parameter's unit and valid values: an interval ``lo..hi`` (each end open or closed), or choices."""

    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] = ()

    def admits(self, value: Any) -> bool:
        if self.choices:
            return isinstance(value, str) and value in self.choices
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            return False
        if self.lo is not None and (value < self.lo or (self.lo_open and value == self.lo)):
            return False
        return self.hi is None or not (value > self.hi or (self.hi_open and value == self.hi))

    def __str__(self) -> str:
        if self.choices:
            return "one of " + ", ".join(json.dumps(c) for c in self.choices)
        lo = "(-inf" if self.lo is None else ("(" if self.lo_open else "[") + _number(self.lo)
        hi = "inf)" if self.hi is None else _number(self.hi) + (")" if self.hi_open else "]")
        return f"{lo}, {hi}" + (f" {self.unit}" if self.unit else "")


def _number(x: float) -> str:
    if float(x).is_integer() and abs(x) < 1e15:
        return str(int(x))
    return f"{x:g}"


def param(default: Any, unit: str = "", *, gt: float | None = None, ge: float | None = None,
          lt: float | None = None, le: float | None = None, choices: tuple[str, ...] = ()) -> Any:
    """A dataclass field: ``default``, its ``unit`` and its valid values.

    ``gt``/``ge`` give the lower end (open/closed), ``lt``/``le`` the upper end; ``choices``
    the allowed strings. Every numeric parameter declares both ends: a bound is what keeps a
    typo from turning into a hang or an allocation of terabytes.
    """
    if gt is not None and ge is not None or lt is not None and le is not None:
        raise TypeError("give one of gt/ge and one of lt/le")
    spec = Range(unit, gt if gt is not None else ge, lt if lt is not None else le, gt is not None, lt is not None,
                 tuple(choices))
    return dataclasses.field(default=default, metadata={_RANGE_KEY: spec})


def range_of(f: dataclasses.Field) -> Range | None:
    """The :class:`Range` a field was declared with by :func:`param` (None for nested tables and plain fields)."""
    return f.metadata.get(_RANGE_KEY)


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    """The field types of a dataclass, resolved once per class (construction checks every field)."""
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _word(name: Any) -> str:
    """A parameter or section name as typed, quoted where it holds spaces or characters that do not print
    (at most :data:`~fmcwlog.errors.EXCERPT_CHARS` of it)."""
    text = str(name)
    return excerpt(text if text and text.isprintable() and " " not in text else repr(text))


def _show(value: Any) -> str:
    text = _number(value) if isinstance(value, float) and math.isfinite(value) else repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def check_value(name: str, value: Any, kind: Any, spec: Range | None) -> None:
    """Refuse ``value`` for parameter ``name`` of type ``kind`` unless it is of that type and in ``spec``."""
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, int | float) and not isinstance(value, bool)
    else:
        ok = isinstance(value, str) if kind is str else True
    if not ok:
        raise ConfigError(f"{name} must be {_KIND_WORDS.get(kind, 'a value')}, got {_show(value)}")
    if spec is not None and not spec.admits(value):
        if spec.choices:
            raise ConfigError(f"{name} = {_show(value)} is not {spec}")
        raise ConfigError(f"{name} = {_show(value)} is out of range: {spec}")


_KIND_WORDS = {bool: "true or false", int: "a whole number", float: "a number", str: "a string"}


def check_params(obj: Any, where: str = "") -> Any:
    """Check every field of dataclass ``obj`` and of the dataclasses it nests; returns ``obj``.

    ``where`` prefixes the names in messages (``icp`` -> ``icp.huber_delta``).
    """
    hints = _hints(type(obj))
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        name = f"{where}.{f.name}" if where else f.name
        if dataclasses.is_dataclass(value):
            check_params(value, name)
        else:
            check_value(name, value, hints[f.name], range_of(f))
    return obj


class Checked:
    """Base of parameter dataclasses: construction (and ``dataclasses.replace``) checks every field."""

    def __post_init__(self) -> None:
        check_params(self, type(self).__name__)


# --------------------------------------------------------------------------- reading


def parse_set_option(items: tuple[str, ...]) -> dict[str, dict[str, str]]:
    """``("sensor.range_sigma=0.03", ...)`` -> ``{"sensor": {"range_sigma": "0.03"}}``."""
    out: dict[str, dict[str, str]] = {}
    for item in items:
        key, sep, value = item.partition("=")
        section, dot, name = key.strip().partition(".")
        if not sep or not section or not dot or not name:
            raise ConfigError(f"--set expects SECTION.NAME=VALUE, got {excerpt(repr(item))}")
        out.setdefault(section, {})[name] = value.strip()
    return out


_FORMATS = {".toml": "toml", ".yaml": "yaml", ".yml": "yaml", ".json": "json"}


def read_structured_file(path: str | Path, error: type[ValueError] = ConfigError,
                         default_format: str | None = None) -> Any:
    """Parse a TOML, YAML or JSON file, by its suffix (``default_format`` for any other suffix).

    Failures raise ``error`` with one line naming the file and the problem.
    """
    path = Path(path)
    fmt = _FORMATS.get(path.suffix.lower(), default_format)
    if fmt is None:
        raise error(f"{path}: unknown file type (use .toml, .yaml or .json)")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise error(f"{path}: cannot read ({(exc.strerror or str(exc)).lower()})") from None
    except UnicodeDecodeError:
        raise error(f"{path}: not a text file (it is not UTF-8)") from None
    import yaml  # here, not at import: 0.06 s that only a config or world file needs

    try:
        if fmt == "toml":
            return tomllib.loads(text)
        return yaml.safe_load(text) if fmt == "yaml" else json.loads(text)
    except (ValueError, yaml.YAMLError) as exc:  # TOMLDecodeError and JSONDecodeError are ValueErrors
        first = (str(exc).splitlines() or [type(exc).__name__])[0]
        raise error(f"{path}: malformed: {first}") from None
    except RecursionError:
        raise error(f"{path}: malformed: nested too deeply") from None


@contextlib.contextmanager
def naming(path: str | Path | None) -> Iterator[None]:
    """A :class:`ConfigError` raised inside (an unknown key, a value out of range) names the file
    ``path`` whose content it is about; a message that names it already is left as it is."""
    try:
        yield
    except ConfigError as exc:
        if path is None or str(exc).startswith(f"{path}:"):
            raise
        raise ConfigError(f"{path}: {exc}") from None


def read_config_file(path: str | Path) -> dict[str, Any]:
    """Parse a TOML (.toml), YAML (.yaml/.yml) or JSON (.json) config file into a dict."""
    data = read_structured_file(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a table of sections at the top level")
    return data


def coerce(value: Any, kind: Any, name: str) -> Any:
    """``value`` (often a string from the command line) as the field type ``kind``."""
    try:
        if isinstance(value, bool) and kind is not bool:
            raise ValueError
        if kind is bool:
            if isinstance(value, str):
                if value.lower() in ("1", "true", "yes", "on"):
                    return True
                if value.lower() in ("0", "false", "no", "off"):
                    return False
            if isinstance(value, bool):
                return value
            raise ValueError
        if kind is int:
            if isinstance(value, str):
                value = float(value)
            if not isinstance(value, int | float) or float(value) != int(value):
                raise ValueError
            return int(value)
        if kind is float:
            if not isinstance(value, int | float | str):
                raise ValueError
            return float(value)
        if not isinstance(value, str):
            raise ValueError
        return value
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"{name} must be {_KIND_WORDS.get(kind, 'a value')}, got {_show(value)}") from None


def _split_dotted(values: dict[Any, Any], where: str) -> dict[str, Any]:
    """``{"gmmsc.w_th": 1}`` (from --set) -> ``{"gmmsc": {"w_th": 1}}``, merged with the tables given."""
    nested: dict[str, Any] = {}
    for key, value in values.items():
        if not isinstance(key, str) or not key:
            raise ConfigError(f"{where or 'a config'}: parameter names must be words, got {_show(key)}")
        key = key if key.isprintable() else _word(key)  # reported as unknown, quoted
        head, dot, rest = key.partition(".")
        if dot:
            value = {rest: value}
        old = nested.get(head)
        if isinstance(old, dict) and isinstance(value, dict):
            nested[head] = {**old, **value}
        elif head in nested:
            raise ConfigError(f"{where + '.' if where else ''}{_word(head)} is given twice")
        else:
            nested[head] = value
    return nested


def apply_to_dataclass(obj: Any, values: dict[str, Any], where: str = "") -> Any:
    """A copy of dataclass ``obj`` with ``values`` set; nested dataclasses take nested tables.

    ``where`` prefixes the parameter names in error messages (``icp`` -> ``icp.huber_delta``).
    Each value is coerced to its field's type and checked against its declared range.
    """
    if not isinstance(values, dict):
        raise ConfigError(f"[{where}] must be a table of parameters")
    hints = _hints(type(obj))
    fields = {f.name: f for f in dataclasses.fields(obj)}
    changes = {}
    for key, value in _split_dotted(values, where).items():
        name = f"{where}.{key}" if where else key
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(f"unknown parameter {where + '.' if where else ''}{_word(key)} (known: {known})")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise ConfigError(f"[{name}] must be a table of parameters")
            changes[key] = apply_to_dataclass(current, value, name)
        else:
            changes[key] = coerce(value, hints[key], name)
            check_value(name, changes[key], hints[key], range_of(fields[key]))
    return dataclasses.replace(obj, **changes)


# --------------------------------------------------------------------------- writing


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)  # the shortest text that reads back as the same float; valid TOML
    if isinstance(value, int):
        return str(value)
    return json.dumps(value)  # a TOML basic string: the same escapes as JSON


def _comment(f: dataclasses.Field, kind: Any) -> str:
    spec = range_of(f)
    if kind is bool:
        return "true or false"
    return str(spec) if spec is not None else ""


def toml_table(name: str, obj: Any, nested: bool = True) -> list[str]:
    """``[name]`` with ``obj``'s parameters (each with its range as a comment), then
    ``[name.sub]`` for each nested dataclass (unless ``nested`` is False)."""
    hints = _hints(type(obj))
    scalars = [f for f in dataclasses.fields(obj) if not dataclasses.is_dataclass(getattr(obj, f.name))]
    pairs = [(f"{f.name} = {_toml_value(getattr(obj, f.name))}", _comment(f, hints[f.name])) for f in scalars]
    width = max((len(p) for p, _ in pairs), default=0)
    lines = [f"[{name}]"] + [f"{p:<{width}}  # {c}" if c else p for p, c in pairs] + [""]
    if nested:
        for f in dataclasses.fields(obj):
            sub = getattr(obj, f.name)
            if dataclasses.is_dataclass(sub):
                lines += toml_table(f"{name}.{f.name}", sub)
    return lines
