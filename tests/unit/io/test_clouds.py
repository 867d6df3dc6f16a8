"""Clouds as real FMCW LiDARs record them (:mod:`fmcwlog.io.clouds`): per-point times by field name and
type, and a 3-D cloud brought down to the sensor's plane with its Doppler corrected for elevation.

The physics is written here from the 3-D bearing, ``v_r = −u₃·v_s`` with ``u₃ = (cos e cos φ,
cos e sin φ, sin e)`` (/work/shared/NOTES.md's planar model is its ``e = 0``), not from the code.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fmcwlog.errors import ConfigError, LogError
from fmcwlog.frontend.egomotion import fit_sensor_velocity
from fmcwlog.io.clouds import CloudReading, InputParams, TimeField, is_3d, parse_time_field, planar_doppler
from fmcwlog.io.sweeps import InputLimits, Rejected, sweep_from_pointcloud

STAMP_NS = 1_700_000_000_123_456_789
DTYPES = {2: "u1", 4: "<u2", 5: "<i4", 6: "<u4", 7: "<f4", 8: "<f8"}
PATH = Path("cloud.mcap")


def cloud(columns: dict[str, tuple[int, np.ndarray]], stamp_ns: int = STAMP_NS) -> SimpleNamespace:
    """A decoded ``sensor_msgs/PointCloud2`` as the readers see it: ``columns`` name -> (datatype, values),
    packed point by point in order."""
    layout = np.dtype({"names": list(columns), "formats": [DTYPES[d] for d, _ in columns.values()]})
    n = len(next(iter(columns.values()))[1])
    points = np.zeros(n, dtype=layout)
    for name, (_, values) in columns.items():
        points[name] = values
    fields = [SimpleNamespace(name=name, offset=layout.fields[name][1], datatype=d, count=1)
              for name, (d, _) in columns.items()]
    stamp = SimpleNamespace(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    return SimpleNamespace(header=SimpleNamespace(stamp=stamp, frame_id="lidar"), height=1, width=n, fields=fields,
                           is_bigendian=False, point_step=layout.itemsize, row_step=layout.itemsize * n,
                           data=points.tobytes(), is_dense=True)


def _planar(n: int = 50) -> dict[str, tuple[int, np.ndarray]]:
    rng = np.random.default_rng(1)
    phi = np.linspace(-2.0, 2.0, n)
    r = rng.uniform(1.0, 10.0, n)
    return {"x": (7, r * np.cos(phi)), "y": (7, r * np.sin(phi)), "velocity": (7, rng.normal(0, 1, n)),
            "intensity": (7, rng.uniform(0, 1, n))}


T_S = np.linspace(0.0, 0.075, 50)  # each point's time after the stamp, s


@pytest.mark.parametrize("field, datatype, values", [
    ("t", 7, T_S),  # the log format
    ("t", 8, T_S),
    ("t", 6, np.round(T_S * 1e9)),  # Ouster: uint32 ns
    ("time_offset_ns", 6, np.round(T_S * 1e9)),  # Aeva
    ("timestamp", 8, STAMP_NS * 1e-9 + T_S),  # absolute, s since the epoch (Hesai, Robosense)
])
def test_point_times_are_read_by_field_name_and_type(field, datatype, values):
    sweep, layout = sweep_from_pointcloud(PATH, cloud({**_planar(), field: (datatype, values)}))
    assert layout.time is not None and layout.time.name == field
    tol = 1e-6 if field == "timestamp" else 1e-8  # float64 s since the epoch: 0.24 us steps
    assert np.allclose(sweep.t, T_S, atol=tol, rtol=0)


@pytest.mark.parametrize("field, datatype", [("time", 7), ("t", 5), ("timestamp", 7), ("offset_time", 6)])
def test_a_time_field_of_unknown_layout_is_refused_naming_the_fields_and_the_option(field, datatype):
    with pytest.raises(LogError) as exc:
        sweep_from_pointcloud(PATH, cloud({**_planar(), field: (datatype, T_S)}))
    text = str(exc.value)
    assert text.startswith(f"{PATH}: ") and "\n" not in text
    assert "x (float32), y (float32), velocity (float32), intensity (float32)" in text
    assert repr(field) in text and "--time-field NAME:UNIT" in text


def test_the_time_field_option_reads_a_field_of_any_name_in_the_unit_it_gives():
    msg = cloud({**_planar(), "time": (7, T_S * 1e3), "t": (8, np.zeros(50))})
    reading = CloudReading(time_field=parse_time_field("time:ms"))
    sweep, layout = sweep_from_pointcloud(PATH, msg, reading=reading)
    assert layout.time == TimeField("time", "ms") and np.allclose(sweep.t, T_S)
    ns = cloud({**_planar(), "stamp": (8, STAMP_NS + T_S * 1e9)})
    sweep, _ = sweep_from_pointcloud(PATH, ns, reading=CloudReading(time_field=parse_time_field("stamp:abs_ns")))
    assert np.allclose(sweep.t, T_S, atol=1e-6)
    with pytest.raises(LogError, match=r"--time-field names 'when', which the cloud does not have \(its fields: x"):
        sweep_from_pointcloud(PATH, msg, reading=CloudReading(time_field=TimeField("when", "s")))


@pytest.mark.parametrize("text", ["t", "t:", ":ns", "t:sec", "t:NS"])
def test_a_time_field_option_that_is_not_name_and_unit_is_refused(text):
    with pytest.raises(ConfigError, match="--time-field expects NAME:UNIT"):
        parse_time_field(text)


def test_point_times_out_of_the_sweep_say_how_the_field_was_read():
    """uint32 nanoseconds in a float32 field read as seconds: the sweep is refused with the unit it was read in."""
    with pytest.raises(Rejected) as exc:
        sweep_from_pointcloud(PATH, cloud({**_planar(), "t": (7, T_S * 1e9)}), InputLimits(0.1))
    assert exc.value.kind == "times"
    assert "point times span [0, 75000000] s (field 't' (float32) read as s after header.stamp; --time-field" \
        in exc.value.detail


def test_a_cloud_without_a_time_field_is_taken_at_its_stamp():
    sweep, layout = sweep_from_pointcloud(PATH, cloud(_planar()))
    assert layout.time is None and not sweep.t.any()


def test_a_flat_cloud_is_planar_and_read_as_it_is():
    cols = {**_planar(), "z": (7, np.zeros(50)), "t": (7, T_S)}
    sweep, layout = sweep_from_pointcloud(PATH, cloud(cols))
    assert layout.kept is None and len(sweep.xy) == 50
    assert np.array_equal(sweep.velocity, cols["velocity"][1].astype(np.float32).astype(float))


def _rings(elevations_deg, n: int = 90, v_s=(1.2, -0.4)):
    """A 3-D cloud of static points on rings at ``elevations_deg``, 2-12 m away, seen by a sensor moving
    at ``v_s`` in its plane: x, y, z, velocity (the 3-D bearing's), t, and a uint16 ring field."""
    rng = np.random.default_rng(2)
    e = np.radians(np.repeat(elevations_deg, n))
    phi = np.tile(np.linspace(-2.3, 2.3, n), len(elevations_deg))
    r = rng.uniform(2.0, 12.0, len(e))
    u3 = np.column_stack([np.cos(e) * np.cos(phi), np.cos(e) * np.sin(phi), np.sin(e)])
    v_r = -u3 @ np.array([*v_s, 0.0])
    xyz = r[:, None] * u3
    return {"x": (7, xyz[:, 0]), "y": (7, xyz[:, 1]), "z": (7, xyz[:, 2]), "velocity": (8, v_r),
            "t": (7, np.tile(np.linspace(0, 0.075, n), len(elevations_deg))),
            "ring": (4, np.repeat(np.arange(len(elevations_deg)), n))}


def test_a_3d_cloud_keeps_the_band_about_the_sensor_plane_projected_with_planar_doppler():
    cols = _rings([-15.0, -5.0, -1.0, 1.0, 5.0, 15.0])
    sweep, layout = sweep_from_pointcloud(PATH, cloud(cols))
    assert (layout.points, layout.kept) == (540, 180)  # the rings at -1 and +1 deg
    assert np.allclose(sweep.xy, np.column_stack([cols["x"][1], cols["y"][1]])[180:360].astype(np.float32))
    u = sweep.xy / np.hypot(sweep.xy[:, 0], sweep.xy[:, 1])[:, None]
    assert np.allclose(sweep.velocity, -u @ np.array([1.2, -0.4]), atol=1e-6)  # cos(e) undone
    wide = CloudReading(InputParams(plane_band_deg=10.0))
    sweep, layout = sweep_from_pointcloud(PATH, cloud(cols), reading=wide)
    assert layout.kept == 360
    u = sweep.xy / np.hypot(sweep.xy[:, 0], sweep.xy[:, 1])[:, None]
    assert np.allclose(sweep.velocity, -u @ np.array([1.2, -0.4]), atol=1e-6)
    with pytest.raises(Rejected, match="no point of the 3-D cloud's 180 within ±2° of the sensor's plane"):
        sweep_from_pointcloud(PATH, cloud(_rings([-15.0, 15.0])))


def test_a_cloud_is_3d_by_the_spread_of_its_z_or_by_its_rings():
    assert not is_3d(np.zeros(10), None)
    assert not is_3d(np.full(10, 0.3) + np.linspace(0, 0.005, 10), None)  # a planar scanner mounted 0.3 m up
    assert is_3d(np.linspace(-0.5, 2.0, 10), None)
    assert is_3d(np.zeros(10), np.repeat([0, 1], 5))
    assert not is_3d(None, np.zeros(10))


@pytest.mark.parametrize("elevation_deg", [0.0, 2.0, 10.0, -25.0, 45.0])
def test_the_doppler_of_a_point_at_elevation_e_is_cos_e_of_the_planar_one_and_is_corrected(elevation_deg):
    """Sensor moving at (1.5, 0.6) m/s in its plane, static points at a known elevation all round."""
    v_s = np.array([1.5, 0.6])
    e = np.radians(elevation_deg)
    phi = np.linspace(-np.pi, np.pi, 73)
    u = np.column_stack([np.cos(phi), np.sin(phi)])
    xyz = 7.0 * np.column_stack([np.cos(e) * u, np.full(len(phi), np.sin(e))])
    v_r = -(xyz / 7.0) @ np.array([*v_s, 0.0])  # the 3-D bearing
    assert np.allclose(v_r, np.cos(e) * -(u @ v_s))  # cos(e) of what a planar sensor would see
    assert np.allclose(planar_doppler(xyz, v_r), -(u @ v_s))
    fit = fit_sensor_velocity(xyz[:, :2], planar_doppler(xyz, v_r), random_state=0)
    assert np.allclose(fit.v_sensor, v_s, atol=1e-9)
    if elevation_deg:  # uncorrected, the fit is cos(e) of the truth: 1.5 cm/s short at 10 deg of 1.6 m/s
        raw = fit_sensor_velocity(xyz[:, :2], v_r, random_state=0)
        assert np.allclose(raw.v_sensor, np.cos(e) * v_s, atol=1e-9)


def test_a_movers_doppler_is_corrected_the_same_way():
    """A point on a mover (horizontal velocity v_t) at elevation e: u₃·(v_t − v_s) = cos e · u·(v_t − v_s)."""
    e, phi = np.radians(8.0), 0.7
    u = np.array([np.cos(phi), np.sin(phi)])
    u3 = np.array([np.cos(e) * u[0], np.cos(e) * u[1], np.sin(e)])
    v_s, v_t = np.array([1.0, 0.2, 0.0]), np.array([-0.5, 1.1, 0.0])
    v_r = u3 @ (v_t - v_s)
    assert np.isclose(planar_doppler(5.0 * u3[None, :], np.array([v_r]))[0], u @ (v_t - v_s)[:2])


def test_a_time_field_of_a_datatype_no_pointfield_has_is_a_damaged_sweep_not_a_refused_log():
    with pytest.raises(Rejected, match="field 't' has unknown datatype 99") as exc:
        msg = cloud({**_planar(), "t": (7, T_S)})
        msg.fields[-1].datatype = 99
        sweep_from_pointcloud(PATH, msg)
    assert exc.value.kind == "layout"
