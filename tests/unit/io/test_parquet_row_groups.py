"""trajectories.parquet written a row group at a time: the same table as one written whole, and
the same bytes where it fits in one group."""

from __future__ import annotations

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from fmcwlog.io import outputs
from fmcwlog.io.outputs import PARQUET_COLUMNS, TrajectoryRows, write_trajectories_parquet


def _rows(n: int, seed: int = 0) -> TrajectoryRows:
    rng = np.random.default_rng(seed)
    rows = TrajectoryRows()
    for k in range(n):
        method = ("improved", "baseline", "wheel_odometry")[k % 3]
        values = {"method": method, "stamp_ns": 10**18 + (k // 3) * 10**8, "x": rng.normal(), "y": rng.normal(),
                  "yaw": rng.normal(), "v": rng.normal(), "omega": rng.normal()}
        if method != "wheel_odometry":  # the motion prior's rows leave the method columns null
            values.update(icp_iterations=int(rng.integers(1, 30)), correspondences=int(rng.integers(0, 900)),
                          moving_points=int(rng.integers(0, 50)), keyframe=bool(k % 7 == 0), ms=rng.exponential(),
                          x_frontend=rng.normal(), y_frontend=rng.normal(), yaw_frontend=rng.normal())
        rows.add(values)
    return rows


def _whole(path, rows: TrajectoryRows) -> None:
    """The straightforward form: one table of every row, written in one call."""
    table = pa.table({k: rows.arrow(k, t) for k, (t, _) in PARQUET_COLUMNS.items()})
    with open(path, "wb") as fh:
        pq.write_table(table, fh)


def test_row_groups_read_back_as_the_whole_table(tmp_path, monkeypatch):
    monkeypatch.setattr(outputs, "PARQUET_ROW_GROUP", 100)
    rows = _rows(1003)
    write_trajectories_parquet(tmp_path / "groups.parquet", rows)
    _whole(tmp_path / "whole.parquet", rows)
    grouped = pq.ParquetFile(tmp_path / "groups.parquet")
    assert grouped.metadata.num_row_groups == 11
    assert grouped.read().equals(pq.read_table(tmp_path / "whole.parquet"))  # values and nulls alike
    meta = grouped.schema_arrow.metadata
    assert b"fmcwlog.column.yaw" in meta and b"fmcwlog.frames" in meta


def test_one_group_is_the_bytes_of_one_write(tmp_path):
    rows = _rows(900)  # a 30 s log's three trajectories
    write_trajectories_parquet(tmp_path / "groups.parquet", rows)
    table = pa.table({k: rows.arrow(k, t) for k, (t, _) in PARQUET_COLUMNS.items()})
    meta = pq.read_schema(tmp_path / "groups.parquet").metadata
    with open(tmp_path / "whole.parquet", "wb") as fh:
        pq.write_table(table.replace_schema_metadata(meta), fh)
    assert (tmp_path / "groups.parquet").read_bytes() == (tmp_path / "whole.parquet").read_bytes()


def test_no_rows_is_an_empty_table(tmp_path):
    write_trajectories_parquet(tmp_path / "t.parquet", TrajectoryRows())
    table = pq.read_table(tmp_path / "t.parquet")
    assert table.num_rows == 0 and table.column_names == list(PARQUET_COLUMNS)
