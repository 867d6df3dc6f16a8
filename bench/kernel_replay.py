"""Benchmark: every call a log's processing makes into the compiled core, recorded once and replayed
on a given build of ``fmcwlog._core``, kernel by kernel: time per call and the answers.

``capture`` processes the log (one method, the compiled kernels of this checkout) and stores each
core call's arguments: arrays copied before the call, a ``TargetGrid`` as its points and radius, a
parameter object as its fields. ``replay`` loads a build (the ``.so`` given, imported directly, no
source check), rebuilds the grids once, then calls each kernel on its recorded arguments ``--repeat``
times (CPU time, ``time.process_time``; per kernel the best repeat's sum over its calls) and writes
each call's answer (the returned values and the output arrays it filled). ``compare`` says whether two
replays gave the same answers, bit for bit, and puts their times side by side.

    python bench/kernel_replay.py capture /tmp/s27/corridor.mcap improved /tmp/calls.pkl [KERNEL,KERNEL,...]
    python bench/kernel_replay.py replay /tmp/calls.pkl main_core.so /tmp/main.pkl
    python bench/kernel_replay.py replay /tmp/calls.pkl fmcwlog/_core*.so /tmp/new.pkl
    python bench/kernel_replay.py compare /tmp/main.pkl /tmp/new.pkl

Alternate the two replays (several processes each) on a shared machine and take the best.
"""

from __future__ import annotations

import importlib.util
import pickle
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


class GridRef:
    """A recorded ``TargetGrid``: its number in the capture."""

    def __init__(self, key: int):
        self.key = key


class CallbackRef:
    """A recorded Python callback: what it returned, call by call (replayed in that order)."""

    def __init__(self):
        self.results: list[object] = []


class ParamsRef:
    """A recorded parameter object: its type's name and fields."""

    def __init__(self, kind: str, fields: dict):
        self.kind, self.fields = kind, fields


def capture(log: str, method: str, out: str, kernels: set[str]) -> None:
    """Process ``log`` with ``method`` on this checkout's compiled core, recording each call into
    ``kernels`` (all where empty) and every grid built."""
    import os

    os.environ["FMCWLOG_KERNELS"] = "compiled"
    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.kernels import compiled

    mod = compiled.core()
    grids: dict[int, tuple[np.ndarray, float]] = {}
    grid_of: dict[int, int] = {}
    keep_alive: list[object] = []
    calls: list[tuple[str, tuple, dict]] = []
    grid_type = mod.TargetGrid

    def live(a: object, rec: object) -> object:
        """The argument to pass: a callback through a recorder, else ``a`` itself."""
        if isinstance(rec, CallbackRef):
            def recording(*args, _fn=a, _rec=rec):
                res = _fn(*args)
                _rec.results.append(res.copy() if isinstance(res, np.ndarray) else res)
                return res
            return recording
        if isinstance(a, (tuple, list)) and isinstance(rec, (tuple, list)):
            return type(a)(live(v, r) for v, r in zip(a, rec))
        return a

    def conv(a: object) -> object:
        if callable(a) and not isinstance(a, (type, grid_type)) and not hasattr(a, "__array__"):
            return CallbackRef()
        if isinstance(a, np.ndarray):
            return a.copy()
        if isinstance(a, grid_type):
            return GridRef(grid_of[id(a)])
        if isinstance(a, (tuple, list)):
            return type(a)(conv(v) for v in a)
        if type(a).__module__ == mod.__name__ or type(a).__module__.startswith("fmcwlog._core"):
            fields = {k: getattr(a, k) for k in dir(a) if not k.startswith("_")}
            return ParamsRef(type(a).__name__, fields)
        return a

    def make_grid(target, radius):
        g = grid_type(target, radius)
        grid_of[id(g)] = len(grids)
        grids[len(grids)] = (np.array(target, dtype=float, copy=True), float(radius))
        keep_alive.append(g)
        calls.append(("TargetGrid", (GridRef(grid_of[id(g)]),), {}))
        return g

    for name in dir(mod):
        fn = getattr(mod, name)
        if name.startswith("_") or not callable(fn) or isinstance(fn, type):
            continue

        def wrapped(*a, _fn=fn, _n=name, **k):
            if kernels and _n not in kernels:
                return _fn(*a, **k)
            ra, rk = conv(a), {key: conv(v) for key, v in k.items()}
            calls.append((_n, ra, rk))
            return _fn(*live(a, ra), **{key: live(v, rk[key]) for key, v in k.items()})

        setattr(mod, name, wrapped)
    mod.TargetGrid = make_grid
    from fmcwlog.frontend.methods import FrontEnd  # noqa: F401  (loaded before the run)

    with tempfile.TemporaryDirectory() as tmp:
        process(log, tmp + "/o", ProcessOptions(methods=(method,)), jobs=1)
    with open(out, "wb") as f:
        pickle.dump({"grids": grids, "calls": calls}, f, protocol=pickle.HIGHEST_PROTOCOL)
    counts: dict[str, int] = {}
    for name, _, _ in calls:
        counts[name] = counts.get(name, 0) + 1
    print(f"{len(calls)} calls: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))


def load_build(path: str):
    spec = importlib.util.spec_from_file_location("fmcwlog._core", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def answer(a: object) -> object:
    """A call's answer as comparable plain values."""
    if isinstance(a, np.ndarray):
        return ("nd", a.dtype.str, a.shape, a.tobytes())
    if isinstance(a, (tuple, list)):
        return tuple(answer(v) for v in a)
    if isinstance(a, float):
        return ("f", float(a).hex())
    if a is None or isinstance(a, (bool, int, str)):
        return a
    return ("obj", type(a).__name__)  # a grid, a parameter object, a callback: the same inputs


def replay(calls_path: str, build: str, out: str, repeat: int) -> None:
    mod = load_build(build)
    with open(calls_path, "rb") as f:
        rec = pickle.load(f)
    grids = {k: mod.TargetGrid(np.ascontiguousarray(p), r) for k, (p, r) in rec["grids"].items()}
    params_cache: dict[int, object] = {}

    def back(a: object) -> object:
        if isinstance(a, np.ndarray):
            return a.copy()
        if isinstance(a, GridRef):
            return grids[a.key]
        if isinstance(a, CallbackRef):
            it = iter(a.results)
            return lambda *args: next(it)
        if isinstance(a, ParamsRef):
            obj = params_cache.get(id(a))
            if obj is None:
                obj = getattr(mod, a.kind)()
                for k, v in a.fields.items():
                    if not callable(v):
                        setattr(obj, k, v)
                params_cache[id(a)] = obj
            return obj
        if isinstance(a, (tuple, list)):
            return type(a)(back(v) for v in a)
        return a

    by_kernel: dict[str, list[int]] = {}
    for i, (name, _, _) in enumerate(rec["calls"]):
        by_kernel.setdefault(name, []).append(i)
    times: dict[str, float] = {}
    answers: dict[int, object] = {}
    for name, idx in sorted(by_kernel.items()):
        best = float("inf")
        for r in range(repeat):
            prepared = [(i, back(rec["calls"][i][1]), back(rec["calls"][i][2])) for i in idx]
            if name == "TargetGrid":
                prepared = [(i, (np.ascontiguousarray(rec["grids"][a[0].key][0]), rec["grids"][a[0].key][1]), k)
                            for i, a, k in ((i, rec["calls"][i][1], {}) for i in idx)]
            fn = getattr(mod, name)
            total = 0.0
            for i, a, k in prepared:
                t0 = time.process_time()
                res = fn(*a, **k)
                total += time.process_time() - t0
                if r == 0 and name != "TargetGrid":
                    answers[i] = (answer(res), answer(list(a)), answer(list(k.values())))
            best = min(best, total)
        times[name] = best / len(idx)
    with open(out, "wb") as f:
        pickle.dump({"times": times, "counts": {k: len(v) for k, v in by_kernel.items()}, "answers": answers}, f)
    for name in sorted(times, key=lambda n: -times[n] * len(by_kernel[n])):
        print(f"  {name:28s} {len(by_kernel[name]):6d} calls {times[name] * 1e6:8.1f} us/call")


def compare(*paths: str) -> None:
    runs = []
    for p in paths:
        with open(p, "rb") as f:
            runs.append(pickle.load(f))
    first = runs[0]
    for p, run in zip(paths[1:], runs[1:]):
        diff = [i for i in first["answers"] if first["answers"][i] != run["answers"].get(i)]
        print(f"{p}: {len(diff)} of {len(first['answers'])} answers differ from {paths[0]}"
              + (f" (first: call {diff[0]})" if diff else ""))
    print(f"{'kernel':28s} " + " ".join(f"{Path(p).stem:>12s}" for p in paths) + "   (us/call)")
    for name in sorted(first["times"], key=lambda n: -first["times"][n] * first["counts"][n]):
        print(f"{name:28s} " + " ".join(f"{r['times'][name] * 1e6:12.1f}" for r in runs))


if __name__ == "__main__":
    cmd = sys.argv[1]
    if cmd == "capture":
        capture(sys.argv[2], sys.argv[3], sys.argv[4], set(sys.argv[5].split(",")) if len(sys.argv) > 5 else set())
    elif cmd == "replay":
        replay(sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]) if len(sys.argv) > 5 else 5)
    elif cmd == "compare":
        compare(*sys.argv[2:])
