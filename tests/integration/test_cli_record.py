"""`fmcwlog record` from the command line: clear errors, no debris, safe interruption."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

pytestmark = pytest.mark.slow  # end to end: fmcwlog record in a subprocess


def run(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "fmcwlog", *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def assert_one_line_error(proc: subprocess.CompletedProcess, *words: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("fmcwlog: error:"), proc.stderr
    assert "Traceback" not in proc.stderr
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.parametrize(
    "args, words",
    [
        (["--scenario", "mars"], ["mars"]),
        (["--duration", "-3"], ["duration"]),
        (["--duration", "abc"], ["--duration"]),
        (["--set", "sensor.range_sigmaa=0.1"], ["range_sigmaa"]),
        (["--set", "robot.speed=fast"], ["robot.speed"]),
    ],
)
def test_bad_arguments_give_one_line_and_no_file(tmp_path, args, words):
    out = tmp_path / "x.mcap"
    assert_one_line_error(run("record", "-o", str(out), *args), *words)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    "text, words",
    [
        ("walls: [[0, 0, 1", ["malformed"]),
        ("walls: [[0, 0, 1, 1]]\n", ["route"]),
        ("walls: [[0, 0, 1]]\nroute: {waypoints: [[0, 0], [1, 0]], loop: false}\n", ["walls"]),
        ("walls: [[0, 0, 5, 0]]\nroute: {waypoints: [[0, 0], [1, 0]], loop: false}\nmovers: [{kind: dog, path: [[0, 0], [1, 1]]}]\n",
         ["movers[0].kind"]),
        ("walls: [[0, 0, 5, 0]]\nroute: {waypoints: [[0, 0]]}\n", ["waypoints"]),
        ("walls: [[0, 0, 5, 0]]\nroute: {waypoints: [[0, 1], [4, 1]], loop: false}\n"
         "features: [{id: 1, name: x, a: [0, 0], b: [0, 0]}]\n", ["features[0]", "same point"]),
    ],
)
def test_malformed_world_file_names_the_file_and_the_problem(tmp_path, text, words):
    world = tmp_path / "w.yaml"
    world.write_text(text)
    out = tmp_path / "x.mcap"
    assert_one_line_error(run("record", "--world", str(world), "-o", str(out)), "w.yaml", *words)
    assert not out.exists()


def test_existing_output_is_refused_without_force(tmp_path):
    out = tmp_path / "x.mcap"
    out.write_bytes(b"precious")
    assert_one_line_error(run("record", "-o", str(out), "--duration", "0.5"), "exists", "--force")
    assert out.read_bytes() == b"precious"
    ok = run("record", "-o", str(out), "--duration", "0.5", "--force")
    assert ok.returncode == 0, ok.stderr
    assert out.read_bytes()[:5] == b"\x89MCAP"


def test_world_file_and_config_file_are_used(tmp_path):
    world = tmp_path / "hall.json"
    world.write_text(json.dumps({
        "name": "hall",
        "walls": [[0, 0, 12, 0], [12, 0, 12, 8], [12, 8, 0, 8], [0, 8, 0, 0]],
        "features": [{"id": 1, "name": "south wall", "a": [0, 0], "b": [12, 0]}],
        "route": {"waypoints": [[2, 2], [10, 2], [10, 6], [2, 6]], "loop": True, "corner_radius": 1.0},
        "movers": [{"kind": "cart", "path": [[3, 4], [9, 4]], "speed": 0.7}],
    }))
    config = tmp_path / "params.toml"
    config.write_text("[sensor]\nfov_deg = 180.0\nresolution_deg = 0.5\n[run]\nseed = 3\n")
    out = tmp_path / "hall.mcap"
    proc = run("record", "--world", str(world), "--config", str(config), "--duration", "1", "-o", str(out))
    assert proc.returncode == 0, proc.stderr
    with open(out, "rb") as fh:
        reader = make_reader(fh)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert float(meta["fmcwlog.calibration"]["fov"]) == pytest.approx(3.14159265, abs=1e-6)
    assert json.loads(meta["fmcwlog.world"]["features"])[0]["b"] == [12.0, 0.0]
    assert json.loads(meta["fmcwlog.sim"]["config"])["run"]["seed"] == 3


def test_ctrl_c_leaves_a_valid_shorter_log(tmp_path):
    out = tmp_path / "long.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "fmcwlog", "record", "-o", str(out), "--duration", "600"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60

    def partial_size() -> int:  # the log is written as .long.mcap.partial-PID until it is complete
        return sum(p.stat().st_size for p in tmp_path.glob(".long.mcap.partial*"))

    while partial_size() <= 200_000 and time.time() < deadline:
        time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 0, stderr
    assert "stopped early" in stdout
    assert not list(tmp_path.glob(".long.mcap.partial*"))
    with open(out, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()  # a finished file: summary and footer are there
        stats = summary.statistics
    counts = {summary.channels[cid].topic: n for cid, n in stats.channel_message_counts.items()}
    assert 0 < counts["/fmcw/points"] < 6000
    assert counts["/wheel/ticks"] == 5 * counts["/fmcw/points"]


def test_a_route_through_a_wall_is_refused_and_one_through_an_opening_is_not(tmp_path):
    """A waypoint on the wrong side of a wall would have the robot drive through it, and the log would
    still be written (points from inside the wall, a map with the robot's path across it). The route
    from (2, 2) to (18, 2) crosses x = 10: through the wall (10, 0)-(10, 5), or through a 1 m gap in it."""
    box = [[0, 0, 20, 0], [20, 0, 20, 5], [20, 5, 0, 5], [0, 5, 0, 0]]
    route = "route: {waypoints: [[2, 2], [18, 2]], loop: false}\n"
    solid = tmp_path / "solid.yaml"
    solid.write_text(f"walls: {box + [[10, 0, 10, 5]]}\n{route}")
    out = tmp_path / "x.mcap"
    assert_one_line_error(run("record", "--world", str(solid), "-o", str(out)), "solid.yaml", "walls[4]", "(10.00, 2.00)")
    assert not out.exists()
    door = tmp_path / "door.yaml"
    door.write_text(f"walls: {box + [[10, 0, 10, 1.5], [10, 2.5, 10, 5]]}\n{route}")
    ok = run("record", "--world", str(door), "-o", str(out), "--duration", "2")
    assert ok.returncode == 0, ok.stderr


def test_the_builtin_routes_and_the_readme_world_stay_clear_of_their_walls():
    import re

    import yaml

    from fmcwlog.sim import scenarios
    from fmcwlog.sim.world import route_crossing, world_from_dict

    for name, make in scenarios.SCENARIOS.items():
        w = make()
        assert route_crossing(w.walls, w.route.build()) is None, name
    from helpers import ROOT

    readme = (ROOT / "README.md").read_text()
    text = re.search(r"```yaml\n(name: my-floor.*?)```", readme, re.S)[1]
    world_from_dict(yaml.safe_load(text), "README")  # raises if its route crossed a wall
