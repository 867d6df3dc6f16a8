"""What a command costs from the shell: wall and CPU seconds of ``python -m fmcwlog ...``, best of N.

    python bench/command_costs.py [--repeat 3] [--source CHECKOUT ...] [--one-second LOG] [--kernels compiled|numpy]

Times ``fmcwlog --help``, ``fmcwlog process --help``, and ``fmcwlog -q process`` of a 1 s log (recorded
with ``fmcwlog record --duration 1`` unless given) and of ``sample_logs/corridor_30s.mcap``. CPU is the
user + system time of the command and of every process it waited for (the method process too:
``RUSAGE_CHILDREN``), so on a machine that other work shares it is the steadier number. Each
command's runs alternate with the others' (and several ``--source`` checkouts' with each other's),
and the best of ``--repeat`` is printed per command and checkout. ``--kernels`` sets ``FMCWLOG_KERNELS``
for every command (default: as the environment has it): the compiled kernels import no scipy, the
numpy ones import scipy.spatial at their first KD-tree, so the two cost differently from the shell.
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def timed(args: list[str], cwd: Path, env: dict[str, str] | None = None) -> tuple[float, float]:
    """Wall and CPU seconds (user + system, children included) of ``python -m fmcwlog ARGS``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "fmcwlog", *args], cwd=cwd, check=True, stdout=subprocess.DEVNULL, env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--source", type=Path, action="append", help="a checkout whose fmcwlog runs (repeatable; "
                                                                 "default: this one)")
    ap.add_argument("--one-second", type=Path, default=None, help="a 1 s log (else recorded here)")
    ap.add_argument("--kernels", choices=("compiled", "numpy"), default=None,
                    help="FMCWLOG_KERNELS for every command (default: the environment's)")
    a = ap.parse_args()
    env = None if a.kernels is None else {**os.environ, "FMCWLOG_KERNELS": a.kernels}
    sources = a.source or [REPO]
    with tempfile.TemporaryDirectory(prefix="fmcwlog-costs-") as tmp:
        out = Path(tmp)
        one = a.one_second
        if one is None:
            one = out / "one.mcap"
            subprocess.run([sys.executable, "-m", "fmcwlog", "-q", "record", "--duration", "1", "-o", str(one)],
                           cwd=sources[0], check=True)
        commands = {
            "--help": ["--help"],
            "process --help": ["process", "--help"],
            "process 1 s log": ["-q", "process", str(one.resolve()), "-o", str(out / "one"), "--force"],
            "process corridor_30s": ["-q", "process", str(REPO / "sample_logs" / "corridor_30s.mcap"),
                                     "-o", str(out / "corridor"), "--force"],
        }
        best: dict[tuple[Path, str], tuple[float, float]] = {}
        for _ in range(a.repeat):
            for name, args in commands.items():
                for source in sources:
                    wall, cpu = timed(args, source, env)
                    w, c = best.get((source, name), (wall, cpu))
                    best[source, name] = (min(w, wall), min(c, cpu))
    for source in sources:
        kernels = a.kernels or os.environ.get("FMCWLOG_KERNELS", "default")
        print(f"{'command':24s} {'wall s':>8s} {'cpu s':>8s}   (best of {a.repeat}, {source}, kernels {kernels})")
        for name in commands:
            wall, cpu = best[source, name]
            print(f"{name:24s} {wall:8.3f} {cpu:8.3f}")


if __name__ == "__main__":
    main()
