"""Fleets: a folder of logs, each in a worker of its own, locally and through Ray, and the fleet page.

The folder holds three short good logs (two share a stem, one has no ground truth), a file
that is not a log at all, and a long log whose worker is killed with SIGKILL while it is
writing (the test finds the worker by its ``.long.partial-PID`` folder, as an OOM killer
would pick it: nothing in fmcwlog knows it is under test). Each good log's results must be
byte-identical to ``api.process`` on that log alone (parquet: every column but ``ms``); the
bad ones must be reported with their reasons, the exit status must say so, and nothing of
them may be left behind. Trajectory errors and disagreements on the fleet page are checked
against the tests' own Kabsch alignment (helpers.ate_rmse), sweep counts against plain mcap.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from helpers import ROOT, ate_rmse, copy_log, decoded, ground_truth, tum

from fmcwlog import api
from fmcwlog.cli import cli
from fmcwlog.errors import ConfigError, FmcwlogError, LogError
from fmcwlog.evaluation.fleet import FleetRow, flag_logs
from fmcwlog.fleet.inputs import LOG_PATTERNS, find_logs, unique_names
from fmcwlog.fleet.local import run_one
from fmcwlog.fleet.state import completeness
from fmcwlog.fleet.tasks import Limits, LogTask
from fmcwlog.pipeline.options import options_digest
from fmcwlog.sim import scenarios
from fmcwlog.sim.config import SimConfig, apply_overrides
from fmcwlog.sim.recorder import record

IDENTICAL = ("improved.tum", "baseline.tum", "wheel_odometry.tum", "improved_map.pgm", "improved_map.yaml",
             "improved_map.png", "baseline_map.pgm", "baseline_map.yaml", "baseline_map.png", "processed.mcap")
GROUND_TRUTH_TOPICS = ("/ground_truth/odom", "/ground_truth/point_labels")


def _record(path: Path, scenario: str, duration: float, seed: int) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    record(scenarios.SCENARIOS[scenario](), apply_overrides(SimConfig(), {"run": {"duration": duration, "seed": seed}}),
           path)
    return path


@pytest.fixture(scope="session")
def fleet(tmp_path_factory):
    """The folder of logs, and each good log processed alone (the reference) under its batch name."""
    root = tmp_path_factory.mktemp("fleet")
    logs = root / "logs"
    _record(logs / "a.mcap", "corridor", 6.0, 0)
    _record(logs / "sub" / "a.mcap", "crowd", 5.0, 1)
    with_gt = _record(root / "nogt-source.mcap", "corridor", 6.0, 2)
    copy_log(with_gt, logs / "nogt.mcap", drop_topics=GROUND_TRUTH_TOPICS)
    (logs / "junk.mcap").write_bytes(b"these bytes are no MCAP log\n" * 10)
    (logs / "notes.txt").write_text("not a log: the search must pass it by\n")
    _record(logs / "long.mcap", "corridor", 90.0, 3)  # long enough to outlast a 2 s --timeout at any speed here
    names = {"a": "logs-a", "sub-a": "sub-a", "nogt": "nogt"}
    good = {names["a"]: logs / "a.mcap", names["sub-a"]: logs / "sub" / "a.mcap", names["nogt"]: logs / "nogt.mcap"}
    ref = root / "reference"
    for name, log in good.items():
        api.process(log, ref / name)
    return {"logs": logs, "good": good, "ref": ref, "root": root}


def _kill_when_writing(watch: Path, name: str, killed: dict, deadline_s: float = 300.0) -> threading.Thread:
    """Kill the worker writing ``.NAME.partial-PID`` (under ``watch``, at any depth) with SIGKILL
    once its processed.mcap has bytes in it: mid-way through the log."""
    pattern = re.compile(rf"^\.{re.escape(name)}\.partial-(\d+)$")

    def run() -> None:
        end = time.monotonic() + deadline_s
        while time.monotonic() < end and "pid" not in killed:
            for folder in (p for p in watch.rglob(f".{name}.partial-*") if p.is_dir()):
                m = pattern.match(folder.name)
                written = [f for f in folder.glob(".processed.mcap.partial-*") if f.stat().st_size > 0]
                if m and written:
                    killed["pid"] = int(m[1])
                    os.kill(killed["pid"], signal.SIGKILL)
                    return
            time.sleep(0.05)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def _assert_same_results(out: Path, ref: Path) -> None:
    for f in IDENTICAL:
        assert (out / f).read_bytes() == (ref / f).read_bytes(), f"{out / f} differs from a run on that log alone"
    a, b = pq.read_table(out / "trajectories.parquet"), pq.read_table(ref / "trajectories.parquet")
    assert a.drop(["ms"]).equals(b.drop(["ms"]))
    run = json.loads((out / "run.json").read_text())
    assert run["log_sha256"] == json.loads((ref / "run.json").read_text())["log_sha256"]


def _assert_bad_ones_reported(out: Path, reasons: dict[str, str], killed_pid: int) -> None:
    assert "not an MCAP file" in reasons["junk"]
    assert "killed by SIGKILL" in reasons["long"]
    done, total = map(int, re.search(r"at sweep (\d+) of (\d+)", reasons["long"]).groups())
    assert total == 900 and 0 <= done < total  # the long log: 90 s at 10 sweeps a second
    left = {p.name for p in out.iterdir()}
    assert "junk" not in left and "long" not in left
    assert not [n for n in left if n.startswith(".")], f"leftovers of failed logs: {left}"
    assert not (out / f".long.partial-{killed_pid}").exists()


@pytest.fixture(scope="module")
def local_batch(fleet):
    """``fmcwlog process LOGS -o OUT --jobs 2`` with the long log's worker killed mid-way."""
    out = fleet["root"] / "out"
    killed: dict = {}
    watcher = _kill_when_writing(out, "long", killed)
    proc = subprocess.run([sys.executable, "-m", "fmcwlog", "process", str(fleet["logs"]), "-o", str(out), "--jobs", "2"],
                          capture_output=True, text=True, timeout=600, cwd=ROOT)
    watcher.join(1)
    return out, proc, killed


@pytest.mark.slow
def test_a_folder_of_logs_gives_each_its_own_results_and_reports_the_bad_ones(fleet, local_batch):
    out, proc, killed = local_batch
    assert "pid" in killed, "the long log's worker was never seen writing"
    assert proc.returncode == 1, proc.stderr
    warnings = [ln for ln in proc.stderr.splitlines() if ln.startswith("fmcwlog: warning:")]
    assert any("junk.mcap" in w and "not an MCAP file" in w for w in warnings), proc.stderr
    assert any("long.mcap" in w and "killed by SIGKILL" in w for w in warnings), proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("fmcwlog: error: 2 of 5 logs failed")
    assert "Traceback" not in proc.stderr
    assert {p.name for p in out.iterdir() if p.is_dir()} == set(fleet["good"])
    for name in fleet["good"]:
        _assert_same_results(out / name, fleet["ref"] / name)
    batch = json.loads((out / "batch.json").read_text())
    assert {n: r["status"] for n, r in batch["logs"].items()} == {**dict.fromkeys(fleet["good"], "done"),
                                                                  "junk": "failed", "long": "failed"}
    _assert_bad_ones_reported(out, {n: r["reason"] for n, r in batch["logs"].items() if r["reason"]}, killed["pid"])


@pytest.mark.slow
def test_a_pipe_gets_a_line_as_each_log_ends(fleet, local_batch):
    """Without a terminal there is no bar: a CI log or ``| tee`` would show nothing for the whole
    batch (minutes, hours). Each log's end is one line, numbered, with what batch.json records."""
    out, proc, _ = local_batch
    batch = json.loads((out / "batch.json").read_text())["logs"]
    lines = [ln for ln in proc.stdout.splitlines() if re.match(r"^\[\d+/\d+\] ", ln)]
    assert [ln.split("]")[0] for ln in lines] == [f"[{i}/5" for i in range(1, 6)], proc.stdout
    said = {re.match(r"^\[\d+/5\] ([^:]+): (\w+)", ln).groups() for ln in lines}
    assert said == {(n, r["status"]) for n, r in batch.items()}
    for ln in lines:
        name = re.match(r"^\[\d+/5\] ([^:]+):", ln)[1]
        if batch[name]["status"] == "done":
            assert f"{batch[name]['sweeps']} sweeps in " in ln
        else:
            assert batch[name]["reason"] in ln
    summary = next(i for i, ln in enumerate(proc.stdout.splitlines()) if ln.startswith("5 logs: "))
    assert proc.stdout.splitlines().index(lines[-1]) < summary


@pytest.mark.slow
def test_running_it_again_skips_the_complete_logs(fleet, local_batch):
    out, _, _ = local_batch
    before = {n: (out / n / "run.json").stat() for n in fleet["good"]}
    # the same command (a --timeout shorter than the long log: what ran before does not run again)
    proc = subprocess.run([sys.executable, "-m", "fmcwlog", "process", str(fleet["logs"]), "-o", str(out), "--jobs", "2",
                           "--timeout", "2"], capture_output=True, text=True, timeout=600, cwd=ROOT)
    assert proc.returncode == 1
    assert "3 skipped (complete already)" in proc.stdout
    assert re.search(r"long\.mcap: timed out after 2 s \(--timeout\), at sweep \d+", proc.stderr), proc.stderr
    for n, st in before.items():
        now = (out / n / "run.json").stat()
        assert (now.st_ino, now.st_mtime_ns) == (st.st_ino, st.st_mtime_ns), f"{n} was redone"
    batch = json.loads((out / "batch.json").read_text())
    assert all(batch["logs"][n]["status"] == "skipped" for n in fleet["good"])
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


def test_batch_json_lists_its_logs_by_name_whatever_order_they_ended_in(tmp_path):
    """Workers end in the order their timing gives, and a resumed batch starts from the earlier
    batch.json: the file must not carry either order (the same batch, the same file)."""
    from fmcwlog.fleet.batch import _Record
    from fmcwlog.fleet.tasks import LogOutcome

    first = _Record(tmp_path, api.ProcessOptions(), "local")
    for name in ("zeta", "alpha"):  # the short log ended first
        first.add(LogOutcome(name, tmp_path / f"{name}.mcap", "done", sweeps=3))
    again = _Record(tmp_path, api.ProcessOptions(), "local")  # the same command run again
    again.add(LogOutcome("mid", tmp_path / "mid.mcap", "done"))
    again.add(LogOutcome("alpha", tmp_path / "alpha.mcap", "skipped", reason="complete"))
    text = (tmp_path / "batch.json").read_text()
    assert list(json.loads(text)["logs"]) == ["alpha", "mid", "zeta"]
    assert text.index('"alpha"') < text.index('"mid"') < text.index('"zeta"')


@pytest.mark.slow
def test_resumption_looks_at_the_bytes_and_the_options(fleet, tmp_path):
    name, log = next(iter(fleet["good"].items()))
    ref, opts = fleet["ref"] / name, api.ProcessOptions()
    moved = tmp_path / "moved.mcap"
    moved.write_bytes(log.read_bytes())
    assert completeness(ref, moved, options_digest(opts)) == (True, "complete")  # moved, same bytes: still complete
    changed = bytearray(log.read_bytes())
    changed[len(changed) // 2] ^= 1  # same size, one bit
    moved.write_bytes(bytes(changed))
    assert completeness(ref, moved, options_digest(opts)) == (False, "the log changed")
    other = api.ProcessOptions(params=api.ProcessParams(min_range=0.4))
    assert completeness(ref, log, options_digest(other)) == (False, "the options changed")
    assert completeness(tmp_path / "absent", log, options_digest(opts))[0] is False


CALIBRATION = {"wheel_radius_left": 0.1, "wheel_radius_right": 0.1, "track_width": 0.45, "ticks_per_revolution": 4096,
               "lidar_x": 0.35, "lidar_y": 0.0, "lidar_yaw": 0.0}


@pytest.mark.slow
def test_a_calibration_file_edited_in_place_is_a_change_of_options(tmp_path):
    """--calibration names a file: the results depend on its bytes, so a batch run again after
    the file was edited redoes the log (it used to skip it: the digest held only the path),
    and the same bytes at another path change nothing."""
    log = _record(tmp_path / "logs" / "a.mcap", "corridor", 3.0, 0)
    cal = tmp_path / "cal.yaml"
    cal.write_text("".join(f"{k}: {v}\n" for k, v in CALIBRATION.items()))
    out = tmp_path / "out"
    first = api.process_many([log], out, api.ProcessOptions(calibration=cal), jobs=1)
    assert first.count("done") == 1
    cal.write_text("".join(f"{k}: {0.40 if k == 'lidar_x' else v}\n" for k, v in CALIBRATION.items()))
    again = api.process_many([log], out, api.ProcessOptions(calibration=cal), jobs=1)
    assert again.count("done") == 1, [o.reason for o in again.outcomes]
    assert json.loads((out / "a" / "run.json").read_text())["mount"][0] == 0.40
    moved = tmp_path / "elsewhere.yaml"
    moved.write_bytes(cal.read_bytes())
    assert api.process_many([log], out, api.ProcessOptions(calibration=moved), jobs=1).count("skipped") == 1


@pytest.mark.slow
def test_a_log_renamed_by_a_newcomer_with_its_stem_is_resumed_not_doubled(tmp_path):
    """day1/run.mcap's results are OUT/run until day2/run.mcap arrives; then the names are
    day1-run and day2-run. The batch run again must hold what a fresh batch of both holds (it
    redid day1 beside the old folder, and the fleet page counted that log twice)."""
    first_log = _record(tmp_path / "logs" / "day1" / "run.mcap", "corridor", 3.0, 0)
    out = tmp_path / "out"
    assert api.process_many([tmp_path / "logs"], out, jobs=1).count("done") == 1
    made = (out / "run" / "run.json").stat()
    _record(tmp_path / "logs" / "day2" / "run.mcap", "corridor", 3.0, 1)
    again = api.process_many([tmp_path / "logs"], out, jobs=1)
    assert {o.name: o.status for o in again.outcomes} == {"day1-run": "skipped", "day2-run": "done"}
    assert sorted(p.name for p in out.iterdir()) == ["batch.json", "day1-run", "day2-run"]
    assert (out / "day1-run" / "run.json").stat().st_mtime_ns == made.st_mtime_ns  # the same results, moved
    assert json.loads((out / "day1-run" / "run.json").read_text())["log"] == str(first_log.resolve())
    assert sorted(json.loads((out / "batch.json").read_text())["logs"]) == ["day1-run", "day2-run"]
    seen: list[tuple[int, int, str]] = []
    assert [r["name"] for r in api.report_fleet(out, on_log=lambda *a: seen.append(a))["logs"]] == ["day1-run", "day2-run"]
    assert seen == [(1, 2, "day1-run"), (2, 2, "day2-run")]  # progress as each log is reported


@pytest.mark.slow
def test_the_fleet_page_has_a_row_per_log_and_flags_the_failed_ones(fleet, local_batch):
    out, _, _ = local_batch
    ran = CliRunner().invoke(cli, ["report", str(out)])  # in this process: the reports are the slow part
    assert ran.exit_code == 0, ran.output
    assert "needs a look" in ran.output and (out / "fleet.html").is_file()
    result = json.loads((out / "fleet.json").read_text())
    rows = {r["name"]: r for r in result["logs"]}
    assert set(rows) == {*fleet["good"], "junk", "long"}
    batch = json.loads((out / "batch.json").read_text())
    for n in ("junk", "long"):
        assert rows[n]["status"] == "failed" and rows[n]["reason"] == batch["logs"][n]["reason"]
        assert any(f.startswith("failed: ") for f in rows[n]["flags"])
    flagged = {f["name"] for f in result["flagged"]}
    assert {"junk", "long"} <= flagged
    sweeps = 0
    for n, log in fleet["good"].items():
        r = rows[n]
        assert (out / n / "report.html").is_file() and r["report"] == f"{n}/report.html"
        count = sum(1 for _ in decoded(log, ["/fmcw/points"]))
        assert r["sweeps"] == count
        sweeps += count
        est = {m: tum(out / n / f"{m}.tum") for m in ("improved", "baseline")}
        if n == "nogt":
            assert not r["ground_truth"] and r["ate_rmse_m"]["improved"] is None
            assert r["methods_disagreement_m"] == pytest.approx(ate_rmse(est["baseline"], est["improved"]), abs=1e-6)
            assert r["distance_from"] == "improved estimate"
        else:
            gt = ground_truth(log)
            assert r["ground_truth"] and r["distance_from"] == "ground truth"
            for m, e in est.items():
                assert r["ate_rmse_m"][m] == pytest.approx(ate_rmse(e, gt), abs=2e-3)
            inside = (gt[:, 0] >= est["improved"][0, 0]) & (gt[:, 0] <= est["improved"][-1, 0])
            assert r["distance_m"] == pytest.approx(np.sum(np.hypot(*np.diff(gt[inside, 1:3], axis=0).T)), rel=0.02)
    assert result["totals"]["sweeps"] == sweeps and result["totals"]["failed"] == 2


@pytest.fixture(scope="module")
def local_ray(tmp_path_factory):
    """One local Ray for the module (its start-up is the slow part); its workers' temporary
    folders under a folder the test can watch."""
    ray = pytest.importorskip("ray")
    tmp = tmp_path_factory.mktemp("ray-node-tmp")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, runtime_env={"env_vars": {"TMPDIR": str(tmp)}})
    yield tmp
    ray.shutdown()


@pytest.mark.slow
def test_the_same_batch_on_a_local_ray(fleet, local_ray):
    out = fleet["root"] / "out-ray"
    killed: dict = {}
    watcher = _kill_when_writing(local_ray, "long", killed)
    # 2 GB declared per task: a small CI machine's Ray still has a node that holds one
    summary = api.process_many([fleet["logs"]], out, ray=True, limits=Limits(memory_limit_mb=2048))
    watcher.join(1)
    assert "pid" in killed, "the long log's worker was never seen writing"
    status = {o.name: o.status for o in summary.outcomes}
    assert status == {**dict.fromkeys(fleet["good"], "done"), "junk": "failed", "long": "failed"}
    assert summary.executor == "ray" and all(o.host for o in summary.outcomes)  # each ran on a node
    for name in fleet["good"]:
        _assert_same_results(out / name, fleet["ref"] / name)
    _assert_bad_ones_reported(out, {o.name: o.reason for o in summary.failed}, killed["pid"])
    assert not list(local_ray.glob("fmcwlog-*")), "a node's temporary folder was left behind"
    again = api.process_many([fleet["logs"]], out, ray=True, limits=Limits(memory_limit_mb=2048, timeout_s=2))
    assert {o.name: o.status for o in again.outcomes if o.name in fleet["good"]} == dict.fromkeys(fleet["good"],
                                                                                                  "skipped")
    with pytest.raises(FmcwlogError, match="no Ray node has 100000000 MB"):  # would wait for ever: said at once
        api.process_many([fleet["logs"]], fleet["root"] / "out-ray-huge", ray=True, limits=Limits(memory_limit_mb=10**8))


@pytest.mark.slow
def test_a_worker_over_its_memory_cap_fails_alone_with_that_reason(fleet, tmp_path):
    log = fleet["good"]["logs-a"]
    task = LogTask("a", log, tmp_path / "a", api.ProcessOptions(), False, log.stat().st_size)
    # 150 MB of address space: less than numpy, pyarrow and the run map (the API refuses it, run_one does
    # not; 300 MB was enough to fail while the calibration check imported scipy.optimize, and no longer is)
    outcome = run_one(task, Limits(memory_limit_mb=150, timeout_s=120))
    assert outcome.status == "failed" and "out of memory" in outcome.reason and "150 MB" in outcome.reason
    assert not list(tmp_path.iterdir())
    with pytest.raises(ConfigError, match="--memory-limit"):
        api.process_many([log], tmp_path / "b", limits=Limits(memory_limit_mb=500))


def test_a_search_passes_by_hidden_entries_outputs_and_other_files(tmp_path):
    for rel in ("x/run.mcap", "y/run.mcap", "y/z/RUN.MCAP", "top.mcap", ".hidden/h.mcap", ".h.mcap",
                "done/processed.mcap", "out/k/processed.mcap", "note.txt"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    (tmp_path / "done" / "run.json").write_text("{}")
    logs = find_logs([tmp_path], skip=tmp_path / "out")
    assert [p.relative_to(tmp_path).as_posix() for p in logs] == ["top.mcap", "x/run.mcap", "y/run.mcap", "y/z/RUN.MCAP"]
    assert unique_names(logs) == ["top", "x-run", "y-run", "z-RUN"]  # a name's case is kept
    assert find_logs([tmp_path / "top.mcap", tmp_path]) == find_logs([tmp_path])  # each log once
    (tmp_path / "empty").mkdir()
    with pytest.raises(LogError, match="no logs found"):
        find_logs([tmp_path / "empty"])
    with pytest.raises(LogError, match="no such file or folder"):
        find_logs([tmp_path / "absent"])


def test_ray_given_a_path_as_its_address_says_how_to_write_it(tmp_path):
    (tmp_path / "logs").mkdir()
    ran = CliRunner().invoke(cli, ["process", "--ray", str(tmp_path / "logs"), "-o", str(tmp_path / "out")])
    assert ran.exit_code == 2 and "put --ray after the logs, or write --ray=ADDRESS" in ran.output
    assert not (tmp_path / "out").exists()


def _row(name: str, gt: bool, ate: float | None = None, disagree: float | None = None, starved: int = 0) -> FleetRow:
    return FleetRow(name, None, "done", ground_truth=gt, ate_rmse_m={"improved": ate}, methods_disagreement_m=disagree,
                    icp_starved_sweeps={"improved": starved}, sweeps=100)


def test_flags_go_to_the_clear_outliers_only():
    rows = [_row(f"gt{i}", True, ate=0.01 + 0.001 * i) for i in range(9)] + [_row("gt-bad", True, ate=0.5)]
    rows += [_row(f"free{i}", False, disagree=0.02) for i in range(7)] + [_row("free-bad", False, disagree=0.4)]
    rows += [_row("starved", False, disagree=0.02, starved=5)]
    flag_logs(rows)
    assert {r.name for r in rows if r.flags} == {"gt-bad", "free-bad", "starved"}
    assert "ATE RMSE 50.0 cm" in rows[9].flags[0] and "5 of 100 sweeps" in rows[-1].flags[0]
    even = [_row(f"e{i}", True, ate=0.01 + 0.0001 * i) for i in range(10)]
    flag_logs(even)
    assert not any(r.flags for r in even)  # the worst of ten good logs needs no look
    few = [_row(f"f{i}", False, disagree=0.02) for i in range(4)] + [_row("far", False, disagree=0.4)]
    flag_logs(few)
    assert not any(r.flags for r in few)  # five logs cannot show an outlier


@pytest.mark.slow
def test_import_carmen_takes_a_folder_and_goes_on_past_a_bad_file(tmp_path):
    src = tmp_path / "carmen"
    (src / "day2").mkdir(parents=True)
    ranges = " ".join(["2.0"] * 180)
    lines = [f"FLASER 180 {ranges} {0.1 * i:.1f} 0.0 0.0 {0.1 * i:.1f} 0.0 0.0 {100 + i}.0 host {100 + i}.0"
             for i in range(5)]
    (src / "good.clf").write_text("\n".join(lines) + "\n")
    (src / "day2" / "empty.log").write_text("# nothing usable\n")
    (src / "README.txt").write_text("not a log\n")
    out = tmp_path / "mcap"
    proc = subprocess.run([sys.executable, "-m", "fmcwlog", "import", "carmen", str(src), "-o", str(out)],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 1 and "no laser scans" in proc.stderr and "1 of 2 sources failed" in proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["good.mcap"]
    assert sum(1 for _ in decoded(out / "good.mcap", ["/scan"])) == 5
    again = api.import_carmen_many([src / "good.clf", src / "day2"], out)
    assert [(o.output.name, o.status) for o in again] == [("good.mcap", "skipped"), ("empty.mcap", "failed")]


@pytest.mark.slow
def test_force_on_a_batch_never_removes_a_file_fmcwlog_did_not_write(fleet, tmp_path):
    """A log's folder in the batch that holds the user's own file is not replaced, --force or not:
    that log fails with the reason, the file stays, and the batch's other logs are unaffected."""
    log = fleet["good"]["logs-a"]
    name = unique_names([log], LOG_PATTERNS)[0]
    mine = tmp_path / "out" / name / "my-notes.txt"
    mine.parent.mkdir(parents=True)
    mine.write_text("the user's own file\n")
    for force in (False, True):
        summary = api.process_many([log], tmp_path / "out", force=force, jobs=1)
        [outcome] = summary.outcomes
        assert outcome.status == "failed" and str(mine.parent) in outcome.reason, outcome.reason
        assert mine.read_text() == "the user's own file\n"


@pytest.mark.slow
def test_report_without_ground_truth_prints_how_far_the_methods_disagree(fleet, tmp_path):
    """A log with no ground truth: the console shows the methods' disagreement (as evo_ape -a of one
    trajectory against the other computes it), not a table of dashes that says nothing of why."""
    import shutil

    folder = tmp_path / "nogt"
    shutil.copytree(fleet["ref"] / "nogt", folder)
    ran = CliRunner().invoke(cli, ["report", str(folder)])
    assert ran.exit_code == 0, ran.output
    assert "no ground truth in nogt.mcap" in ran.output
    row = next(ln for ln in ran.output.splitlines() if ln.startswith("baseline "))
    printed = float(row.split()[1])
    evo_ape = shutil.which("evo_ape") or str(Path(sys.executable).parent / "evo_ape")
    res = subprocess.run([evo_ape, "tum", "improved.tum", "baseline.tum", "-a"], cwd=folder, capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    rmse = float(next(line.split()[-1] for line in res.stdout.splitlines() if line.strip().startswith("rmse")))
    assert printed == pytest.approx(rmse, abs=0.0006)  # printed to the millimetre


@pytest.mark.slow
def test_a_batch_stopped_before_any_log_ended_leaves_no_folder_of_its_own(fleet, tmp_path, monkeypatch):
    """Ctrl-C before the first log ends: the output folder the batch made is removed (it held nothing),
    a folder that was there before is kept, and nothing is left in it."""
    from fmcwlog.fleet import batch

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(batch, "run_local", interrupted)
    logs = [fleet["good"]["logs-a"]]
    with pytest.raises(KeyboardInterrupt):
        api.process_many(logs, tmp_path / "new" / "out", jobs=1)
    assert not (tmp_path / "new").exists()
    (tmp_path / "mine").mkdir()
    with pytest.raises(KeyboardInterrupt):
        api.process_many(logs, tmp_path / "mine", jobs=1)
    assert (tmp_path / "mine").is_dir() and not any((tmp_path / "mine").iterdir())
