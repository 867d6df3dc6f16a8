"""How a PointCloud2 is read beyond x, y and velocity: each point's time, and a 3-D cloud brought
down to the sensor's plane.

**Point times.** The log format has ``t``, float32 seconds after ``header.stamp``. Drivers of real
sensors name and type it otherwise; a field is read by its name and type (:func:`choose_time_field`):

| field | type | read as |
|---|---|---|
| ``t`` | float32, float64 | s after ``header.stamp`` (the log format) |
| ``t`` | uint32 | ns after ``header.stamp`` (Ouster) |
| ``time_offset_ns`` | uint32 | ns after ``header.stamp`` (Aeva) |
| ``timestamp`` | float64 | s since the epoch, taken relative to ``header.stamp`` |

A field that looks like a time (``t``, or a name holding ``time`` or ``stamp``) in any other layout
is refused, naming the cloud's fields and ``--time-field NAME:UNIT``, which says how to read one
(:func:`parse_time_field`): guessing a unit wrong by 10⁹ would skew every sweep or reject them all.

**3-D clouds.** Every FMCW LiDAR on the market scans in 3-D; the estimation is planar. A cloud is
3-D when its ``z`` spreads over more than :data:`FLAT_Z_SPREAD` or its ring field
(:data:`RING_FIELDS`) holds more than one ring. Of a 3-D cloud only the points within
:attr:`InputParams.plane_band_deg` of elevation of the sensor's plane are kept (the floor, the
ceiling and anything sloped would otherwise be drawn as walls round the sensor), each projected
onto the plane (its ``x``, ``y``), and their Doppler is corrected for elevation
(:func:`planar_doppler`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import Checked, param
from ..errors import ConfigError, LogError

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}  # a time offset after header.stamp, in s per unit
EPOCH_UNITS = {"abs_s": 1.0, "abs_ns": 1e-9}  # a time since the epoch, in s per unit
RING_FIELDS = ("ring", "line_index", "line", "channel")  # Ouster/Velodyne/Hesai, Aeva, Livox, Robosense
# m: a planar scanner writes z = 0 (or leaves it out); a 3-D one spreads its rings over metres of height
FLAT_Z_SPREAD = 0.01
TYPE_NAMES = {1: "int8", 2: "uint8", 3: "int16", 4: "uint16", 5: "int32", 6: "uint32", 7: "float32", 8: "float64"}
_FLOATS, _UINT32 = (7, 8), 6


@dataclass(frozen=True)
class InputParams(Checked):
    """How the scan topic's points are read (the ``[inputs]`` table).

    plane_band_deg: of a 3-D cloud, the points within this elevation of the sensor's plane are
        kept (deg). 2°: on the simulated corridor with 16 rings from −15° to +15° (2° apart, the
        sensor 0.5 m above the floor) ±2° keeps the two rings nearest the plane, whose floor hits lie
        beyond 28 m, and the improved method's ATE is 2.1 cm (3.5 cm on the planar log); ±4° lets the
        floor in from 9.5 m and gives 31 cm (docs/real-logs.md). A wider band keeps more of the walls
        but draws the floor nearer: a ring at elevation −e meets it ``height / tan(e)`` away. Up
        to 60° (beyond, the Doppler correction by 1/cos(e) > 2 amplifies the noise more than it
        measures).
    """

    plane_band_deg: float = param(2.0, "deg", gt=0.0, le=60.0)


@dataclass(frozen=True)
class TimeField:
    """A per-point time field: its ``name``, and ``unit``, one of :data:`TIME_UNITS` (an offset
    after ``header.stamp``) or :data:`EPOCH_UNITS` (since the epoch)."""

    name: str
    unit: str

    def seconds(self, values: np.ndarray, stamp_ns: int) -> np.ndarray:
        """The field's values (N,) as s after ``stamp_ns``."""
        if self.unit in EPOCH_UNITS:
            return values * EPOCH_UNITS[self.unit] - stamp_ns * 1e-9
        return values * TIME_UNITS[self.unit]

    def describe(self, datatype: int) -> str:
        """``field 'time_offset_ns' (uint32) read as ns after header.stamp``."""
        what = (f"{self.unit[4:]} since the epoch" if self.unit in EPOCH_UNITS
                else f"{self.unit} after header.stamp")
        return f"field {self.name!r} ({TYPE_NAMES.get(datatype, f'datatype {datatype}')}) read as {what}"


TIME_FIELD_HELP = ("--time-field NAME:UNIT says how to read one (UNIT: s, ms, us or ns after header.stamp; "
                   "abs_s or abs_ns since the epoch)")


def parse_time_field(text: str | None) -> TimeField | None:
    """``"time_offset_ns:ns"`` -> ``TimeField("time_offset_ns", "ns")``; None for None or "".
    Raises :class:`~fmcwlog.errors.ConfigError` for anything else."""
    if not text:
        return None
    name, sep, unit = text.rpartition(":")
    if not sep or not name or unit not in TIME_UNITS | EPOCH_UNITS:
        raise ConfigError(f"--time-field expects NAME:UNIT with UNIT one of "
                          f"{', '.join((*TIME_UNITS, *EPOCH_UNITS))}, got {text!r}")
    return TimeField(name, unit)


def _known_time_field(name: str, datatype: int) -> TimeField | None:
    """The per-point time fields read by name and type (module docstring), else None."""
    if name == "t" and datatype in _FLOATS:
        return TimeField("t", "s")
    if name in ("t", "time_offset_ns") and datatype == _UINT32:
        return TimeField(name, "ns")
    if name == "timestamp" and datatype == 8:
        return TimeField(name, "abs_s")
    return None


def _time_like(name: str) -> bool:
    low = name.lower()
    return low == "t" or "time" in low or "stamp" in low


def fields_text(fields: dict[str, int]) -> str:
    """``x (float32), y (float32), t (uint64)``: a cloud's fields as a message names them."""
    return ", ".join(f"{n} ({TYPE_NAMES.get(d, f'datatype {d}')})" for n, d in fields.items())


def choose_time_field(fields: dict[str, int], mapped: TimeField | None) -> TimeField | None:
    """The per-point time field of a cloud with ``fields`` (name -> PointField datatype): ``mapped``
    (``--time-field``) if given, else one read by name and type; None when the cloud has no
    time-like field. Raises :class:`~fmcwlog.errors.LogError` (without the log's name: the
    caller adds it) when ``mapped`` is not among the fields or a time-like field of a valid datatype
    cannot be read."""
    if mapped is not None:
        if mapped.name not in fields:
            raise LogError(f"--time-field names {mapped.name!r}, which the cloud does not have "
                           f"(its fields: {fields_text(fields)})")
        return mapped  # a datatype that is no PointField's is damage: the layout check skips that sweep
    for name in ("t", "time_offset_ns", "timestamp"):
        if name in fields and (known := _known_time_field(name, fields[name])) is not None:
            return known
    unknown = [n for n, d in fields.items() if _time_like(n) and d in TYPE_NAMES]  # else damage, as above
    if unknown:
        raise LogError(f"PointCloud2 fields {fields_text(fields)}: no per-point time field of a known layout "
                       f"(t float32/float64 s or uint32 ns, time_offset_ns uint32 ns, timestamp float64 s since "
                       f"the epoch), and {', '.join(repr(n) for n in unknown)} cannot be read without a unit: "
                       f"{TIME_FIELD_HELP}")
    return None


def ring_field(fields: dict[str, int]) -> str | None:
    """The cloud's ring (scan line) field, if it has one of :data:`RING_FIELDS`."""
    return next((n for n in RING_FIELDS if n in fields), None)


def is_3d(z: np.ndarray | None, ring: np.ndarray | None) -> bool:
    """Whether a cloud is 3-D: its ``z`` spreads over more than :data:`FLAT_Z_SPREAD` m, or its ring
    field holds more than one ring."""
    if ring is not None and len(ring) and (ring != ring[0]).any():
        return True
    if z is None or not len(z):
        return False
    finite = np.isfinite(z)
    if not finite.all():
        z = z[finite]
        if not len(z):
            return False
    return float(z.max() - z.min()) > FLAT_Z_SPREAD  # np.ptp, without its dispatch


def elevation(xyz: np.ndarray) -> np.ndarray:
    """Elevation (N,) of points (N, 3) above the sensor's plane, rad (NaN where a coordinate is)."""
    return np.arctan2(xyz[:, 2], np.hypot(xyz[:, 0], xyz[:, 1]))


def planar_doppler(xyz: np.ndarray, v_r: np.ndarray) -> np.ndarray:
    """The radial velocities (N,) of points (N, 3) as a planar sensor would measure them at their
    projections onto its plane, m/s (positive when the range grows).

    A static point along the 3-D unit bearing ``u₃ = (cos e·u, sin e)`` (``u`` the planar bearing,
    ``e`` the elevation) seen by a sensor moving with ``v_s`` has ``v_r = −u₃ᵀ v_s``; for planar
    motion (``v_s`` in the plane) that is ``cos e · (−uᵀ v_s)``. A mover's own horizontal motion
    scales the same way. Dividing by ``cos e`` gives ``−uᵀ v_s``, the planar model of
    :mod:`fmcwlog.frontend.egomotion`; the noise grows by the same ``1/cos e``.
    """
    return v_r / np.cos(elevation(xyz))


@dataclass(frozen=True)
class Band:
    """Which points of a 3-D cloud are kept: ``keep`` (N,) bool, within ``half_angle_deg`` of the plane."""

    keep: np.ndarray
    half_angle_deg: float


def plane_band(xyz: np.ndarray, half_angle_deg: float) -> Band:
    """The points (N, 3) within ``half_angle_deg`` of elevation of the sensor's plane."""
    with np.errstate(invalid="ignore"):
        keep = np.abs(elevation(xyz)) <= math.radians(half_angle_deg)
    return Band(keep, half_angle_deg)


@dataclass(frozen=True)
class CloudReading:
    """How :class:`fmcwlog.io.inputs.LogInputs` reads a PointCloud2: the band of a 3-D cloud
    (:class:`InputParams`) and the time field ``--time-field`` names (None: by name and type)."""

    inputs: InputParams = InputParams()
    time_field: TimeField | None = None
