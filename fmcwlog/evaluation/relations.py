"""The relations metric of Kümmerle et al. 2009 ("On measuring the accuracy of SLAM algorithms").

A relations file holds, one per line, ``t1 t2 x y z roll pitch yaw``: the true motion ``δ*`` of the
robot from its pose at ``t1`` to its pose at ``t2``, in the frame of the first (m, rad). For an
estimated trajectory ``P``, each relation whose stamps both fall on its poses (within 1 ms) gives
``δ = inv(P(t1)) ⊕ P(t2)`` (poses interpolated at the stamps) and the error ``δ*⁻¹ ⊕ δ``: its
translation (m) and the absolute value of its rotation (deg). Reported as mean ± std over the
relations, as in the paper's tables; beside it, the same over the relations spanning less than
``SHORT_SPAN_S`` and over those spanning more (a robot that stands still scores a flattering mean
on short relations, and the long ones carry a front end's drift), and the trajectory's path length.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import RelationsError
from ..geometry import between, interpolate_poses

SHORT_SPAN_S = 20.0  # s: relations spanning less are "short"


@dataclass
class RelationsResult:
    """Over all the relations that fall on the trajectory's stamps (``n``), and the short
    (``t2 - t1 < SHORT_SPAN_S``) and long ones apart; ``path_length_m``: the trajectory's."""

    n: int
    trans_mean_m: float | None
    trans_std_m: float | None
    rot_mean_deg: float | None
    rot_std_deg: float | None
    short_n: int = 0
    short_trans_mean_m: float | None = None
    short_rot_mean_deg: float | None = None
    long_n: int = 0
    long_trans_mean_m: float | None = None
    long_rot_mean_deg: float | None = None
    path_length_m: float | None = None

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def read_relations(path: str | Path) -> np.ndarray:
    """(K, 5) array of ``t1, t2, x, y, yaw``."""
    path = Path(path)
    rows = []
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise RelationsError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise RelationsError(f"{path}: not a text file (it is not UTF-8)") from None
    for i, line in enumerate(lines, 1):
        tok = line.split()
        if not tok or tok[0].startswith("#"):
            continue
        if len(tok) != 8:
            raise RelationsError(f"{path}: line {i} has {len(tok)} fields, a relation has 8 (t1 t2 x y z roll pitch yaw)")
        try:
            v = [float(x) for x in tok]
        except ValueError:
            raise RelationsError(f"{path}: line {i} holds a value that is not a number") from None
        if not all(np.isfinite(v)):
            raise RelationsError(f"{path}: line {i} holds a value that is not finite (NaN or infinity)")
        rows.append([v[0], v[1], v[2], v[3], v[7]])
    if not rows:
        raise RelationsError(f"{path}: no relations")
    return np.asarray(rows)


def relations_error(t: np.ndarray, poses: np.ndarray, relations: np.ndarray, max_gap: float = 1e-3) -> RelationsResult:
    """Errors of the relations whose two stamps each lie within ``max_gap`` (s) of a pose of the
    trajectory: interpolating across a longer gap would score the interpolation, not the method."""
    def near(x: np.ndarray) -> np.ndarray:
        i = np.clip(np.searchsorted(t, x), 1, len(t) - 1)
        return np.minimum(np.abs(t[i] - x), np.abs(t[i - 1] - x)) <= max_gap

    rel = relations[near(relations[:, 0]) & near(relations[:, 1])]
    path = float(np.hypot(*np.diff(poses[:, :2], axis=0).T).sum()) if len(poses) > 1 else 0.0
    if len(rel) == 0:
        return RelationsResult(0, None, None, None, None, path_length_m=path)
    p1 = interpolate_poses(rel[:, 0], t, poses)
    p2 = interpolate_poses(rel[:, 1], t, poses)
    err = between(rel[:, 2:5], between(p1, p2))
    trans = np.hypot(err[:, 0], err[:, 1])
    rot = np.degrees(np.abs(err[:, 2]))
    short = np.abs(rel[:, 1] - rel[:, 0]) < SHORT_SPAN_S

    def mean(x: np.ndarray) -> float | None:
        return float(x.mean()) if len(x) else None

    return RelationsResult(len(rel), float(trans.mean()), float(trans.std()), float(rot.mean()), float(rot.std()),
                           int(short.sum()), mean(trans[short]), mean(rot[short]),
                           int((~short).sum()), mean(trans[~short]), mean(rot[~short]), path)
