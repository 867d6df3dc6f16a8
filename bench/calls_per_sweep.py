"""Benchmark: how many Python and C function calls each method makes a sweep (and, with the compiled
kernels, calls into ``fmcwlog._core``), and what a numpy call costs.

The front end is stages of numpy calls on sweep-sized arrays, so its floor is the number of calls
times what one costs, whatever the arithmetic. The counts come from ``cProfile`` enabled only
inside :meth:`fmcwlog.frontend.methods.FrontEnd.step` (counts, not times: the same on any machine
for the same log and code); the per-call costs from ``timeit`` (the best of 300 windows of 100 calls) on 1,000-point arrays,
a sweep's size. Compare the product with KISS-ICP's whole sweep (``bench/speed.py``).

    python bench/calls_per_sweep.py                     # 20 s crowd and 120 s corridor, both methods
    python bench/calls_per_sweep.py --log my.mcap       # an existing log instead
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import subprocess
import sys
import tempfile
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # this checkout's fmcwlog, in the child too
ONE_THREAD = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}


def count_calls(log: str, method: str) -> dict:
    """Calls a sweep inside one method's step, processing ``log`` with that method alone, in this process."""
    from fmcwlog.api import ProcessOptions, process
    from fmcwlog.frontend.methods import FrontEnd

    prof, sweeps, step = cProfile.Profile(), [0], FrontEnd.step
    core_calls = _count_core_calls()

    def profiled_step(self, sweep, prior):
        sweeps[0] += 1
        prof.enable()
        try:
            return step(self, sweep, prior)
        finally:
            prof.disable()

    FrontEnd.step = profiled_step  # type: ignore[method-assign]
    with tempfile.TemporaryDirectory() as tmp:
        process(log, str(Path(tmp) / "out"), ProcessOptions(methods=(method,)), jobs=1)
    python_calls = c_calls = 0
    for (filename, _, name), (_, ncalls, _, _, _) in pstats.Stats(prof).stats.items():  # type: ignore[attr-defined]
        if filename == "~":  # cProfile's mark of a built-in (C) function
            c_calls += ncalls
        elif name != _COUNTING_WRAPPER:  # the counter's own frames (core calls are counted apart)
            python_calls += ncalls
    in_step = sum(n for n in core_calls.values())
    return {"method": method, "sweeps": sweeps[0], "python_calls_per_sweep": python_calls / sweeps[0],
            "c_calls_per_sweep": c_calls / sweeps[0], "core_calls_per_sweep": in_step / sweeps[0],
            "kernels": "compiled" if core_calls is not _NO_CORE else "numpy"}


_COUNTING_WRAPPER = "counted_core_call"
_NO_CORE: dict[str, int] = {}


def _count_core_calls() -> dict[str, int]:
    """Calls into the compiled module (``fmcwlog._core``) inside the step, by function: cProfile
    does not see them (nanobind's functions are not built-in functions), so each is wrapped in a
    counter that counts only while the step's profiler runs (``_COUNTING_WRAPPER`` frames are left
    out of the Python count). ``_NO_CORE`` where the numpy kernels run."""
    from fmcwlog.kernels import compiled

    module = compiled.core()
    if module is None:
        return _NO_CORE
    counts: dict[str, int] = {}
    for name in dir(module):
        fn = getattr(module, name)
        if name.startswith("_") or not callable(fn) or isinstance(fn, type):
            continue

        def counted_core_call(*args, _fn=fn, _name=name, **kwargs):
            if sys.getprofile() is not None:  # inside the step
                counts[_name] = counts.get(_name, 0) + 1
            return _fn(*args, **kwargs)

        setattr(module, name, counted_core_call)
    return counts


def numpy_call_costs() -> dict[str, float]:
    """Microseconds a call, the best of 300 windows of 100 calls, on 1,000-point float64 arrays.

    Short windows, many of them: on a shared machine the best of 7 windows of 20,000 calls (50 ms
    each) was always stretched by the neighbours (np.add 2.4-3.0 us at load 6-7 on 2 cores), while
    the best short window finds the uncontended cost (0.78 us in the same minute)."""
    import numpy as np

    rng = np.random.default_rng(0)
    a, b = rng.random(1000), rng.random(1000)
    idx, mask = rng.integers(0, 1000, 1000), a > 0.5
    env = {"np": np, "a": a, "b": b, "idx": idx, "mask": mask}
    cases = {"np.add(a, b)": "np.add(a, b)", "np.take(a, idx)": "np.take(a, idx)",
             "a[mask]": "a[mask]", "a.sum()": "a.sum()"}
    return {name: min(timeit.repeat(stmt, globals=env, number=100, repeat=300)) / 100 * 1e6
            for name, stmt in cases.items()}


def _record(scenario: str, seconds: float, out: Path) -> None:
    subprocess.run([sys.executable, "-m", "fmcwlog", "record", "--scenario", scenario, "--duration",
                    str(seconds), "-o", str(out)], check=True, cwd=ROOT, capture_output=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", action="append", help="log(s) to count on instead of recording crowd 20 s and corridor 120 s")
    ap.add_argument("--child", nargs=2, metavar=("LOG", "METHOD"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(count_calls(*args.child)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        logs = args.log
        if not logs:
            logs = [str(Path(tmp) / "crowd20.mcap"), str(Path(tmp) / "corridor120.mcap")]
            _record("crowd", 20, Path(logs[0]))
            _record("corridor", 120, Path(logs[1]))
        print("| log | method | kernels | sweeps | Python calls a sweep | C calls a sweep | compiled-core calls a sweep |")
        print("|---|---|---|---|---|---|---|")
        for log in logs:
            for method in ("improved", "baseline"):
                res = subprocess.run([sys.executable, __file__, "--child", log, method], check=True, cwd=ROOT,
                                     capture_output=True, text=True, env={**os.environ, **ONE_THREAD})
                r = json.loads(res.stdout.strip().splitlines()[-1])
                print(f"| {Path(log).name} | {method} | {r['kernels']} | {r['sweeps']} | {r['python_calls_per_sweep']:.0f} | "
                      f"{r['c_calls_per_sweep']:.0f} | {r['core_calls_per_sweep']:.1f} |")
    print()
    for name, us in numpy_call_costs().items():
        print(f"{name:18s} {us:.2f} us a call (1,000 points)")


if __name__ == "__main__":
    main()
