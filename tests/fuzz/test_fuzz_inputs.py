"""Fuzzing what a user types and writes: config files (TOML, YAML, JSON), ``--set`` strings, world files.

Every generated input must end in one of two ways: success, or exit status 2 with a single
``fmcwlog: error: ...`` line (an exception escaping ``cli.main`` fails the test as the
traceback it would be). Either way nothing is left behind but what success writes. A success
of ``--show-config`` must print TOML that ``--config`` takes back unchanged.

The profile is reproducible (``derandomize``, no example database): the same examples every
run, about 30 s in all on one core.
"""

from __future__ import annotations

import json
import math
import tempfile
import tomllib
from pathlib import Path

import pytest
import yaml
from helpers import param_leaves, run_cli_here
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from fmcwlog.config import range_of
from fmcwlog.pipeline.params import ProcessParams
from fmcwlog.sim.config import RobotConfig, RunConfig, SensorConfig

settings.register_profile("fmcwlog-fuzz", derandomize=True, database=None, deadline=None, print_blob=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
FUZZ = settings.get_profile("fmcwlog-fuzz")



# every real parameter, as --set names it: the front end's own keys in [frontend]
LEAVES = {"process": [(n if "." in n else f"frontend.{n}", k, range_of(f)) for n, f, k in param_leaves(ProcessParams)],
          "record": [(f"{s}.{n}", k, r) for s, c in (("sensor", SensorConfig), ("robot", RobotConfig), ("run", RunConfig))
                     for n, f, k in param_leaves(c) for r in (range_of(f),)]}
PARAM_NAMES = sorted({n.rsplit(".", 1)[-1] for leaves in LEAVES.values() for n, _, _ in leaves})
SECTIONS = ["frontend", "segmentation", "icp", "sensor", "robot", "run"]


def _valid(kind, spec) -> st.SearchStrategy:
    """Values inside a parameter's declared range."""
    if kind is bool:
        return st.booleans()
    if kind is str:
        return st.sampled_from(spec.choices)
    if kind is int:
        return st.integers(int(spec.lo) + spec.lo_open, int(spec.hi) - spec.hi_open)
    return st.floats(spec.lo, spec.hi, exclude_min=spec.lo_open, exclude_max=spec.hi_open)

junk_scalar = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-2.0, max_value=200.0),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.integers(min_value=-3, max_value=5000),
    st.booleans(),
    st.text(max_size=8),
    st.sampled_from(["nan", "inf", "1e400", "true", "zstd", "", "0x10", " 3 "]),
    st.none(),
)
junk_value = st.recursive(junk_scalar, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                              st.dictionaries(st.text(max_size=6), inner, max_size=3)),
                          max_leaves=6)
keys = st.one_of(st.sampled_from(PARAM_NAMES), st.text(min_size=1, max_size=10))
sections = st.one_of(st.sampled_from(SECTIONS), st.text(min_size=1, max_size=8))
configs = st.dictionaries(sections, st.one_of(st.dictionaries(keys, junk_value, max_size=4), junk_value), max_size=4)


def _toml_value(v) -> str | None:
    """A TOML spelling of ``v`` (None where TOML has none); the parser may still refuse odd strings."""
    if v is None:
        return None
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")) if not math.isfinite(v) else repr(v)
    if isinstance(v, int | str):
        return json.dumps(v) if isinstance(v, str) else str(v)
    if isinstance(v, list):
        return "[" + ", ".join(t for t in map(_toml_value, v) if t is not None) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {t}" for k, x in v.items() if (t := _toml_value(x)) is not None) + "}"


def _toml(doc: dict) -> str:
    lines = []
    for section, body in doc.items():
        if isinstance(body, dict):
            lines.append(f"[{json.dumps(section)}]")
            lines += [f"{json.dumps(k)} = {t}" for k, v in body.items() if (t := _toml_value(v)) is not None]
        elif (t := _toml_value(body)) is not None:
            lines.insert(0, f"{json.dumps(section)} = {t}")
    return "\n".join(lines) + "\n"


def _dump(doc, fmt: str) -> str:
    if fmt == "toml":
        return _toml(doc)
    if fmt == "yaml":
        return yaml.safe_dump(doc)
    return json.dumps(doc)


def _check(code: int, out: str, err: str, command: str, folder: Path, expected: set[str]) -> None:
    """Success (and the printed TOML round-trips) or one clean error line; nothing else in ``folder``."""
    lines = [line for line in err.splitlines() if line.strip()]
    assert "Traceback" not in err
    event("accepted" if code == 0 else "refused")  # --hypothesis-show-statistics: both must occur
    if code == 0:
        assert lines == [], err
        printed = folder / "printed.toml"
        printed.write_text(out)
        tomllib.loads(out)
        code2, again, err2 = run_cli_here(command, "--config", str(printed), "--show-config")
        assert code2 == 0 and again == out, err2
        printed.unlink()
    else:
        assert code == 2 and len(lines) == 1 and lines[0].startswith("fmcwlog: error: "), (code, err)
        assert out == ""
    assert {p.name for p in folder.iterdir()} == expected


def _nest(doc: dict, dotted: str, value) -> None:
    *tables, key = dotted.split(".")
    for t in tables:
        doc = doc.setdefault(t, {}) if isinstance(doc.get(t, {}), dict) else {}
    doc[key] = value


@st.composite
def real_configs(draw, command: str) -> dict:
    """Real parameters in their tables, each value inside its range or (one time in four) junk."""
    doc: dict = {}
    for name, kind, spec in draw(st.lists(st.sampled_from(LEAVES[command]), min_size=1, max_size=4, unique=True)):
        _nest(doc, name, draw(st.one_of(_valid(kind, spec), _valid(kind, spec), _valid(kind, spec), junk_value)))
    return doc


@pytest.mark.slow
@settings(FUZZ, max_examples=150)
@given(data=st.data(), fmt=st.sampled_from(["toml", "yaml", "json"]), command=st.sampled_from(["process", "record"]))
def test_generated_config_files_of_real_parameters(data, fmt, command):
    doc = data.draw(real_configs(command))
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        cfg = folder / f"c.{fmt}"
        cfg.write_text(_dump(doc, fmt))
        _check(*run_cli_here(command, "--config", str(cfg), "--show-config"), command, folder, {cfg.name})


@settings(FUZZ, max_examples=80)
@given(doc=configs, fmt=st.sampled_from(["toml", "yaml", "json"]), command=st.sampled_from(["process", "record"]))
def test_generated_config_files(doc, fmt, command):
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        cfg = folder / f"c.{fmt}"
        cfg.write_text(_dump(doc, fmt))
        _check(*run_cli_here(command, "--config", str(cfg), "--show-config"), command, folder, {cfg.name})


@settings(FUZZ, max_examples=60)
@given(text=st.text(max_size=60), fmt=st.sampled_from(["toml", "yaml", "json"]), command=st.sampled_from(["process", "record"]))
def test_config_files_of_arbitrary_text(text, fmt, command):
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        cfg = folder / f"c.{fmt}"
        cfg.write_text(text)
        _check(*run_cli_here(command, "--config", str(cfg), "--show-config"), command, folder, {cfg.name})


set_values = st.one_of(st.text(max_size=12), st.floats().map(repr), st.integers(min_value=-(2**66), max_value=2**66).map(str),
                       st.sampled_from(["nan", "inf", "-inf", "1e400", "true", "false", "", " 3 ", "0.5", "1e-300"]))
set_items = st.one_of(
    st.text(max_size=30),
    st.builds(lambda s, n, v: f"{s}.{n}={v}", sections, keys, set_values),
    st.builds(lambda n, v: f"icp.gmmsc.{n}={v}", keys, set_values),
)


def _spelled(value) -> str:
    return str(value).lower() if isinstance(value, bool) else (repr(value) if isinstance(value, float) else str(value))


@st.composite
def real_set_items(draw, command: str) -> str:
    """``--set NAME=VALUE`` of a real parameter, the value inside its range or (one time in three) not."""
    name, kind, spec = draw(st.sampled_from(LEAVES[command]))
    return f"{name}={draw(st.one_of(_valid(kind, spec).map(_spelled), _valid(kind, spec).map(_spelled), set_values))}"


@settings(FUZZ, max_examples=150)
@given(data=st.data(), command=st.sampled_from(["process", "record"]))
def test_generated_set_options_of_real_parameters(data, command):
    items = data.draw(st.lists(real_set_items(command), min_size=1, max_size=3))
    with tempfile.TemporaryDirectory() as d:
        args = [a for item in items for a in ("--set", item)]
        _check(*run_cli_here(command, *args, "--show-config"), command, Path(d), set())


@settings(FUZZ, max_examples=80)
@given(items=st.lists(set_items, min_size=1, max_size=3), command=st.sampled_from(["process", "record"]))
def test_generated_set_options(items, command):
    with tempfile.TemporaryDirectory() as d:
        args = [a for item in items for a in ("--set", item)]
        _check(*run_cli_here(command, *args, "--show-config"), command, Path(d), set())


@st.composite
def valid_worlds(draw) -> dict:
    """A rectangular floor with the robot's route inside it, labelled walls and a few movers."""
    w, h = draw(st.floats(6.0, 40.0)), draw(st.floats(5.0, 30.0))
    walls = [[0, 0, w, 0], [w, 0, w, h], [w, h, 0, h], [0, h, 0, 0]]
    walls += draw(st.lists(st.tuples(st.floats(0.5, w - 0.5), st.floats(0.5, h - 0.5), st.floats(0.1, 2.0))
                           .map(lambda t: [t[0], t[1], min(t[0] + t[2], w), t[1]]), max_size=3))
    m = draw(st.floats(1.0, 2.0))
    loop = draw(st.booleans())
    waypoints = [[m, m], [w - m, m], [w - m, h - m]] + ([[m, h - m]] if loop or draw(st.booleans()) else [])
    movers = draw(st.lists(st.fixed_dictionaries({
        "kind": st.sampled_from(["person", "cart"]),
        "path": st.lists(st.tuples(st.floats(0.5, w - 0.5), st.floats(0.5, h - 0.5)).map(list), min_size=1, max_size=3),
        "speed": st.floats(0.0, 2.0)}, optional={"phase": st.floats(0.0, 10.0), "radius": st.floats(0.1, 0.5),
                                                   "length": st.floats(0.3, 2.0), "width": st.floats(0.3, 1.0)}),
        max_size=3))
    features = [{"id": i + 1, "name": f"wall {i + 1}", "a": wall[:2], "b": wall[2:]}
                for i, wall in enumerate(walls[:draw(st.integers(0, 4))])]
    return {"name": "fuzz", "walls": walls, "route": {"waypoints": waypoints, "loop": loop,
                                                      "corner_radius": draw(st.floats(0.1, 2.0))},
            "features": features, "movers": movers}


def _places(doc, path=()):
    """Every (container, key) in a parsed world, depth first."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        yield doc, key
        yield from _places(value, (*path, key))


@st.composite
def worlds(draw) -> dict:
    """A valid world, or one with up to three entries replaced by junk, removed, or joined by unknown keys."""
    world = draw(valid_worlds())
    for _ in range(draw(st.integers(0, 3))):
        container, key = draw(st.sampled_from(list(_places(world))))
        action = draw(st.sampled_from(["junk", "junk", "remove", "add"]))
        if action == "junk":
            container[key] = draw(junk_value)
        elif action == "remove" and isinstance(container, dict):
            del container[key]
        elif action == "remove":
            container.pop(key)
        elif isinstance(container, dict):
            container[draw(st.text(min_size=1, max_size=6))] = draw(junk_value)
    return world


@pytest.mark.slow
@settings(FUZZ, max_examples=150)
@given(world=worlds(), fmt=st.sampled_from(["yaml", "json"]))
def test_generated_world_files(world, fmt):
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        wf = folder / f"w.{fmt}"
        wf.write_text(yaml.safe_dump(world) if fmt == "yaml" else json.dumps(world))
        out = folder / "out" / "log.mcap"
        code, stdout, err = run_cli_here("-q", "record", "--world", str(wf), "--duration", "0.3", "-o", str(out))
        lines = [line for line in err.splitlines() if line.strip()]
        assert "Traceback" not in err
        event("recorded" if code == 0 else "refused")
        if code == 0:
            assert lines == [], err
            assert out.read_bytes()[:5] == b"\x89MCAP"
            assert {str(p.relative_to(folder)) for p in folder.rglob("*")} == {wf.name, "out", "out/log.mcap"}
        else:
            assert code == 2 and len(lines) == 1 and lines[0].startswith("fmcwlog: error: "), (code, err)
            assert [p.name for p in folder.iterdir()] == [wf.name]  # not even the folder it would have made
