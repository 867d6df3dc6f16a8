"""LiDAR-only robots: the improved method, the baseline and KISS-ICP on logs with no odometry and no Doppler.

For each scenario it records a log (``--duration`` s, seed 0), writes a copy without ``/wheel/ticks``,
``/odom`` and the clouds' ``velocity`` field (the points and their times unchanged), runs
``fmcwlog process`` on that copy (``python -m fmcwlog`` in ``--source``, default this checkout, so
that two checkouts can be compared), the KISS-ICP peer (``bench/kiss_icp_peer.py``) and scores
them all with ``fmcwlog report``'s code: ATE RMSE after SE(2) alignment, with the back end and
without it (each method's ``<method>_frontend`` trajectory); and the time: median ms per sweep and
the wall time of ``fmcwlog process``, beside the same for the log as recorded (wheel ticks and Doppler in).

    python bench/lidar_only.py                              # corridor and crowd, 60 s each
    python bench/lidar_only.py --duration 20 --scenarios corridor
    python bench/lidar_only.py --source /path/to/other/checkout --out /tmp/before

Writes OUT/lidar_only.md and .json (``lidar_only_<duration>s`` for another duration; OUT default bench/results).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from results_io import kiss_icp_available, write_results  # noqa: E402

from fmcwlog.evaluation.evaluate import evaluate  # noqa: E402

DROPPED_TOPICS = ("/wheel/ticks", "/odom")
TRAJECTORIES = ("improved", "improved_frontend", "baseline", "baseline_frontend", "kiss_icp")


def lidar_only_copy(src: Path, dst: Path) -> None:
    """``src`` re-encoded without the odometry topics and without the clouds' ``velocity`` field."""
    with open(src, "rb") as fh:
        meta = {m.name: dict(m.metadata) for m in make_reader(fh).iter_metadata()}
    with open(src, "rb") as fh, open(dst, "wb") as out:
        w = Writer(out)
        for name, values in meta.items():
            w.add_metadata(name, values)
        schemas: dict[str, object] = {}
        for schema, channel, message, msg in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            if channel.topic in DROPPED_TOPICS:
                continue
            if schema.name == "sensor_msgs/msg/PointCloud2":
                msg.fields = [f for f in msg.fields if f.name != "velocity"]
            if schema.name not in schemas:
                schemas[schema.name] = w.register_msgdef(schema.name, schema.data.decode())
            w.write_message(channel.topic, schemas[schema.name], msg, log_time=message.log_time,
                            publish_time=message.publish_time)
        w.finish()


def _kiss(log: Path, out: Path) -> dict:
    child = ("import sys, json; from pathlib import Path; sys.path.insert(0, sys.argv[3]); "
             "from kiss_icp_peer import run_kiss_icp; print(json.dumps(run_kiss_icp(Path(sys.argv[1]), Path(sys.argv[2]))))")
    res = subprocess.run([sys.executable, "-c", child, str(log), str(out), str(HERE)], capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1"}, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def _process(log: Path, out: Path, source: Path) -> tuple[float, dict]:
    """``fmcwlog process`` of ``source`` on ``log``: its wall time (s) and run.json."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "fmcwlog", "-q", "process", str(log), "-o", str(out)], cwd=source, check=True)
    return time.perf_counter() - t0, json.loads((out / "run.json").read_text())


def run_scenario(scenario: str, duration: float, seed: int, tmp: Path, source: Path, with_kiss: bool,
                 with_odometry: bool) -> dict:
    full, log = tmp / f"{scenario}.mcap", tmp / f"{scenario}_lidar_only.mcap"
    subprocess.run([sys.executable, "-m", "fmcwlog", "-q", "record", "--scenario", scenario, "--duration", str(duration),
                    "--seed", str(seed), "-o", str(full)], cwd=HERE.parent, check=True)
    lidar_only_copy(full, log)
    out = tmp / f"{scenario}_out"
    wall, run = _process(log, out, source)
    methods = evaluate(out, log).result["methods"]
    row: dict = {"scenario": scenario, "seed": seed, "duration_s": duration, "wall_s": round(wall, 1),
                 "prior": run.get("prior"), "ms_per_sweep_median": run.get("ms_per_sweep_median"),
                 "warnings": run.get("warnings", [])}
    for m in TRAJECTORIES[:4]:
        row[m] = (methods.get(m) or {}).get("ate_rmse_m")
    row["kiss_icp"] = None
    if with_kiss:
        kiss_out = tmp / f"{scenario}_kiss"
        timing = _kiss(log, kiss_out)
        row["kiss_icp"] = evaluate(kiss_out, log).result["methods"]["kiss_icp"]["ate_rmse_m"]
        row["kiss_icp_ms_median"] = timing["ms_median"]
    if with_odometry:  # the same log as recorded, wheel ticks and Doppler in: what the LiDAR-only run costs beside it
        wall, run = _process(full, tmp / f"{scenario}_odometry_out", source)
        row["odometry_wall_s"], row["odometry_ms_per_sweep_median"] = round(wall, 1), run.get("ms_per_sweep_median")
    return row


def markdown(rows: list[dict], meta: dict) -> str:
    def cm(x: float | None) -> str:
        return "—" if x is None else f"{x * 100:.1f}"

    def ms(d: dict | None, m: str) -> str:
        return "—" if not d or m not in d else f"{d[m]:.1f}"

    lines = [f"{meta['duration_s']:g} s logs without odometry or Doppler, seed {meta['seed']}, {meta['machine']}; "
             "ATE RMSE in cm after SE(2) alignment.", "",
             "| scenario | improved | improved, front end alone | baseline | baseline, front end alone | KISS-ICP |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scenario']} | {cm(r['improved'])} | {cm(r['improved_frontend'])} | {cm(r['baseline'])} | "
                     f"{cm(r['baseline_frontend'])} | {cm(r['kiss_icp'])} |")
    lines += ["", "Median ms per sweep (improved / baseline; KISS-ICP) and `fmcwlog process`'s wall time; "
              "beside them the same logs as recorded, with wheel ticks and Doppler.", "",
              "| scenario | LiDAR-only ms | KISS-ICP ms | LiDAR-only wall s | with odometry ms | with odometry wall s |",
              "|---|---|---|---|---|---|"]
    for r in rows:
        d, o = r["ms_per_sweep_median"], r.get("odometry_ms_per_sweep_median")
        kms, owall = r.get("kiss_icp_ms_median"), r.get("odometry_wall_s")
        lines.append(f"| {r['scenario']} | {ms(d, 'improved')} / {ms(d, 'baseline')} | "
                     f"{'—' if kms is None else f'{kms:.1f}'} | {r['wall_s']:.0f} | {ms(o, 'improved')} / {ms(o, 'baseline')} | "
                     f"{'—' if owall is None else f'{owall:.0f}'} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenarios", nargs="+", default=["corridor", "crowd"])
    ap.add_argument("--duration", type=float, default=60.0, help="seconds per log (default 60)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--source", type=Path, default=HERE.parent, help="the checkout whose fmcwlog processes the logs")
    ap.add_argument("--no-kiss", action="store_true", help="skip the KISS-ICP peer")
    ap.add_argument("--no-odometry", action="store_true", help="skip processing the logs as recorded")
    ap.add_argument("--keep", type=Path, default=None, help="keep the logs and outputs in this folder")
    ap.add_argument("--out", type=Path, default=HERE / "results")
    args = ap.parse_args()
    with_kiss = kiss_icp_available(not args.no_kiss)
    rows = []
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = args.keep or Path(tmp_name)
        tmp.mkdir(parents=True, exist_ok=True)
        for scenario in args.scenarios:
            row = run_scenario(scenario, args.duration, args.seed, tmp, args.source.resolve(), with_kiss,
                               not args.no_odometry)
            rows.append(row)
            print(json.dumps({k: row[k] for k in ("scenario", *TRAJECTORIES, "wall_s")}), flush=True)
    meta = {"duration_s": args.duration, "seed": args.seed, "source": str(args.source.resolve()),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"}
    name = "lidar_only" if args.duration == 60.0 else f"lidar_only_{args.duration:g}s"
    write_results(args.out, name, markdown(rows, meta), {"meta": meta, "rows": rows})


if __name__ == "__main__":
    main()
