"""Association of two trajectories by time stamp."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from imuslam.errors import InputError
from imuslam.geometry.interp import interpolate_poses
from imuslam.interfaces.trajectory import Trajectory

IntArray = NDArray[np.int64]


def match_stamps(
    t1: NDArray[np.float64], t2: NDArray[np.float64], max_diff: float
) -> tuple[IntArray, IntArray]:
    """For each stamp of ``t1``, the nearest stamp of sorted ``t2`` within ``max_diff`` (s).

    Ties go to the earlier stamp of ``t2`` (evo's rule); a stamp of t2 may match several of t1.
    """
    if np.any(np.diff(t2) < 0):
        order = np.argsort(t2, kind="stable")
        i1, j = match_stamps(t1, t2[order], max_diff)
        return i1, order[j]
    idx = np.clip(np.searchsorted(t2, t1, side="right"), 0, len(t2) - 1)
    diff_ub = t2[idx] - t1
    diff_lb = np.where(idx > 0, t1 - t2[np.maximum(idx - 1, 0)], np.inf)
    use_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    use_lb = ~use_ub & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    inside = (t1 >= t2[0] - max_diff) & (t1 <= t2[-1] + max_diff)
    keep = inside & (use_ub | use_lb)
    best = np.where(use_ub, idx, idx - 1)
    return np.flatnonzero(keep).astype(np.int64), best[keep].astype(np.int64)


def associate(
    ref: Trajectory, est: Trajectory, max_diff_s: float = 0.01, min_pairs: int = 3
) -> tuple[Trajectory, Trajectory]:
    """Pairs of poses with nearest stamps: the shorter trajectory is matched into the longer (as evo).

    Raises InputError when the time ranges do not overlap or fewer than ``min_pairs`` pairs are found.
    """
    if ref.t_ns[-1] < est.t_ns[0] or est.t_ns[-1] < ref.t_ns[0]:
        raise InputError(
            f"{est.source} ({est.t_s[0]:.3f}-{est.t_s[-1]:.3f} s) and {ref.source} "
            f"({ref.t_s[0]:.3f}-{ref.t_s[-1]:.3f} s) do not overlap in time"
        )
    second_longer = len(est) > len(ref)
    short, longer = (ref, est) if second_longer else (est, ref)
    i_s, i_l = match_stamps(short.t_s, longer.t_s, max_diff_s)
    if len(i_s) < min_pairs:
        raise InputError(
            f"{est.source} vs {ref.source}: {len(i_s)} poses associated within {max_diff_s} s "
            f"(at least {min_pairs} needed)"
        )
    a, b = short.subset(i_s), longer.subset(i_l)
    return (a, b) if second_longer else (b, a)


def interpolate(traj: Trajectory, t_ns: NDArray[np.int64]) -> Trajectory:
    """Poses at ``t_ns`` (within the span): linear in position, geodesic (slerp) in rotation."""
    t = traj.t_ns
    if t_ns.min() < t[0] or t_ns.max() > t[-1]:
        raise InputError(f"{traj.source}: interpolation times leave the trajectory's span")
    p, R = interpolate_poses(t, traj.p_w, traj.R_w_b, t_ns)
    return Trajectory(t_ns, p, R, traj.source)
