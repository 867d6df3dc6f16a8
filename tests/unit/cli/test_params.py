"""Parameters: every numeric one has a bounded range beside its default, values outside it are refused
with one line, and whatever ``--show-config`` prints (or run.json records) ``--config`` takes back.

The round trips are checked with ``tomllib`` (the standard library's TOML parser, not fmcwlog's
printer) and by comparing the parameter objects themselves.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from helpers import SAMPLE_LOGS, assert_one_line_error, copy_log, param_leaves, run_cli_here

from fmcwlog.backend.params import BackendParams
from fmcwlog.backend.registration import LineICPParams
from fmcwlog.config import check_params, parse_set_option, range_of
from fmcwlog.errors import ConfigError, MapSizeError
from fmcwlog.frontend.gmmsc import GMMSCParams
from fmcwlog.frontend.icp import ICPParams
from fmcwlog.frontend.keyframe_map import LocalMapParams
from fmcwlog.frontend.recovery import RecoveryParams
from fmcwlog.frontend.segmentation import SegmentationParams
from fmcwlog.kernels.correlative import CorrelativeParams
from fmcwlog.kernels.occupancy import OccupancyGrid, OccupancyParams
from fmcwlog.pipeline.params import ProcessParams, load_params
from fmcwlog.sim.config import RobotConfig, RunConfig, SensorConfig, SimConfig

USER_PARAMETERS = (ProcessParams, SegmentationParams, ICPParams, GMMSCParams, LocalMapParams, RecoveryParams,
                   CorrelativeParams, BackendParams, LineICPParams, SensorConfig, RobotConfig, RunConfig)


@pytest.mark.parametrize("cls", USER_PARAMETERS, ids=lambda c: c.__name__)
def test_every_numeric_parameter_has_a_bounded_range_holding_its_default(cls):
    obj = cls()
    for name, f, kind in param_leaves(cls):
        spec = range_of(f)
        if kind is bool:
            continue
        assert spec is not None, f"{cls.__name__}.{name} declares no range"
        if kind is str:
            assert spec.choices, name
        else:
            assert spec.lo is not None and spec.hi is not None and spec.lo < spec.hi, name
            assert kind in (int, float)
    check_params(obj)  # the defaults are inside their own ranges


def _numeric():
    """(command, name as --set takes it, type, range) of every numeric parameter of process and record."""
    out = []
    for name, f, kind in param_leaves(ProcessParams):
        if kind in (int, float):  # the front end's own keys live in [frontend]
            out.append(("process", name if "." in name else f"frontend.{name}", kind, range_of(f)))
    for section, cls in (("sensor", SensorConfig), ("robot", RobotConfig), ("run", RunConfig)):
        out += [("record", f"{section}.{name}", kind, range_of(f)) for name, f, kind in param_leaves(cls) if kind in (int, float)]
    return out


@pytest.mark.parametrize("command, name, kind, spec", _numeric(), ids=[f"{c}-{n}" for c, n, _, _ in _numeric()])
def test_every_numeric_parameter_refuses_nan_inf_and_values_past_its_ends(command, name, kind, spec):
    below = spec.lo if spec.lo_open else spec.lo - max(1.0, abs(spec.lo))
    above = spec.hi if spec.hi_open else spec.hi + max(1.0, abs(spec.hi))
    for value in ("nan", "inf", "-inf", repr(below), repr(above)):
        code, out, err = run_cli_here(command, "--set", f"{name}={value}", "--show-config")
        line = assert_one_line_error(code, err, name)
        assert out == ""
        if kind is float and value not in ("nan", "inf", "-inf"):
            assert "is out of range: " + str(spec) in line, line
    inside = spec.lo + (spec.hi - spec.lo) / 3 if kind is float else int(spec.lo + (spec.hi - spec.lo) // 3)
    if name == "sensor.min_range":  # it must also stay below max_range
        inside = 1.0
    code, out, err = run_cli_here(command, "--set", f"{name}={inside!r}", "--show-config")
    assert code == 0, err


@pytest.mark.parametrize("args, expected", [
    (["process", "--set", "icp.huber_delta=-1"], "icp.huber_delta = -1 is out of range: (0, 1] m"),
    (["process", "--set", "icp.huber_delta=0"], "icp.huber_delta = 0 is out of range: (0, 1] m"),
    (["process", "--set", "frontend.voxel_size=0"], "frontend.voxel_size = 0 is out of range: [0.001, 10] m"),
    (["process", "--set", "frontend.map_resolution=1e-5"],
     "frontend.map_resolution = 1e-05 is out of range: [0.01, 10] m"),
    (["process", "--set", "segmentation.eps=nan"], "segmentation.eps = nan is out of range: (0, 10] m"),
    (["process", "--set", "segmentation.min_samples=-3"], "segmentation.min_samples = -3 is out of range: [1, 10000] points"),
    (["process", "--set", "icp.max_iterations=0"], "icp.max_iterations = 0 is out of range: [1, 1000]"),
    (["process", "--set", "icp.gmmsc.n_components=2.5"], "icp.gmmsc.n_components must be a whole number, got 2.5"),
    (["process", "--set", "frontend.prior_sigma_yaw=0"], "frontend.prior_sigma_yaw = 0 is out of range: (0, 3.14159] rad"),
    (["process", "--set", "backend.search.levels=9"], "backend.search.levels = 9 is out of range: [1, 4]"),
    (["process", "--set", "local_map.window_distance=0"],
     "local_map.window_distance = 0 is out of range: (0, 1000] m"),
    (["record", "--set", "sensor.scan_rate=1e6"], "sensor.scan_rate = 1000000 is out of range: [0.1, 100] Hz"),
    (["record", "--duration", "inf"], "run.duration = inf is out of range: (0, 86400] s"),
    (["record", "--duration", "nan"], "run.duration = nan is out of range: (0, 86400] s"),
    (["record", "--seed", "-1"], "run.seed = -1 is out of range: [0, 4294967295]"),
    (["record", "--speed", "0"], "robot.speed = 0 is out of range: (0, 10] m/s"),
    (["record", "--set", "run.compression=gzip"], "run.compression = 'gzip' is not one of \"zstd\", \"lz4\", \"\""),
    (["record", "--set", "sensor.min_range=31"], "sensor.min_range = 31 m must be below sensor.max_range = 30 m"),
    # once a log of no sweeps, exit 0; process then said it had no scan topic
    (["record", "--duration", "0.05"], "run.duration = 0.05 s is shorter than one sweep (1 / sensor.scan_rate = 0.1 s): "
                                       "the log would hold none"),
])
def test_cases_of_the_issue_get_one_line_with_the_parameter_value_and_range(tmp_path, args, expected):
    code, out, err = run_cli_here(*args, "--show-config")
    assert assert_one_line_error(code, err) == f"fmcwlog: error: {expected}"
    if args[0] == "record":  # and recording for real writes nothing either
        code, _, err = run_cli_here(*args, "-o", str(tmp_path / "x.mcap"))
        assert_one_line_error(code, err)
        assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["record", "run", "process"])
def test_an_empty_output_path_is_refused(tmp_path, command):
    args = {"record": ["record"], "run": ["run"], "process": ["process", str(SAMPLE_LOGS / "corridor_30s.mcap")]}[command]
    code, _, err = run_cli_here(*args, "-o", "")
    assert_one_line_error(code, err, "empty path")


def test_library_construction_is_checked_too():
    with pytest.raises(ConfigError, match=r"ICPParams.huber_delta = nan is out of range: \(0, 1\] m"):
        ICPParams(huber_delta=math.nan)
    with pytest.raises(ConfigError, match="GMMSCParams.max_iter must be a whole number"):
        GMMSCParams(max_iter=2.5)
    with pytest.raises(ConfigError, match="SensorConfig.scan_rate"):
        dataclasses.replace(SensorConfig(), scan_rate=0.0)
    assert SegmentationParams(alpha=0.0).alpha == 0.0  # the closed end is inside


def _frontend_as_tables(p: ProcessParams) -> dict:
    """ProcessParams as the TOML tables its printer must produce: the front end's own keys in [frontend]."""
    d = dataclasses.asdict(p)
    nested = {k: d.pop(k) for k in [k for k, v in d.items() if isinstance(v, dict)]}
    return {"frontend": d, **nested}


PROCESS_SETS = ("icp.huber_delta=0.04", "icp.gmmsc.w_th=0.6", "segmentation.v_th=0.25",
                "frontend.map_resolution=0.1", "frontend.seed=4294967295", "frontend.deskew=false",
                "icp.gmmsc.min_spread=3e-7", "frontend.prior_sigma_yaw=0.1", "local_map.max_keyframes=12",
                "recovery.enabled=false", "recovery.correlative.levels=3", "backend.closure_radius=4.5",
                "backend.search.resolution=0.05", "backend.icp.normal_neighbours=8", "backend.cauchy_scale=2.5")
RECORD_SETS = ("sensor.range_sigma=0.03", "sensor.wavelength=9.05e-7", "robot.ticks_per_revolution=1024",
               "run.compression=", "run.start_time_ns=1234567890123456789", "robot.wheel_radius_error_left=-0.01")


@pytest.mark.parametrize("command, sets, extra", [
    ("process", (), ()), ("process", PROCESS_SETS, ()),
    ("record", (), ()), ("record", RECORD_SETS, ("--duration", "7.5", "--seed", "3", "--speed", "1.25")),
])
def test_show_config_is_toml_that_config_takes_back_unchanged(tmp_path, command, sets, extra):
    args = [a for s in sets for a in ("--set", s)] + list(extra)
    code, printed, err = run_cli_here(command, *args, "--show-config")
    assert code == 0, err
    tables = tomllib.loads(printed)  # an independent parser
    if command == "process":
        params = load_params(None, parse_set_option(sets))
        assert tables == _frontend_as_tables(params)
        assert load_params(tables) == params
    else:
        assert set(tables) == {"sensor", "robot", "run"}
        cfg = SimConfig(SensorConfig(**tables["sensor"]), RobotConfig(**tables["robot"]), RunConfig(**tables["run"]))
        assert cfg.as_dict() == tables
        if extra:
            assert (cfg.run.duration, cfg.run.seed, cfg.robot.speed, cfg.run.compression) == (7.5, 3, 1.25, "")
    for line in printed.splitlines():  # each parameter carries its range (or says it is a switch)
        if "=" in line and not line.startswith("#"):
            assert "  # " in line, line
    saved = tmp_path / "p.toml"
    saved.write_text(printed)
    code, again, err = run_cli_here(command, "--config", str(saved), "--show-config")
    assert code == 0, err
    assert again == printed


@pytest.mark.parametrize("suffix, dump", [(".json", json.dumps), (".yaml", None)])
def test_the_same_tables_in_json_or_yaml_give_the_same_parameters(tmp_path, suffix, dump):
    import yaml

    code, printed, _ = run_cli_here("process", "--set", "icp.huber_delta=0.04", "--show-config")
    tables = tomllib.loads(printed)
    f = tmp_path / f"p{suffix}"
    f.write_text(dump(tables) if dump else yaml.safe_dump(tables))
    code, again, err = run_cli_here("process", "--config", str(f), "--show-config")
    assert code == 0 and again == printed, err


def _short_log(tmp_path: Path, name: str = "s.mcap", sweeps: int = 12) -> Path:
    dst = tmp_path / name

    def edit(topic, i, msg):
        return False if i >= (sweeps if topic == "/fmcw/points" else 5 * sweeps) else None

    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", dst, edit=edit)
    return dst


@pytest.mark.slow
def test_a_previous_runs_run_json_is_a_config_that_gives_the_same_parameters(tmp_path):
    log = _short_log(tmp_path)
    sets = [a for s in PROCESS_SETS[:4] for a in ("--set", s)]
    code, _, err = run_cli_here("-q", "process", str(log), "-o", str(tmp_path / "a"), *sets)
    assert code == 0, err
    first = json.loads((tmp_path / "a" / "run.json").read_text())
    code, shown, err = run_cli_here("process", "--config", str(tmp_path / "a" / "run.json"), "--show-config")
    assert code == 0, err
    tables = tomllib.loads(shown)
    assert {**tables.pop("frontend"), **tables} == first["params"]
    code, _, err = run_cli_here("-q", "process", str(log), "-o", str(tmp_path / "b"), "--config",
                                str(tmp_path / "a" / "run.json"))
    assert code == 0, err
    assert json.loads((tmp_path / "b" / "run.json").read_text())["params"] == first["params"]
    assert (tmp_path / "a" / "improved.tum").read_bytes() == (tmp_path / "b" / "improved.tum").read_bytes()


@pytest.mark.parametrize("command", ["process", "record"])
def test_help_says_where_the_ranges_are_shown(command):
    code, out, _ = run_cli_here(command, "--help")
    assert code == 0
    text = " ".join(out.split())
    assert "--show-config" in text and "valid range" in text and "--config takes it back" in text


def test_an_occupancy_grid_past_its_cell_budget_is_refused_before_allocating():
    grid = OccupancyGrid(OccupancyParams(resolution=0.05, max_cells=1_000_000))
    grid.integrate(np.zeros(2), np.array([[10.0, 0.0], [0.0, 10.0]]))  # 28 m square with its margin: 3e5 cells
    assert grid.width * grid.height <= 1_000_000
    with pytest.raises(MapSizeError, match=r"over its budget of 1e\+06 cells"):
        grid.integrate(np.zeros(2), np.array([[1e6, 0.0]]))  # 1000 km away: 2e7 x 3e2 cells
    assert grid.width * grid.height <= 1_000_000  # the grid is as it was
    assert OccupancyParams().max_cells * 5 <= 2**28  # the default budget: arrays of at most ~256 MB


@pytest.mark.parametrize("command, text, words", [
    ("record", "[sensor]\nrange_sigma = -1\n", "sensor.range_sigma = -1 is out of range: [0, 10] m"),
    ("record", "[sensor]\nrange_sigma = true\n", "sensor.range_sigma must be a number, got True"),
    ("process", "[icp]\nhuber_delta = -1\n", "icp.huber_delta = -1 is out of range: (0, 1] m"),
    ("calibrate", "[icp]\nhuber_delta = 'a'\n", "icp.huber_delta must be a number, got 'a'"),
])
def test_a_bad_value_in_a_parameter_file_names_the_file(tmp_path, command, text, words):
    """A value's error named the parameter but not the file it came from (the same words as --set's)."""
    cfg = tmp_path / "p.toml"
    cfg.write_text(text)
    log = str(SAMPLE_LOGS / "corridor_30s.mcap")
    args = {"record": ["record"], "process": ["process", log], "calibrate": ["calibrate", log]}[command]
    out = tmp_path / ("o.yaml" if command == "calibrate" else "o.mcap" if command == "record" else "o")
    code, _, err = run_cli_here(*args, "--config", str(cfg), "-o", str(out))
    assert assert_one_line_error(code, err) == f"fmcwlog: error: {cfg}: {words}"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.toml"]


@pytest.mark.parametrize("command", ["record", "process"])
def test_an_output_name_too_long_for_its_temporary_is_one_line_naming_it(tmp_path, command):
    """A 250-byte name is valid, but its temporary .NAME.partial-PID is not: the line named the temporary
    ('file name too long'), after the work was done."""
    name = "a" * 250 + (".mcap" if command == "record" else "")
    args = {"record": ["record", "--duration", "0.5"], "process": ["process", str(SAMPLE_LOGS / "corridor_30s.mcap")]}
    code, _, err = run_cli_here(*args[command], "-o", str(tmp_path / name))
    assert assert_one_line_error(code, err, "the name is too long", "at most 238 bytes").startswith(
        f"fmcwlog: error: {tmp_path / name}: ")
    assert list(tmp_path.iterdir()) == []
