"""Which kernels run: the compiled ones (``fmcwlog._core``, built from ``src/core/``) or the numpy
reference, and the compiled ones' Python face.

The switch is the environment variable ``FMCWLOG_KERNELS``, read once, at the first registration:

- unset or empty: the compiled kernels where the module imports, the numpy ones otherwise (no error);
- ``numpy``: the numpy reference;
- ``compiled``: the compiled kernels, and an :class:`~fmcwlog.errors.FmcwlogError` where they cannot load.

Both give the same pairs and iteration counts and poses within about 1e-9 (``tests/unit/frontend/
test_compiled_kernels.py``); a build gives the same bytes on every run, but the compiled kernels are not
promised to equal numpy bit for bit.

Where the package is imported from a checkout (``python -m pytest`` in it puts the checkout first
on ``sys.path``) the checkout holds no build: the module is then taken from the installed package
(``pip install .``), if it was built from the same ``src/core/`` (its digest is compiled in).
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
from importlib.machinery import EXTENSION_SUFFIXES
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..errors import FmcwlogError

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree

ENV = "FMCWLOG_KERNELS"
CHOICES = ("compiled", "numpy")
_PACKAGE = Path(__file__).resolve().parent.parent
_SOURCE = _PACKAGE.parent / "src" / "core"  # present in a checkout only

_core: ModuleType | None = None
_why_not = ""  # why the compiled module did not load
_chosen: str | None = None


def _from(path: Path) -> ModuleType:
    """The extension module at ``path`` as ``fmcwlog._core`` (loaded once: a second load of the
    same extension would register its types twice)."""
    loaded = sys.modules.get("fmcwlog._core")
    if loaded is not None:
        return loaded
    spec = importlib.util.spec_from_file_location("fmcwlog._core", path)
    if spec is None or spec.loader is None:
        raise ImportError(f"cannot load {path}")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    sys.modules["fmcwlog._core"] = module
    return module


def _installed_builds() -> list[Path]:
    """``fmcwlog/_core*`` of the other fmcwlog installs on ``sys.path`` (a checkout's installed build)."""
    found = []
    for entry in sys.path:
        folder = Path(entry or ".").resolve() / "fmcwlog"
        if folder == _PACKAGE or not folder.is_dir():
            continue
        found += [folder / f"_core{suffix}" for suffix in EXTENSION_SUFFIXES if (folder / f"_core{suffix}").is_file()]
    return found


def source_digest(folder: Path) -> str:
    """The digest CMakeLists.txt compiles in: SHA-256 of the lines "<name> <SHA-256 of the file>\\n",
    one per ``.cpp`` and ``.hpp`` file of ``folder``, sorted by name."""
    files = sorted((p for p in folder.iterdir() if p.suffix in (".cpp", ".hpp")), key=lambda p: p.name)
    lines = "".join(f"{p.name} {hashlib.sha256(p.read_bytes()).hexdigest()}\n" for p in files)
    return hashlib.sha256(lines.encode()).hexdigest()


def _load() -> tuple[ModuleType | None, str]:
    """The compiled module and "", or None and why not."""
    want = source_digest(_SOURCE) if _SOURCE.is_dir() else None
    candidates: list[ModuleType] = []
    try:
        from .. import _core as own  # type: ignore[attr-defined]

        candidates.append(own)
    except ImportError:
        for path in _installed_builds():
            try:
                candidates.append(_from(path))
            except ImportError:
                continue
    if not candidates:
        return None, "fmcwlog._core is not built (pip install . builds it)"
    for module in candidates:
        if want is None or module.SOURCE_SHA256 == want:
            return module, ""
    return None, f"fmcwlog._core was built from another {_SOURCE} (pip install . rebuilds it)"


def core() -> ModuleType | None:
    """The compiled module where ``FMCWLOG_KERNELS`` selects it (module docstring), else None."""
    global _core, _why_not, _chosen
    if _chosen is None:
        value = os.environ.get(ENV, "").strip().lower()
        if value not in ("", *CHOICES):
            raise FmcwlogError(f"{ENV}={value!r}: expected one of {', '.join(CHOICES)}")
        if value != "numpy":
            _core, _why_not = _load()
            if _core is None and value == "compiled":
                raise FmcwlogError(f"{ENV}=compiled: {_why_not}")
        _chosen = "compiled" if _core is not None and value != "numpy" else "numpy"
    return _core if _chosen == "compiled" else None


class CompiledNearest:
    """The nearest target point of every source point under a pose, within ``bound`` (m), from the
    compiled module's grid over the target: what :meth:`~fmcwlog.kernels.nearest.NearestPairs.nearest`
    answers, for :func:`~fmcwlog.frontend.recovery.inlier_fraction`. ``source`` (N, 2) and ``tree``
    are those of the registration, ``grid`` the module's ``TargetGrid`` of the tree's points."""

    def __init__(self, module: ModuleType, source_xy: np.ndarray, tree: cKDTree, grid: object, bound: float):
        self._module, self.source, self.tree, self.grid, self.bound = module, source_xy, tree, grid, bound
        # (pose, distance, count): the source points nearer than distance (m) to the target under that
        # pose array, where the registration counted them on the way (robust_icp's inlier_distance)
        self.counted: tuple[np.ndarray, float, int] | None = None

    def nearest(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Under ``pose``: the moved source (N, 2), each point's nearest target index (N,; -1 where none
        is within ``bound``) and its distance (N,; inf where none)."""
        n = len(self.source)
        moved, index, dist = np.empty((n, 2)), np.empty(n, np.int64), np.empty(n)
        x, y, th = np.asarray(pose, dtype=float).tolist()
        self._module.nearest(self.grid, self.source, x, y, th, moved, index, dist)
        return moved, index, dist


class MapIndex:
    """A target point set (M, 2) with its search structures, each built on first use and then kept:
    the ``cKDTree`` (what the numpy kernels query; built with ``tree_options``) and the compiled
    module's ``TargetGrid`` per radius (m); :attr:`cache` keeps what else is made of the points (the
    line normals, :func:`fmcwlog.kernels.normals.target_normals`). It stands where a ``cKDTree`` is expected: ``query`` and
    the tree's attributes (``n``, ``data``, ...) are the tree's. The points must not change
    afterwards: a changed set is a new index."""

    def __init__(self, points: np.ndarray, **tree_options: object):
        self.points = points
        self._options = tree_options
        self._tree: cKDTree | None = None
        self._grids: dict[float, object] = {}
        # other structures of these points, each made once by the module that needs it (by its key)
        self.cache: dict[object, object] = {}

    @property
    def tree(self) -> cKDTree:
        """The points' ``cKDTree``, built at the first use."""
        if self._tree is None:
            from scipy.spatial import cKDTree  # here, not at import: scipy.spatial is 0.25 s of imports
            self._tree = cKDTree(self.points, **self._options)
        return self._tree

    def query(self, *args: object, **kwargs: object) -> tuple[np.ndarray, np.ndarray]:
        """``cKDTree.query`` of :attr:`tree`."""
        return self.tree.query(*args, **kwargs)

    def __getattr__(self, name: str) -> object:
        """The tree's other attributes (only called for names the index itself lacks)."""
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.tree, name)

    def grid(self, module: ModuleType, radius: float) -> object:
        """The module's ``TargetGrid`` over the points for ``radius`` (m), built at the first use."""
        found = self._grids.get(radius)
        if found is None:
            found = self._grids[radius] = module.TargetGrid(np.ascontiguousarray(self.points, dtype=float), radius)
        return found


def target_grid(module: ModuleType, tree: object, points: np.ndarray, radius: float) -> object:
    """The module's ``TargetGrid`` over ``points`` (M, 2) for ``radius`` (m): the one ``tree`` keeps
    where it is the :class:`MapIndex` of these points, else a new one."""
    if isinstance(tree, MapIndex) and tree.points is points:
        return tree.grid(module, radius)
    return module.TargetGrid(np.ascontiguousarray(points, dtype=float), radius)


def covering_nearest(tree: object, source_xy: np.ndarray, distance: float) -> CompiledNearest | None:
    """A :class:`CompiledNearest` of ``source_xy`` on a grid that ``tree`` already keeps, one whose
    radius reaches ``distance`` (m); None where the compiled kernels do not run, ``tree`` is no
    :class:`MapIndex` or it keeps no such grid (the caller then asks the tree)."""
    module = core()
    if module is None or not isinstance(tree, MapIndex):
        return None
    for radius, grid in tree._grids.items():
        if radius >= distance:
            return CompiledNearest(module, np.ascontiguousarray(source_xy, dtype=float), tree, grid, radius)
    return None
