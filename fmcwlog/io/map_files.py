"""ROS map_server occupancy maps (``<name>.yaml`` + its image) read back as occupied cells.

The map_server convention (its ``map_server`` and ``map_saver`` documentation): the YAML
gives ``image``, ``resolution`` (m per pixel), ``origin`` (x, y, yaw of the lower-left
pixel's corner in the map's frame), ``negate``, ``occupied_thresh``, ``free_thresh`` and
``mode``; a pixel of value ``v`` has occupancy ``p = (255 - v) / 255`` (``v / 255`` when
``negate``), and is occupied when ``p > occupied_thresh``, free when ``p < free_thresh``.
The image's top row is the map's highest-y row. Only 8-bit binary PGM (P5) images are
read, the format ``map_saver`` and fmcwlog write.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ReportError
from .outputs import pgm_pixels


@dataclass(frozen=True)
class OccupancyImage:
    """An occupancy map as booleans, row 0 = lowest y (as ``nav_msgs/OccupancyGrid``).

    occupied, free: (H, W) masks; resolution: m per cell; origin: (x, y, yaw) of the
    lower-left cell's corner in the map's frame (m, m, rad).
    """

    occupied: np.ndarray
    free: np.ndarray
    resolution: float
    origin: tuple[float, float, float]

    def occupied_centres(self) -> np.ndarray:
        """Centres (N, 2) of the occupied cells in the map's frame, m."""
        rows, cols = np.nonzero(self.occupied)
        local = (np.column_stack([cols, rows]) + 0.5) * self.resolution
        x0, y0, yaw = self.origin
        c, s = np.cos(yaw), np.sin(yaw)
        return local @ np.array([[c, s], [-s, c]]) + np.array([x0, y0])


def _pgm_header(data: bytes) -> tuple[bytes, int, int, int]:
    """Magic, width, height and maxval of a PGM header (comments skipped); ValueError if malformed."""
    tokens: list[bytes] = []
    for line in data.split(b"\n"):
        tokens += line.split(b"#", 1)[0].split()
        if len(tokens) >= 4:
            return tokens[0], int(tokens[1]), int(tokens[2]), int(tokens[3])
    raise ValueError("truncated header")


def read_map_server(yaml_path: Path) -> OccupancyImage:
    """The occupied and free cells of a map_server map; :class:`ReportError` naming the file when unreadable."""
    import yaml

    try:
        info = yaml.safe_load(yaml_path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ReportError(f"{yaml_path}: cannot read the map description ({exc.__class__.__name__})") from None
    try:
        image = yaml_path.parent / str(info["image"])
        resolution = float(info["resolution"])
        origin = tuple(float(v) for v in info["origin"][:3])
        negate = bool(int(info.get("negate", 0)))
        occupied_thresh = float(info.get("occupied_thresh", 0.65))
        free_thresh = float(info.get("free_thresh", 0.196))
    except (TypeError, KeyError, ValueError, IndexError):
        raise ReportError(f"{yaml_path}: not a map_server map (needs image, resolution and origin [x, y, yaw])") \
            from None
    if not resolution > 0 or len(origin) != 3:
        raise ReportError(f"{yaml_path}: resolution must be > 0 and origin [x, y, yaw]")
    try:
        data = image.read_bytes()
        magic, width, height, maxval = _pgm_header(data)
        if magic != b"P5" or maxval > 255:
            raise ValueError("only 8-bit binary PGM (P5) is read")
        pixels = pgm_pixels(data)
        if pixels.shape != (height, width):
            raise ValueError("size differs from its header")
    except OSError:
        raise ReportError(f"{yaml_path}: its image {image} cannot be read") from None
    except (ValueError, IndexError) as exc:
        raise ReportError(f"{image}: not a readable map image ({exc})") from None
    p = pixels.astype(float) / 255.0
    p = p if negate else 1.0 - p
    rows_up = np.flipud  # the image's top row is the map's highest y
    return OccupancyImage(rows_up(p > occupied_thresh), rows_up(p < free_thresh), resolution,
                          (origin[0], origin[1], origin[2]))
