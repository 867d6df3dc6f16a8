"""What ``fmcwlog process`` leaves in its output folder, in the field's usual formats.

- ``<method>.tum``: ``t x y z qx qy qz qw`` per sweep (evo, TUM RGB-D format);
- ``trajectories.parquet``: a row per sweep and method (pandas, pyarrow);
- ``<method>_map.pgm`` + ``.yaml`` (ROS map_server) and ``<method>_map.png``;
- ``processed.mcap``: estimated odometry, maps, static/moving points and the per-point
  moving verdicts (``/<method>/moving_labels``, index for index with the input sweep);
- ``run.json``: parameters, package version, inputs and counts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ..geometry import quaternion_to_yaw, yaw_to_quaternion
from .mcap_log import LogWriter
from .messages import odometry_message, pointcloud_message, stamp

if TYPE_CHECKING:  # the grid is built by the front end; only its export methods are used here
    from ..frontend.occupancy import OccupancyGrid

TRAJECTORY_COLUMNS = ("method", "stamp_ns", "t", "x", "y", "yaw", "icp_iterations", "correspondences",
                      "moving_points", "ms")


def write_tum(path: Path, stamps_ns: np.ndarray, poses: np.ndarray) -> None:
    """TUM trajectory file: seconds (9 decimals), position (m), quaternion (x, y, z, w)."""
    q = yaw_to_quaternion(poses[:, 2])
    t = np.asarray(stamps_ns, dtype=np.int64)
    lines = [
        f"{s // 1_000_000_000}.{s % 1_000_000_000:09d} {p[0]:.6f} {p[1]:.6f} 0.0 {qq[0]:.9f} {qq[1]:.9f} {qq[2]:.9f} {qq[3]:.9f}"
        for s, p, qq in zip(t.tolist(), poses, q)
    ]
    path.write_text("\n".join(lines) + ("\n" if lines else ""))


def read_tum(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (s) and poses (N, 3) of a planar TUM file."""
    a = np.loadtxt(path, ndmin=2)
    if a.size == 0:
        return np.zeros(0), np.zeros((0, 3))
    return a[:, 0], np.column_stack([a[:, 1], a[:, 2], quaternion_to_yaw(a[:, 4], a[:, 5], a[:, 6], a[:, 7])])


def write_trajectories_parquet(path: Path, rows: dict[str, list]) -> None:
    table = pa.table({
        "method": pa.array(rows["method"], pa.string()),
        "stamp_ns": pa.array(rows["stamp_ns"], pa.int64()),
        "t": pa.array(np.asarray(rows["stamp_ns"], dtype=np.int64) * 1e-9, pa.float64()),
        **{k: pa.array(rows[k], pa.float64()) for k in ("x", "y", "yaw", "ms")},
        **{k: pa.array(rows[k], pa.int64()) for k in ("icp_iterations", "correspondences", "moving_points")},
    })
    pq.write_table(table.select(list(TRAJECTORY_COLUMNS)), path)


def write_grid(folder: Path, name: str, grid: OccupancyGrid) -> None:
    """``name.pgm`` + ``name.yaml`` (map_server) and ``name.png`` (a picture of the same)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg

    (folder / f"{name}.pgm").write_bytes(grid.to_pgm_bytes())
    (folder / f"{name}.yaml").write_text(grid.map_server_yaml(f"{name}.pgm"))
    mpimg.imsave(folder / f"{name}.png", pgm_pixels(grid.to_pgm_bytes()), cmap="gray", vmin=0, vmax=255)


def pgm_pixels(data: bytes) -> np.ndarray:
    """Pixels of a binary (P5) PGM with 8-bit samples."""
    parts: list[bytes] = []
    pos = 0
    while len(parts) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        parts.append(data[pos:end])
        pos = end
    w, h = int(parts[1]), int(parts[2])
    return np.frombuffer(data, np.uint8, count=w * h, offset=pos + 1).reshape(h, w)


@dataclass
class ProcessedLog:
    """Streams the processed MCAP: per sweep the estimated odometry and the split points."""

    path: Path
    writer: LogWriter = field(init=False)

    def __post_init__(self) -> None:
        self.writer = LogWriter(self.path)

    def sweep(self, method: str, stamp_ns: int, pose: np.ndarray, static_xy: np.ndarray, moving_xy: np.ndarray) -> None:
        w = self.writer
        w.write(f"/{method}/odom", "nav_msgs/msg/Odometry",
                odometry_message(stamp_ns, "map", "base_link", pose, np.zeros(3)), stamp_ns)
        for kind, xy in (("static", static_xy), ("moving", moving_xy)):
            cols = {"x": xy[:, 0], "y": xy[:, 1], "z": np.zeros(len(xy))}
            w.write(f"/{method}/points/{kind}", "sensor_msgs/msg/PointCloud2", pointcloud_message(stamp_ns, "map", cols),
                    stamp_ns)

    def moving_labels(self, method: str, stamp_ns: int, moving: np.ndarray) -> None:
        """The method's per-point verdict, index for index with the input sweep (1 = moving)."""
        self.writer.write(f"/{method}/moving_labels", "fmcwlog_msgs/msg/PointLabels",
                          {"header": {"stamp": stamp(stamp_ns), "frame_id": "lidar"},
                           "moving": np.asarray(moving, np.uint8).tobytes()}, stamp_ns)

    def odometry(self, topic: str, stamp_ns: int, pose: np.ndarray) -> None:
        self.writer.write(topic, "nav_msgs/msg/Odometry", odometry_message(stamp_ns, "map", "base_link", pose, np.zeros(3)),
                          stamp_ns)

    def grid(self, method: str, stamp_ns: int, grid: OccupancyGrid) -> None:
        msg = {
            "header": {"stamp": stamp(stamp_ns), "frame_id": "map"},
            "info": {
                "map_load_time": stamp(stamp_ns),
                "resolution": float(grid.resolution),
                "width": int(grid.width),
                "height": int(grid.height),
                "origin": {"position": {"x": float(grid.origin[0]), "y": float(grid.origin[1]), "z": 0.0},
                           "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            },
            "data": grid.to_ros_int8().tolist(),  # int8[]: the CDR writer takes bytes only for uint8
        }
        self.writer.write(f"/{method}/map", "nav_msgs/msg/OccupancyGrid", msg, stamp_ns)

    def close(self) -> None:
        self.writer.close()

    def abort(self) -> None:
        self.writer.abort()


class ProcessOutputs:
    """Everything ``fmcwlog process`` writes into its (temporary) output folder, fed sweep by sweep.

    ``processed.mcap`` is streamed; trajectories and the parquet rows are kept (a few
    numbers per sweep) and written by :meth:`finish`, with the maps.
    """

    def __init__(self, folder: Path, trajectories: tuple[str, ...]):
        self.folder = folder
        self.processed = ProcessedLog(folder / "processed.mcap")
        self.rows: dict[str, list] = {k: [] for k in ("method", "stamp_ns", "x", "y", "yaw", "icp_iterations",
                                                      "correspondences", "moving_points", "ms")}
        self.trajectories: dict[str, tuple[list, list]] = {name: ([], []) for name in trajectories}

    def add_sweep(self, method: str, stamp_ns: int, pose: np.ndarray, iterations: int, correspondences: int,
                  moving_points: int, ms: float, static_xy: np.ndarray, moving_xy: np.ndarray,
                  moving_mask: np.ndarray | None) -> None:
        """One method's result for one sweep; ``moving_mask`` is its per-point verdict, if it made one."""
        for k, v in (("method", method), ("stamp_ns", stamp_ns), ("x", pose[0]), ("y", pose[1]), ("yaw", pose[2]),
                     ("icp_iterations", iterations), ("correspondences", correspondences),
                     ("moving_points", moving_points), ("ms", ms)):
            self.rows[k].append(v)
        self.trajectories[method][0].append(stamp_ns)
        self.trajectories[method][1].append(pose)
        self.processed.sweep(method, stamp_ns, pose, static_xy, moving_xy)
        if moving_mask is not None:
            self.processed.moving_labels(method, stamp_ns, moving_mask)

    def add_pose(self, name: str, stamp_ns: int, pose: np.ndarray) -> None:
        """A pose of a trajectory that is not a method's (the motion prior's)."""
        self.trajectories[name][0].append(stamp_ns)
        self.trajectories[name][1].append(pose)
        self.processed.odometry(f"/{name}/odom", stamp_ns, pose)

    def ms_median(self) -> dict[str, float]:
        method = np.asarray(self.rows["method"])
        ms = np.asarray(self.rows["ms"], dtype=float)
        return {m: float(np.median(ms[method == m])) for m in dict.fromkeys(self.rows["method"])}

    def finish(self, grids: dict[str, OccupancyGrid]) -> None:
        """The maps, the trajectories and the parquet; ``processed.mcap`` closed."""
        last_ns = int(self.rows["stamp_ns"][-1])
        for method, grid in grids.items():
            write_grid(self.folder, f"{method}_map", grid)
            self.processed.grid(method, last_ns, grid)
        self.processed.close()
        for name, (stamps, poses) in self.trajectories.items():
            if stamps:
                write_tum(self.folder / f"{name}.tum", np.asarray(stamps), np.asarray(poses))
        write_trajectories_parquet(self.folder / "trajectories.parquet", self.rows)

    def abort(self) -> None:
        self.processed.abort()
