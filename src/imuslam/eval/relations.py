"""The SLAM benchmark metric of Kümmerle et al., "On measuring the accuracy of SLAM algorithms",
Autonomous Robots 27(4), 2009: errors of relative displacements between pairs of poses,
``eps = 1/N sum (delta_ij (-) delta*_ij)^2``, reported as the mean (and std) of the absolute translational
and rotational parts, the reference relations ``delta*_ij`` taken from corrected poses.

The corrected Radish logs carry another time base than the raw benchmark logs, so scans are associated
by their range readings (equal to the centimetre), in order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


def _keys(ranges: NDArray[np.floating]) -> list[bytes]:
    r = np.where(np.isfinite(ranges), np.round(np.asarray(ranges, float) * 100.0), -1.0).astype(
        np.int32
    )
    return [row.tobytes() for row in r]


def associate_by_ranges(
    ref_ranges: NDArray[np.floating], est_ranges: NDArray[np.floating]
) -> tuple[IntArray, IntArray]:
    """Index pairs (i_ref, i_est) of scans with the same readings (to 1 cm), matched in order (each est scan
    at most once, est indices increasing). Both (N, B) with NaN for no return."""
    if ref_ranges.shape[1] != est_ranges.shape[1]:
        raise InputError(
            f"reference scans have {ref_ranges.shape[1]} readings, estimate scans {est_ranges.shape[1]}"
        )
    where: dict[bytes, list[int]] = {}
    for i, k in enumerate(_keys(est_ranges)):
        where.setdefault(k, []).append(i)
    ri: list[int] = []
    ei: list[int] = []
    last = -1
    for i, k in enumerate(_keys(ref_ranges)):
        cands = [j for j in where.get(k, []) if j > last]
        if cands:
            last = cands[0]
            ri.append(i)
            ei.append(last)
    return np.array(ri, np.int64), np.array(ei, np.int64)


def _between(a: FloatArray, b: FloatArray) -> FloatArray:
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.stack(
        [c * dx + s * dy, -s * dx + c * dy, np.angle(np.exp(1j * (b[:, 2] - a[:, 2])))], axis=1
    )


@dataclass
class RelationError:
    """Kümmerle 2009 errors over ``n`` relations: absolute translation (m) and rotation (deg), mean and
    std, and the squared means (m^2, deg^2)."""

    n: int
    trans_mean: float
    trans_std: float
    rot_mean_deg: float
    rot_std_deg: float
    trans_sq_mean: float
    rot_sq_mean_deg2: float


def relation_error(
    est_xy_yaw: FloatArray, ref_xy_yaw: FloatArray, i: IntArray, j: IntArray
) -> RelationError:
    """Errors of the relations (i, j) of the estimate against the reference (both (N, 3) [x, y, yaw]).
    As Kümmerle 2009, eq. 2: the difference of the relative displacements, its translation norm and
    absolute angle."""
    if len(i) == 0:
        raise ValueError("no relations to evaluate")
    de = _between(est_xy_yaw[i], est_xy_yaw[j])
    dr = _between(ref_xy_yaw[i], ref_xy_yaw[j])
    et = np.hypot(de[:, 0] - dr[:, 0], de[:, 1] - dr[:, 1])
    er = np.rad2deg(np.abs(np.angle(np.exp(1j * (de[:, 2] - dr[:, 2])))))
    return RelationError(
        len(i), float(et.mean()), float(et.std()), float(er.mean()), float(er.std()),
        float(np.mean(et**2)), float(np.mean(er**2)),
    )  # fmt: skip


def consecutive_relations(n: int, step: int = 1) -> tuple[IntArray, IntArray]:
    """Pairs (k, k + step) of the associated poses."""
    k = np.arange(0, n - step, dtype=np.int64)
    return k, k + step


def separation_relations(ref_xy_yaw: FloatArray, separation_m: float) -> tuple[IntArray, IntArray]:
    """Pairs (i, j): for every reference pose i, the first later pose j at least ``separation_m`` from it
    along the reference path (the path length of the reference poses between them). Kümmerle et al. 2009
    define the metric for any set of relations; theirs mix short relations with long ones (section 5);
    a longer separation lets an estimator's drift between the two poses show."""
    step = np.hypot(*np.diff(ref_xy_yaw[:, :2], axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(step)])
    j = np.searchsorted(s, s + separation_m, side="left")
    i = np.flatnonzero(j < len(s)).astype(np.int64)
    return i, j[i].astype(np.int64)


def loop_relations(
    ref_xy_yaw: FloatArray, t_s: FloatArray, radius_m: float = 2.0, min_dt_s: float = 60.0
) -> tuple[IntArray, IntArray]:
    """Pairs (i, j), i < j, of reference poses within ``radius_m`` of each other and more than
    ``min_dt_s`` apart in time (``t_s`` of each pose): the same place seen again after a loop, the
    relations that only a consistent map gets right (Kümmerle 2009's relations span loops as well)."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(ref_xy_yaw[:, :2]).query_pairs(radius_m, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i, j = np.minimum(pairs[:, 0], pairs[:, 1]), np.maximum(pairs[:, 0], pairs[:, 1])
    d = np.hypot(*(ref_xy_yaw[i, :2] - ref_xy_yaw[j, :2]).T)
    keep = (np.abs(t_s[j] - t_s[i]) > min_dt_s) & (d < radius_m)
    order = np.lexsort((j[keep], i[keep]))
    return i[keep][order].astype(np.int64), j[keep][order].astype(np.int64)
