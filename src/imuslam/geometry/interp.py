"""Pose interpolation, the one copy: linear in position, geodesic (slerp) in rotation.

``R(t) = R_k exp(a log(R_k^T R_k+1))`` with ``a = (t - t_k) / (t_k+1 - t_k)`` (Shoemake's slerp written
on SO(3)), the same as scipy's ``Slerp`` and evo's interpolation.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imuslam.geometry.so3 import exp, log

FloatArray = NDArray[np.float64]

__all__ = ["interpolate_linear", "interpolate_poses", "interval_weights"]


def interval_weights(t: ArrayLike, t_query: ArrayLike) -> tuple[NDArray[np.int64], FloatArray]:
    """For sorted stamps ``t`` (N,) and queries (M,) inside [t[0], t[-1]]: the interval index k (M,)
    and the weight a in [0, 1] (M,) with ``t_query = (1 - a) t[k] + a t[k+1]``. Integer stamps (ns)
    are differenced as integers first, so no precision is lost to large absolute times."""
    ta = np.asarray(t)
    tq = np.asarray(t_query)
    k = np.clip(np.searchsorted(ta, tq, side="right") - 1, 0, len(ta) - 2).astype(np.int64)
    a = (tq - ta[k]).astype(float) / (ta[k + 1] - ta[k]).astype(float)
    return k, a


def interpolate_linear(t: ArrayLike, values: ArrayLike, t_query: ArrayLike) -> FloatArray:
    """Linear interpolation of (N, ...) values at the queries (M,) -> (M, ...)."""
    v = np.asarray(values, dtype=float)
    k, a = interval_weights(t, t_query)
    a = a.reshape(a.shape + (1,) * (v.ndim - 1))
    return v[k] * (1.0 - a) + v[k + 1] * a


def interpolate_poses(
    t: ArrayLike, p: ArrayLike, R: ArrayLike, t_query: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """Positions (M, 3) and rotations (M, 3, 3) at ``t_query`` from poses (N, 3), (N, 3, 3) at sorted
    ``t``. Queries must lie inside [t[0], t[-1]] (the caller names the data in its error)."""
    Ra = np.asarray(R, dtype=float)
    pa = np.asarray(p, dtype=float)
    k, a = interval_weights(t, t_query)
    p_q = pa[k] * (1.0 - a[:, None]) + pa[k + 1] * a[:, None]
    d = log(np.swapaxes(Ra[k], -1, -2) @ Ra[k + 1])
    return p_q, Ra[k] @ exp(d * a[:, None])
