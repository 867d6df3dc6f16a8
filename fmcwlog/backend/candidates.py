"""Loop-closure candidates: nodes near the query node in the current estimate and far back along
the path.

"Far back" is path length, not time: a robot that stands still must not close loops with
itself, and the front end's local map already holds the last ``window_distance`` metres. The
nearest candidates come first; the ones chosen are spread at least ``candidate_spacing`` m of
path apart, so that two closures of one query do not fall on the same place.
"""

from __future__ import annotations

import numpy as np

from .params import BackendParams


def closure_candidates(query: int, positions: np.ndarray, path_m: np.ndarray, p: BackendParams,
                       radius: float | None = None) -> list[int]:
    """Candidate nodes for ``query`` given every node's estimated position (N, 2) and path (N,),
    within ``radius`` m (default ``p.closure_radius``)."""
    radius = p.closure_radius if radius is None else radius
    older = np.flatnonzero(path_m[:query] <= path_m[query] - p.closure_min_path)
    if older.size == 0:
        return []
    dist = np.hypot(*(positions[older] - positions[query]).T)
    near = dist <= radius
    chosen: list[int] = []
    for j in older[near][np.argsort(dist[near], kind="stable")]:
        if all(abs(path_m[j] - path_m[c]) >= p.candidate_spacing for c in chosen):
            chosen.append(int(j))
            if len(chosen) == p.max_candidates:
                break
    return chosen
