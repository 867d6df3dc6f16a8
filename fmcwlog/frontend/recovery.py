"""Recovery from a poor prior: when the ICP's fit is bad, search around the prior, then ICP again.

Not in the paper. ICP from a prior off by more than its basin (real odometry 5-10° off after a
turn) converges to a wrong local minimum, and the bad match adds drift that nothing later
removes. The search is run only when the fit says the match may be wrong — few of the map's
points near the sweep's after the ICP (:func:`inlier_fraction` below ``min_inlier_fraction``),
or an ICP that did not converge — because a correlative search costs 10-30 ms against the
ICP's 1-2 ms. It scores every pose within ``±linear_window`` / ``±angular_window_deg`` of the
prior on a likelihood grid of the local map (:mod:`.correlative`), and the ICP restarts from
the best; the restart is kept only if its fit is better.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..config import Checked, param
from ..geometry import transform_points
from ..kernels.compiled import CompiledNearest, covering_nearest
from ..kernels.correlative import CorrelativeParams
from ..kernels.nearest import NearestPairs

if TYPE_CHECKING:  # scipy.spatial (0.25 s of imports) only where a KD-tree is built
    from scipy.spatial import cKDTree


@dataclass(frozen=True)
class RecoveryParams(Checked):
    """enabled: run the search at all (False: the ICP from the prior is final).
    inlier_distance: a sweep point is an inlier when the map has a point this close after the
        ICP (m, > 0).
    min_inlier_fraction: below this fraction of inliers the search runs (0-1).
    correlative: the search's window and grids.
    """

    enabled: bool = True
    inlier_distance: float = param(0.1, "m", gt=0.0, le=10.0)
    min_inlier_fraction: float = param(0.6, "", ge=0.0, le=1.0)
    correlative: CorrelativeParams = field(default_factory=CorrelativeParams)


def inlier_fraction(source_xy: np.ndarray, pose: np.ndarray, tree: cKDTree, distance: float,
                    search: NearestPairs | CompiledNearest | None = None) -> float:
    """Fraction of ``source_xy`` (base_link) that lands within ``distance`` (m) of the map's
    points under ``pose``. ``search``: the registration's correspondence search over the same
    source and tree (:attr:`~.icp.ICPResult.search`), which answers exactly and asks the tree
    again only about the points that moved since (the ICP's last steps are sub-millimetre);
    without it (or for a ``distance`` beyond its reach), the compiled kernels' grid that ``tree``
    keeps (a :class:`~fmcwlog.kernels.compiled.MapIndex` the registration used), else one KD-tree
    query; where the registration counted them already at this ``pose`` array and ``distance``
    (:func:`~.robust_icp.register`'s ``inlier_distance``), that count. A point counts where its nearest map
    point is closer than ``distance``."""
    if len(source_xy) == 0:
        return 0.0
    usable = search is not None and search.source is source_xy and search.tree is tree and distance <= search.bound
    counted = search.counted if usable and type(search) is CompiledNearest else None
    if counted is not None and counted[0] is pose and counted[1] == distance:  # counted by the registration
        return float(counted[2] / len(source_xy))
    if not usable:
        search = covering_nearest(tree, source_xy, distance)
    if search is not None:
        d = search.nearest(pose)[2]
        return float(np.count_nonzero(d < distance) / len(d))
    d, _ = tree.query(transform_points(pose, source_xy), k=1, distance_upper_bound=distance)
    return float(np.isfinite(d).mean())
