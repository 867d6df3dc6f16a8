"""A full disk at any point of any writer: one line, exit 2, no debris, nothing of the user's lost.

The disk is simulated in this process: every file opened for writing (``open``, ``io.open``, so
``Path.write_*``, the MCAP writer, Pillow's PNG writer) and every parquet file (pyarrow writes
natively; its bytes are routed through ``open`` here) draws on a budget of bytes; the write that
would pass it fails with ``ENOSPC`` as the kernel's would. The commands run through the real
``cli.main``. A first, unlimited pass records at which byte each file starts; the command is
then re-run with the disk filling up at the first byte of each kind of file it writes, and
half-way through the largest.
"""

from __future__ import annotations

import builtins
import errno
import io
import os
import re
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from helpers import SAMPLE_LOGS, assert_one_line_error, copy_log, run_cli_here

from fmcwlog.io.atomic import MARKER

pytestmark = pytest.mark.slow  # end to end: the command line on logs, on a full disk

_PARTIAL = re.compile(r"^\.(.+)\.(partial|old)-\d+$")


class Disk:
    """A byte budget shared by every file written; ``starts`` maps each file to the byte it began at."""

    def __init__(self, budget: float = float("inf")):
        self.budget, self.used = budget, 0
        self.starts: dict[str, int] = {}
        self.sizes: dict[str, int] = {}

    def charge(self, path: str, n: int) -> None:
        self.starts.setdefault(path, self.used)
        if self.used + n > self.budget:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), path)
        self.used += n
        self.sizes[path] = self.sizes.get(path, 0) + n


class _File:
    """A file object opened for writing whose writes draw on the disk's budget."""

    def __init__(self, f, disk: Disk, path: str):
        self._f, self._disk, self._path = f, disk, path

    def write(self, data):
        self._disk.charge(self._path, len(data.encode() if isinstance(data, str) else memoryview(data).cast("B")))
        return self._f.write(data)

    def writelines(self, lines):
        for line in lines:
            self.write(line)

    def fileno(self):  # no way around the budget: Pillow falls back to write()
        raise io.UnsupportedOperation("fileno")

    def __getattr__(self, name):
        return getattr(self._f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._f.close()

    def __iter__(self):
        return iter(self._f)


@pytest.fixture
def disk(monkeypatch):
    """Install a :class:`Disk`; the test sets its budget."""
    d = Disk()
    real_open, real_write_table = builtins.open, pq.write_table

    def budget_open(file, mode="r", *args, **kwargs):
        f = real_open(file, mode, *args, **kwargs)
        if isinstance(file, int) or not any(c in mode for c in "wax+"):
            return f
        return _File(f, d, os.fspath(file))

    def budget_write_table(table, where, *args, **kwargs):
        if not isinstance(where, str | os.PathLike):
            return real_write_table(table, where, *args, **kwargs)
        sink = pa.BufferOutputStream()
        real_write_table(table, sink, *args, **kwargs)
        with budget_open(where, "wb") as fh:
            fh.write(sink.getvalue().to_pybytes())

    monkeypatch.setattr(builtins, "open", budget_open)
    monkeypatch.setattr(io, "open", budget_open)
    monkeypatch.setattr(pq, "write_table", budget_write_table)
    return d


_WHOLE_NAMES = {"run.json", "report.json", MARKER, "comparison.md", "comparison.json", "compare.json"}


def _kind(path: str) -> str:
    """What a file is, whatever temporary name it was written under: its suffix (mcap, tum, png, ...),
    or its whole name for files of their own kind (run.json, the marker, ...)."""
    name = Path(path).name
    m = _PARTIAL.match(name)
    name = m.group(1) if m else name
    return name if name in _WHOLE_NAMES else name.rsplit(".", 1)[-1]


def _failure_points(d: Disk) -> dict[str, int]:
    """A budget per kind of file: the byte it starts at (its first write fails), and half-way into the largest."""
    points: dict[str, int] = {}
    for path, start in sorted(d.starts.items(), key=lambda kv: kv[1]):
        points.setdefault(_kind(path), start)
    largest = max(d.sizes, key=lambda p: d.sizes[p])
    points["middle"] = d.starts[largest] + d.sizes[largest] // 2
    return points


def _tree(folder: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(folder)): (p.read_bytes() if p.is_file() else None) for p in sorted(folder.rglob("*"))}


def _assert_full_disk_failure(code: int, err: str, root: Path, before: dict, complete=()) -> None:
    """One line, no temporary file or folder anywhere, and the tree as it was, except the files
    named in ``complete``: outputs that a command with several finished before the disk filled."""
    line = assert_one_line_error(code, err)
    assert line.endswith(": no space left on device"), line
    leftovers = [p for p in root.rglob("*") if _PARTIAL.match(p.name)]
    assert not leftovers, leftovers
    after = _tree(root)
    assert {k: v for k, v in after.items() if Path(k).name not in complete} == \
        {k: v for k, v in before.items() if Path(k).name not in complete}  # nothing new, nothing of the user's lost
    assert set(after) == set(before)


def _short_log(path: Path, sweeps: int = 8) -> Path:
    def edit(topic, i, msg):
        return False if i >= (sweeps if topic == "/fmcw/points" else 5 * sweeps) else None

    copy_log(SAMPLE_LOGS / "corridor_30s.mcap", path, edit=edit)
    return path


def _fill_at_each_file(disk: Disk, root: Path, args: list[str], prepare=None, only=None, complete=()) -> dict[str, int]:
    """Run ``args`` once with room to spare (it must succeed), then with the disk full at each point
    (those whose kind is in ``only``, if given); returns every point found."""
    prepare = prepare or (lambda: None)
    prepare()
    before = _tree(root)
    disk.starts.clear(), disk.sizes.clear()
    disk.used = 0
    code, _, err = run_cli_here(*args)
    assert code == 0, err
    points = _failure_points(disk)
    for what, budget in points.items():
        if only is not None and what not in only:
            continue
        shutil.rmtree(root)
        root.mkdir()
        prepare()
        assert _tree(root) == before
        disk.budget, disk.used = budget, 0
        try:
            code, _, err = run_cli_here(*args)
        finally:
            disk.budget = float("inf")
        _assert_full_disk_failure(code, err, root, before, complete)
    return points


def _user_files(root: Path) -> None:
    (root / "notes.txt").write_text("the user's own file beside the outputs")


def test_record_on_a_full_disk(tmp_path, disk):
    root = tmp_path / "w"
    root.mkdir()
    args = ["-q", "record", "--duration", "1", "-o", str(root / "new" / "log.mcap")]  # its folder is made too
    points = _fill_at_each_file(disk, root, args, lambda: _user_files(root))
    assert "mcap" in points and any(k.startswith("middle") for k in points)


def test_record_force_on_a_full_disk_keeps_the_old_log(tmp_path, disk):
    root = tmp_path / "w"
    root.mkdir()

    def prepare():
        (root / "log.mcap").write_bytes(b"the previous log")

    _fill_at_each_file(disk, root, ["-q", "record", "--duration", "1", "-o", str(root / "log.mcap"), "--force"], prepare)


@pytest.fixture(scope="module")
def short_log(tmp_path_factory) -> Path:
    return _short_log(tmp_path_factory.mktemp("full_disk") / "s.mcap")


def test_process_on_a_full_disk_over_an_earlier_output(tmp_path, disk, short_log):
    root = tmp_path / "w"
    root.mkdir()
    earlier = tmp_path / "earlier"  # an output folder made once, copied in before each try

    code, _, err = run_cli_here("-q", "process", str(short_log), "-o", str(earlier))
    assert code == 0, err

    def prepare():
        _user_files(root)
        shutil.copytree(earlier, root / "out")

    points = _fill_at_each_file(disk, root, ["-q", "process", str(short_log), "-o", str(root / "out"), "--force"],
                                prepare)
    assert {"mcap", "pgm", "yaml", "png", "tum", "parquet", "run.json", MARKER} <= set(points), points


def test_report_on_a_full_disk(tmp_path, disk, short_log):
    root = tmp_path / "w"
    root.mkdir()
    made = tmp_path / "made"
    code, _, err = run_cli_here("-q", "process", str(short_log), "-o", str(made))
    assert code == 0, err

    def prepare():
        shutil.copytree(made, root / "out")

    points = _fill_at_each_file(disk, root, ["-q", "report", str(root / "out")], prepare,
                                only={"tum", "report.json", "html", MARKER})
    assert {"html", "md", "report.json", "tum", MARKER} <= set(points), points


def test_comparison_on_a_full_disk(tmp_path, disk, short_log):
    made = tmp_path / "made"
    code, _, err = run_cli_here("-q", "process", str(short_log), "-o", str(made))
    assert code == 0, err
    root = tmp_path / "w"
    root.mkdir()
    _, _, err = run_cli_here("-q", "report", str(made))  # reported once: a second report replaces its pages

    def prepare():
        for name in ("a", "b"):
            shutil.copytree(made, root / name)

    args = ["-q", "report", str(root / "a"), str(root / "b"), "-o", str(root / "cmp" / "here")]
    # the disk fills at comparison.json, when comparison.md is written under its temporary name, or at
    # compare.json, the page's data: none of the four may appear, nor the folders made for them; each
    # folder's report was finished before, and stays
    points = _fill_at_each_file(disk, root, args, prepare, only={"comparison.json", "compare.json"},
                                complete={"report.json", "report.md", "report.html", "gt.tum"})
    assert points["comparison.md"] < points["comparison.json"] < points["compare.json"], points


def test_import_on_a_full_disk(tmp_path, disk):
    root = tmp_path / "w"
    root.mkdir()
    ranges = " ".join(["2.0"] * 180)
    lines = [f"ODOM {0.01 * i:.2f} 0 0 0.1 0 0 {100 + 0.1 * i:.1f} h {100 + 0.1 * i:.1f}" for i in range(50)]
    lines += [f"FLASER 180 {ranges} {0.01 * i:.2f} 0 0 {0.01 * i:.2f} 0 0 {100.05 + 0.1 * i:.2f} h 1" for i in range(50)]
    src = tmp_path / "log.clf"
    src.write_text("\n".join(lines) + "\n")
    _fill_at_each_file(disk, root, ["-q", "import", "carmen", str(src), "-o", str(root / "out" / "log.mcap")],
                       lambda: _user_files(root))


def test_run_on_a_full_disk_puts_the_earlier_run_back(tmp_path, disk):
    root = tmp_path / "w"
    root.mkdir()
    earlier = tmp_path / "earlier"
    code, _, err = run_cli_here("-q", "run", "-o", str(earlier), "--duration", "1")
    assert code == 0, err

    def prepare():
        _user_files(root)
        shutil.copytree(earlier, root / "run")

    points = _fill_at_each_file(disk, root, ["-q", "run", "-o", str(root / "run"), "--duration", "1", "--force"],
                                prepare, only={"mcap", "middle", "parquet", "html", MARKER})
    assert {"mcap", "html", "parquet"} <= set(points), points


def test_calibrate_on_a_full_disk_names_the_file(tmp_path, disk):
    """calibrate's one line once read 'fmcwlog: error: no space left on device', naming no file."""
    log = _short_log(tmp_path / "s.mcap", sweeps=60)
    root = tmp_path / "w"
    root.mkdir()
    out = root / "calib.yaml"
    points = _fill_at_each_file(disk, root, ["-q", "calibrate", str(log), "-o", str(out)], lambda: _user_files(root))
    assert "yaml" in points
    disk.budget, disk.used = points["yaml"], 0
    try:
        code, _, err = run_cli_here("-q", "calibrate", str(log), "-o", str(out))
    finally:
        disk.budget = float("inf")
    assert assert_one_line_error(code, err).startswith(f"fmcwlog: error: {out}: cannot write")
