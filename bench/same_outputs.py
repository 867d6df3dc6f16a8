"""Every output of two fmcwlog checkouts compared, timings aside: a change that should not change results.

    python bench/same_outputs.py make OUT [--source CHECKOUT]   # OUT/run (fmcwlog run: 120 s corridor),
                                                                # OUT/corridor_30s, OUT/crowd_30s (sample logs, reported)
    python bench/same_outputs.py compare BEFORE AFTER           # exit 0: the same; else each difference, one line

``make`` runs ``python -m fmcwlog`` in CHECKOUT (default: this one), so two worktrees of two commits
give the two folders. ``compare`` wants every file byte for byte the same except what measures time
or the moment and place of the run, which differs from run to run of the same commit:

- JSON: the keys ``wall_seconds``, ``seconds``, ``ms_per_sweep_*``, ``sweeps_per_second``,
  ``wall_sweeps_per_second``, ``report_date_utc`` and ``out_dir`` (the output folder's own path) are left out;
- ``trajectories.parquet``: its ``ms`` column is left out (the other columns compared exactly);
- text files: the output folder's own path is read as ``OUT``;
- report pages (``report.md``, ``report.html``): the ``reported by`` line, table columns headed by a
  time (``ms``, ``sweeps/s``), the whole run's wall clock and rate and the time-per-sweep figure are
  left out.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pyarrow.parquet as pq

REPO = Path(__file__).resolve().parents[1]
TIMING_KEYS = re.compile(r"^(wall_seconds|seconds|ms_per_sweep\w*|(wall_)?sweeps_per_second|report_date_utc|out_dir)$")
WALL_CLOCK = re.compile(r"[0-9.]+ s of wall clock, [0-9.]+ sweeps/s")  # the report's sentence on the whole run
TIME_HEADER = re.compile(r"\bms\b|sweeps/s")
SAMPLES = ("corridor_30s", "crowd_30s")


def make(out: Path, source: Path) -> None:
    """The outputs of ``fmcwlog run`` and of the two sample logs (processed and reported), made by ``source``."""
    out.mkdir(parents=True, exist_ok=False)

    def fmcwlog(*args: str) -> None:
        subprocess.run([sys.executable, "-m", "fmcwlog", "-q", *args], cwd=source, check=True)

    fmcwlog("run", "-o", str(out / "run"))
    (out / "logs").mkdir()
    for name in SAMPLES:  # copied into OUT, so that the log's path in run.json and the report is OUT's
        log = out / "logs" / f"{name}.mcap"
        shutil.copyfile(source / "sample_logs" / f"{name}.mcap", log)
        fmcwlog("process", str(log), "-o", str(out / name))
        fmcwlog("report", str(out / name))


def _without_timings(doc):
    if isinstance(doc, dict):
        return {k: _without_timings(v) for k, v in doc.items() if not TIMING_KEYS.match(k)}
    if isinstance(doc, list):
        return [_without_timings(v) for v in doc]
    return doc


def _markdown_page(text: str) -> list[str]:
    lines, masked = [], set()
    for line in WALL_CLOCK.sub("*", text).splitlines():
        if line.startswith("- reported by:"):
            continue
        if line.startswith("|"):
            cells = line.strip("|").split("|")
            if not set(line) <= set("|-: "):
                if any(TIME_HEADER.search(c) for c in cells) and not masked:
                    masked = {i for i, c in enumerate(cells) if TIME_HEADER.search(c)}
                cells = ["*" if i in masked else c for i, c in enumerate(cells)]
            line = "|".join(cells)
        else:
            masked = set()
        lines.append(line)
    return lines


def _html_page(text: str) -> str:
    text = re.sub(r"<tr><td>reported by</td><td>[^<]*</td></tr>", "", WALL_CLOCK.sub("*", text))
    text = re.sub(r'<figure><img alt="time per sweep[^"]*" src="[^"]*">', "<figure>", text)

    def table(m: re.Match) -> str:
        heads = re.findall(r"<th[^>]*>(.*?)</th>", m.group(0))
        masked = {i for i, h in enumerate(heads) if TIME_HEADER.search(h)}
        if not masked:
            return m.group(0)

        def row(r: re.Match) -> str:
            cells = re.findall(r"<td[^>]*>.*?</td>", r.group(0))
            return "<tr>" + "".join("<td>*</td>" if i in masked else c for i, c in enumerate(cells)) + "</tr>"
        return re.sub(r"<tr>(?:<td.*?</td>)+</tr>", row, m.group(0))
    return re.sub(r"<table>.*?</table>", table, text, flags=re.S)


def same(a: Path, b: Path, root_a: Path, root_b: Path) -> bool:
    """Whether ``a`` (under ``root_a``) and ``b`` (under ``root_b``) hold the same, timings and the
    folders' own paths aside."""
    if a.read_bytes() == b.read_bytes():
        return True
    text_a = a.read_text(errors="replace").replace(str(root_a.resolve()), "OUT")
    text_b = b.read_text(errors="replace").replace(str(root_b.resolve()), "OUT")
    if a.suffix == ".json":
        return _without_timings(json.loads(text_a)) == _without_timings(json.loads(text_b))
    if a.suffix == ".parquet":
        ta, tb = pq.read_table(a), pq.read_table(b)
        keep = [c for c in ta.column_names if c != "ms"]
        return ta.column_names == tb.column_names and ta.select(keep).equals(tb.select(keep))
    if a.name == "report.md":
        return _markdown_page(text_a) == _markdown_page(text_b)
    if a.name == "report.html":
        return _html_page(text_a) == _html_page(text_b)
    return False


def compare(before: Path, after: Path) -> int:
    names = sorted({p.relative_to(before) for p in before.rglob("*") if p.is_file()}
                   | {p.relative_to(after) for p in after.rglob("*") if p.is_file()})
    problems = []
    for name in names:
        a, b = before / name, after / name
        if not a.is_file() or not b.is_file():
            problems.append(f"{name}: only in {'after' if not a.is_file() else 'before'}")
        elif not same(a, b, before, after):
            problems.append(f"{name}: differs")
    for line in problems:
        print(line)
    print(f"{len(names) - len(problems)} of {len(names)} files the same (timings aside)")
    return 1 if problems else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    m = sub.add_parser("make", help="make the outputs")
    m.add_argument("out", type=Path)
    m.add_argument("--source", type=Path, default=REPO, help="the checkout to run (default: this one)")
    c = sub.add_parser("compare", help="compare two folders made by 'make'")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    args = parser.parse_args()
    if args.command == "make":
        make(args.out.resolve(), args.source.resolve())
        return 0
    return compare(args.before, args.after)


if __name__ == "__main__":
    sys.exit(main())
