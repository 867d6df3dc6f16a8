"""Benchmark: the compiled ``TargetGrid``'s nearest-point query, alone and inside the registrations
that use it, replayed from a log, for one build of ``fmcwlog._core`` or two compared.

1. ``capture LOG... -o CASES``: every registration the improved method (robust ICP), the baseline
   (point-to-point ICP) and the back end (point-to-line ICP: local edges, closures) make processing
   the logs (numpy kernels), written to one pickle.
2. ``replay CASES --core SO``: in this process, with the module at ``SO``: per registration the
   grid's build (once per distinct map), the registration through its Python entry point and the
   query alone (``nearest`` of the source under the start and the final pose), each the best of
   ``--repeat`` CPU times; printed as JSON.
3. ``compare CASES --core OLD --core NEW``: ``replay`` in a fresh process per build, alternating
   ``--rounds`` times, each number the best over the rounds; a table of the two and their ratio.

    python bench/target_grid.py capture sample_logs/crowd_30s.mcap sample_logs/corridor_30s.mcap -o /tmp/cases.pkl
    python bench/target_grid.py compare /tmp/cases.pkl --core /tmp/old/_core.so --core fmcwlog/_core.so
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's fmcwlog
for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[var] = "1"

import numpy as np

from fmcwlog.api import ProcessOptions, process
from fmcwlog.backend import local_edges, registration, verification
from fmcwlog.frontend import methods, robust_icp
from fmcwlog.frontend import point_to_point_icp as p2p
from fmcwlog.kernels import compiled


def capture(logs: list[str]) -> list[dict]:
    """Every registration of both methods on ``logs``: kind, log, the register call's arguments."""
    os.environ[compiled.ENV] = "numpy"
    compiled._chosen = None
    seen: list[dict] = []
    log_name = ""
    robust, baseline = methods.register, methods.register_point_to_point

    def robust_rec(source, tree, target, start, params, mixture=None, prior_pose=None, prior_information=None):
        seen.append(dict(kind="robust", log=log_name, args=(source.copy(), target.copy(), np.array(start, float),
                                                             params, mixture, prior_pose, prior_information)))
        return robust_icp.register_numpy(source, tree, target, start, params, mixture, prior_pose, prior_information)

    def baseline_rec(source, tree, target, start, params):
        seen.append(dict(kind="p2p", log=log_name, args=(source.copy(), target.copy(), np.array(start, float), params)))
        return p2p.register_point_to_point_numpy(source, tree, target, start, params)

    def line_rec(source, submap, initial, p=registration.LineICPParams(), prior=None):
        seen.append(dict(kind="line", log=log_name, args=(source.copy(), submap, np.array(initial, float), p, prior)))
        return registration.register_point_to_line(source, submap, initial, p, prior)

    methods.register, methods.register_point_to_point = robust_rec, baseline_rec
    local_edges.register_point_to_line = verification.register_point_to_line = line_rec
    try:
        for log in logs:
            log_name = Path(log).stem
            with tempfile.TemporaryDirectory() as tmp:
                process(log, tmp + "/out", ProcessOptions(methods=("improved", "baseline")), jobs=1)
    finally:
        methods.register, methods.register_point_to_point = robust, baseline
        local_edges.register_point_to_line = verification.register_point_to_line = registration.register_point_to_line
    return seen


def _map_and_gate(case: dict) -> tuple[np.ndarray, float]:
    """The case's target points (M, 2) and search radius (m)."""
    if case["kind"] == "line":
        return case["args"][1].points, case["args"][3].max_distance
    return case["args"][1], case["args"][3].max_correspondence_distance


def _best(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        c0 = time.process_time_ns()
        fn()
        best = min(best, time.process_time_ns() - c0)
    return best / 1e3


def _registration(case: dict, index: compiled.MapIndex, grid: object):
    """The case's registration as a call of no arguments, on ``index`` (point-to-line: ``grid``)."""
    source, target, start, params = case["args"][:4]
    if case["kind"] == "line":
        target.grids = {params.max_distance: grid}
        return partial(registration.register_point_to_line, source, target, start, params, case["args"][4])
    if case["kind"] == "robust":
        return partial(robust_icp.register, source, index, target, start, params, *case["args"][4:])
    return partial(p2p.register_point_to_point, source, index, target, start, params)


def _replay_one(module: ModuleType, case: dict, new_map: bool, repeat: int, out: dict[str, list]) -> None:
    """One case's times (build where ``new_map``, registration, queries) and result into ``out``."""
    source, start = case["args"][0], case["args"][2]
    target, gate = _map_and_gate(case)
    points = np.ascontiguousarray(target, dtype=float)
    out["build"].append(_best(partial(module.TargetGrid, points, gate), repeat) if new_map else 0.0)
    out["new_map"].append(new_map)
    index = compiled.MapIndex(target)
    grid = index.grid(module, gate)
    run = _registration(case, index, grid)
    out["register"].append(_best(run, repeat))
    result = run()
    kept = result.pairs if case["kind"] == "line" else result.n_correspondences_kept
    out["pose"].append(np.asarray(result.pose).tolist() + [result.iterations, kept])
    src = np.ascontiguousarray(source, dtype=float)
    n = len(src)
    moved, idx, dist = np.empty((n, 2)), np.empty(n, np.int64), np.empty(n)
    for key, pose in (("query_start", start), ("query_final", result.pose)):
        x, y, th = np.asarray(pose, dtype=float).tolist()
        out[key].append(_best(partial(module.nearest, grid, src, x, y, th, moved, idx, dist), repeat))
    out["n"].append(n)


def replay(cases: list[dict], so: str, repeat: int) -> dict:
    """CPU µs per case (build, registration, query at start and at final pose) with the module at ``so``."""
    module = compiled._from(Path(so))
    compiled._core, compiled._chosen = module, "compiled"
    out: dict[str, list] = {k: [] for k in ("build", "register", "query_start", "query_final", "n", "pose", "new_map")}
    last_target: dict[tuple, np.ndarray] = {}  # per log and kind: the map of its last registration
    for case in cases:
        target = _map_and_gate(case)[0]
        before = last_target.get((case["log"], case["kind"]))
        new_map = before is None or before.shape != target.shape or not np.array_equal(before, target)
        last_target[(case["log"], case["kind"])] = target
        _replay_one(module, case, new_map, repeat, out)
    return out


def compare(path: str, builds: list[str], rounds: int, repeat: int) -> None:
    """Alternate ``replay`` of each build in fresh processes; print per-kind totals and ratios."""
    cases = pickle.loads(Path(path).read_bytes())
    best: dict[str, dict] = {}
    for _ in range(rounds):
        for so in builds:
            got = json.loads(subprocess.run([sys.executable, __file__, "replay", path, "--core", so, "--repeat",
                                             str(repeat)], check=True, capture_output=True, text=True).stdout)
            if so not in best:
                best[so] = got
            else:
                for key in ("build", "register", "query_start", "query_final"):
                    best[so][key] = np.minimum(best[so][key], got[key]).tolist()
                assert best[so]["pose"] == got["pose"]
    same = all(best[b]["pose"] == best[builds[0]]["pose"] for b in builds)
    print(f"identical poses, iterations, pairs kept across builds: {same}")
    kinds = sorted({(c["log"], c["kind"]) for c in cases})
    header = "| log | ICP | n | " + " | ".join(f"{k} ({i})" for i in range(len(builds)) for k in
                                               ("reg µs", "query ns", "build µs")) + " |"
    print(header)
    for log, kind in kinds:
        sel = [i for i, c in enumerate(cases) if c["log"] == log and c["kind"] == kind]
        row = [log, kind, str(len(sel))]
        for so in builds:
            b = best[so]
            n = sum(b["n"][i] for i in sel)
            reg = np.mean([b["register"][i] for i in sel])
            q = 1e3 * sum(b["query_final"][i] for i in sel) / n
            q0 = 1e3 * sum(b["query_start"][i] for i in sel) / n
            builds_us = [b["build"][i] for i in sel if b["new_map"][i]]
            row += [f"{reg:.1f}", f"{q:.1f} (start {q0:.1f})", f"{np.mean(builds_us):.0f} x{len(builds_us)}"]
        print("| " + " | ".join(row) + " |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("capture")
    c.add_argument("logs", nargs="+")
    c.add_argument("-o", "--out", required=True)
    r = sub.add_parser("replay")
    r.add_argument("cases")
    r.add_argument("--core", required=True)
    r.add_argument("--repeat", type=int, default=3)
    m = sub.add_parser("compare")
    m.add_argument("cases")
    m.add_argument("--core", action="append", required=True)
    m.add_argument("--rounds", type=int, default=3)
    m.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    if a.cmd == "capture":
        Path(a.out).write_bytes(pickle.dumps(capture(a.logs)))
    elif a.cmd == "replay":
        print(json.dumps(replay(pickle.loads(Path(a.cases).read_bytes()), a.core, a.repeat)))
    else:
        compare(a.cases, a.core, a.rounds, a.repeat)


if __name__ == "__main__":
    main()
