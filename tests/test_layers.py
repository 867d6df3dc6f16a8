"""The layers hold by construction: one-way imports, no cycle, estimation walled off from files and ground truth.

The imports of every module are read from its source (not by importing it), at module level and
inside functions alike (``TYPE_CHECKING`` ones too), and followed transitively inside the package.

- The layers, lowest first (``LAYERS``): a module imports only from its own layer or a lower
  one, and the front end and the back end, side by side, never import each other.
- No import cycle among the package's modules.
- Estimation (the front end, the back end, the kernels and types they share) reaches no file
  format (``fmcwlog.io``), no evaluation (where the only ground-truth readers are) and no
  simulator (which knows the true wheel radii and the world); no module outside evaluation and
  the simulator names a ground-truth topic or record.
- The fleet imports the pipeline, never the library façade ``fmcwlog.api``.
- Importing the front end loads no MCAP reader, no plotting and no gtsam (a fresh interpreter).
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "fmcwlog"
GROUND_TRUTH_NAMES = {"GT_ODOM_TOPIC", "GT_LABELS_TOPIC", "GT_TF_TOPIC", "GT_BASE_FRAME", "WORLD_KEY", "SIM_KEY"}  # the prefix may be named: to skip them

# lowest first; a module may import its own layer and those before it
LAYERS: list[tuple[str, ...]] = [
    ("fmcwlog", "fmcwlog.errors", "fmcwlog.config", "fmcwlog.geometry", "fmcwlog.allocator"),
    ("fmcwlog.types",),
    ("fmcwlog.kernels",),
    ("fmcwlog.frontend", "fmcwlog.backend"),  # side by side: neither imports the other
    ("fmcwlog.io",),
    ("fmcwlog.pipeline",),
    ("fmcwlog.fleet",),
    ("fmcwlog.evaluation",),
    ("fmcwlog.sim",),
    ("fmcwlog.api",),
    ("fmcwlog.cli", "fmcwlog.__main__"),
]
ESTIMATION = ("fmcwlog.frontend", "fmcwlog.backend", "fmcwlog.kernels", "fmcwlog.types")
OFF_LIMITS_TO_ESTIMATION = ("fmcwlog.io", "fmcwlog.evaluation", "fmcwlog.sim", "fmcwlog.pipeline", "fmcwlog.fleet",
                            "fmcwlog.api", "fmcwlog.cli")


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def _imports(name: str) -> set[str]:
    """Package modules ``name`` imports (absolute or relative, anywhere in the file)."""
    path = MODULES[name]
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parent + ([base] if base else []))
            targets = [base] + [f"{base}.{a.name}" for a in node.names]
        else:
            continue
        found |= {t for t in targets if t in MODULES and t != name}
    return found


def _parents(name: str) -> list[str]:  # importing a.b.c runs a/__init__ and a/b/__init__
    parts = name.split(".")
    return [".".join(parts[:i]) for i in range(1, len(parts))]


def _reachable(start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo += _imports(m) | {p for p in _parents(m) if p in MODULES}
    return seen


def _layer(name: str) -> int:
    """The index in LAYERS of the longest prefix naming ``name``'s layer."""
    best, rank = -1, None
    for i, layer in enumerate(LAYERS):
        for prefix in layer:
            if (name == prefix or name.startswith(prefix + ".")) and len(prefix) > best:
                best, rank = len(prefix), i
    assert rank is not None, f"{name} is in no layer: add it to LAYERS"
    return rank


def _side(name: str) -> str:
    return name.split(".")[1] if name.count(".") >= 1 else ""


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan's algorithm, iteratively)."""
    graph = {m: sorted(_imports(m)) for m in MODULES}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(graph[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(graph[w])))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def test_the_walker_sees_real_imports():
    assert "fmcwlog.evaluation.ground_truth" in _reachable("fmcwlog.evaluation.evaluate")
    assert "fmcwlog.frontend.gmmsc" in _reachable("fmcwlog.frontend.methods")
    assert "fmcwlog.sim.recorder" in _reachable("fmcwlog.api")
    assert "fmcwlog.pipeline.process" in _imports("fmcwlog.fleet.worker")  # an import inside a function


def test_the_cycle_finder_finds_a_cycle(monkeypatch):
    """A planted two-module cycle is found (so an empty answer means something)."""
    real = _imports
    planted = {"fmcwlog.types": {"fmcwlog.kernels.voxel"}, "fmcwlog.kernels.voxel": {"fmcwlog.types"}}
    monkeypatch.setattr(sys.modules[__name__], "_imports", lambda m: real(m) | planted.get(m, set()))
    assert ["fmcwlog.kernels.voxel", "fmcwlog.types"] in _cycles()


def test_no_import_cycle():
    assert _cycles() == []


@pytest.mark.parametrize("module", sorted(MODULES))
def test_a_module_imports_only_its_own_layer_and_those_below(module):
    mine = _layer(module)
    above = sorted(m for m in _imports(module) if _layer(m) > mine)
    assert not above, f"{module} (layer {mine}) imports {above} from a higher layer"
    if _layer(module) == 3:  # the front end and the back end stand side by side
        across = sorted(m for m in _imports(module) if _layer(m) == 3 and _side(m) != _side(module))
        assert not across, f"{module} imports {across} across the front end / back end line"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if m.startswith(ESTIMATION)))
def test_estimation_reaches_no_file_format_ground_truth_or_simulator(module):
    leaks = sorted(m for m in _reachable(module) if m.startswith(OFF_LIMITS_TO_ESTIMATION))
    assert not leaks, f"{module} reaches {leaks}"


def test_the_fleet_never_imports_the_facade():
    for name in (m for m in MODULES if m.startswith("fmcwlog.fleet")):
        assert "fmcwlog.api" not in _reachable(name), name


def test_only_evaluation_and_the_simulator_name_ground_truth():
    allowed = ("fmcwlog.evaluation", "fmcwlog.sim", "fmcwlog.io.topics")
    for name, path in MODULES.items():
        if name.startswith(allowed):
            continue
        used = {n.id for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.Name)}
        used |= {a.name for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.ImportFrom) for a in n.names}
        assert not used & GROUND_TRUTH_NAMES, f"{name} names {sorted(used & GROUND_TRUTH_NAMES)}"


def test_the_method_names_agree_with_the_method_classes():
    from fmcwlog import types
    from fmcwlog.frontend.methods import METHODS

    assert tuple(METHODS) == types.METHOD_NAMES
    assert tuple(m for m, cls in METHODS.items() if cls.segments) == types.SEGMENTING_METHODS


def _loaded_after(code: str, prefixes: tuple[str, ...]) -> list[str]:
    """The modules starting with ``prefixes`` that a fresh interpreter holds after running ``code``."""
    probe = f"{code}\nimport sys\nprint(sorted(m for m in sys.modules if m.startswith({prefixes!r})))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=PACKAGE.parent, check=True)
    return eval(out.stdout.strip().splitlines()[-1])  # a printed list of str


def test_importing_the_front_end_loads_no_file_format_plots_or_gtsam():
    stages = " ".join(f"import {m};" for m in sorted(MODULES) if m.startswith("fmcwlog.frontend"))
    assert _loaded_after(stages, ("mcap", "matplotlib", "gtsam", "pyarrow", "fmcwlog.io")) == []
    # the probe sees what it looks for: the back end's first solve loads gtsam
    solve = ("import numpy as np\nfrom fmcwlog.backend.graph import PoseGraph\n"
             "g = PoseGraph()\ng.add_node(np.zeros(3))\ng.optimize()")
    assert "gtsam" in _loaded_after(solve, ("gtsam",))


def test_evaluation_does_not_import_the_estimation_stack():
    """report needs the methods' names, not scikit-learn and the stages (1.7 s of imports)."""
    assert _loaded_after("import fmcwlog.evaluation.pages", ("sklearn", "fmcwlog.frontend")) == []


ESTIMATION_STACK = ("gtsam", "scipy.optimize", "scipy.ndimage", "scipy.spatial", "sklearn", "pyarrow",
                    "fmcwlog.frontend.params", "fmcwlog.backend.pipeline", "fmcwlog.evaluation.evaluate")


def test_record_does_not_import_the_estimation_stack(tmp_path):
    """``fmcwlog record`` (and ``--help``) import the simulator and the log writer only: the
    estimation stack and the evaluation are about a second of imports a recording never uses."""
    code = ("import sys\n"
            "from fmcwlog.cli import cli\n"
            "cli.main(sys.argv[1:], standalone_mode=False)\n"
            f"print(sorted(m for m in sys.modules if m.startswith({ESTIMATION_STACK!r})))")
    log = tmp_path / "short.mcap"
    for args in (["--help"], ["-q", "record", "--scenario", "crowd", "--duration", "0.3", "-o", str(log)]):
        out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                             cwd=PACKAGE.parent, check=True)
        assert out.stdout.strip().splitlines()[-1] == "[]", (args, out.stdout[-500:])
    assert log.stat().st_size > 0


OTHER_COMMANDS = ("fmcwlog.cli.record", "fmcwlog.cli.report", "fmcwlog.cli.compare", "fmcwlog.cli.run", "fmcwlog.cli.import_carmen",
                  "fmcwlog.cli.calibrate", "fmcwlog.sim", "fmcwlog.evaluation", "fmcwlog.fleet.imports")


@pytest.mark.parametrize("args", [["--help"], ["process", "--help"]])
def test_help_loads_no_numpy_and_no_other_command(args):
    """``fmcwlog --help`` and ``fmcwlog process --help`` answer from click and the command's own module:
    no numpy, no file format, no other command's module (they cost 0.2 s of a 0.25 s answer)."""
    code = ("import sys\n"
            "from fmcwlog.cli import cli\n"
            "cli.main(sys.argv[1:], standalone_mode=False)\n"
            f"print(sorted(m for m in sys.modules if m.startswith({('numpy', 'mcap', *OTHER_COMMANDS)!r})))")
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=PACKAGE.parent,
                         check=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout[-500:]


def test_process_loads_no_other_command_plots_or_evaluation(tmp_path):
    """``fmcwlog process`` loads the estimation stack and its outputs' writers, and nothing of the
    other commands: no simulator, no evaluation or plotting, no CARMEN import, no scikit-learn."""
    log, out = tmp_path / "short.mcap", tmp_path / "out"
    code = ("import sys\n"
            "from fmcwlog.cli import cli\n"
            "cli.main(sys.argv[1:], standalone_mode=False)\n"
            f"print(sorted(m for m in sys.modules if m.startswith({(*OTHER_COMMANDS, 'matplotlib', 'sklearn')!r})))")
    subprocess.run([sys.executable, "-c", code, "-q", "record", "--duration", "0.5", "-o", str(log)],
                   cwd=PACKAGE.parent, check=True, capture_output=True)
    ran = subprocess.run([sys.executable, "-c", code, "-q", "process", str(log), "-o", str(out)],
                         capture_output=True, text=True, cwd=PACKAGE.parent, check=True)
    assert ran.stdout.strip().splitlines()[-1] == "[]", ran.stdout[-500:]
    assert (out / "trajectories.parquet").stat().st_size > 0


SCIPY = ("scipy.spatial", "scipy.optimize", "scipy.ndimage", "scipy.linalg", "scipy.sparse", "scipy.special")


@pytest.fixture(scope="module")
def short_log(tmp_path_factory) -> Path:
    """A 1 s recording: keyframes, maps and a back end's nodes, no loop closure."""
    log = tmp_path_factory.mktemp("short") / "one.mcap"
    subprocess.run([sys.executable, "-m", "fmcwlog", "-q", "record", "--duration", "1", "-o", str(log)],
                   cwd=PACKAGE.parent, check=True, capture_output=True)
    return log


def _process_loads(log: Path, out: Path, kernels: str, prefixes: tuple[str, ...]) -> list[str]:
    """The modules starting with ``prefixes`` that ``fmcwlog -q process --jobs 1 LOG`` (both methods in
    this one process) holds at its end with ``FMCWLOG_KERNELS=kernels``; its parquet is checked written."""
    code = ("import sys\n"
            "from fmcwlog.cli import cli\n"
            "cli.main(sys.argv[1:], standalone_mode=False)\n"
            f"print(sorted(m for m in sys.modules if m.startswith({prefixes!r})))")
    env = {**os.environ, "FMCWLOG_KERNELS": kernels}
    ran = subprocess.run([sys.executable, "-c", code, "-q", "process", "--jobs", "1", str(log), "-o", str(out)],
                         capture_output=True, text=True, cwd=PACKAGE.parent, check=True, env=env)
    assert (out / "trajectories.parquet").stat().st_size > 0
    return eval(ran.stdout.strip().splitlines()[-1])  # a printed list of str


def _core_built() -> bool:
    from fmcwlog.kernels import compiled

    return compiled._load()[0] is not None


@pytest.mark.skipif(not _core_built() and os.environ.get("FMCWLOG_KERNELS") != "compiled",
                    reason="the compiled core is not built")
def test_process_with_compiled_kernels_loads_no_scipy_and_no_unused_gtsam(short_log, tmp_path):
    """The compiled kernels need no KD-tree, no LAPACK wrapper and no special function: a run with
    them loads no scipy (0.25 s of imports: spatial pulls sparse, linalg and special), and a back
    end that never solves (no closure in 1 s) never loads gtsam; matplotlib is never loaded."""
    loaded = _process_loads(short_log, tmp_path / "out", "compiled", (*SCIPY, "gtsam", "matplotlib", "fmcwlog._core"))
    assert loaded == ["fmcwlog._core"], loaded  # the probe sees what it looks for: the core is loaded


def test_process_with_numpy_kernels_still_loads_its_kd_tree(short_log, tmp_path):
    """The numpy reference path imports scipy.spatial where it builds its first tree, and runs."""
    loaded = _process_loads(short_log, tmp_path / "out", "numpy", ("scipy.spatial", "gtsam", "matplotlib"))
    assert "scipy.spatial" in loaded and "gtsam" not in loaded and "matplotlib" not in loaded, loaded
