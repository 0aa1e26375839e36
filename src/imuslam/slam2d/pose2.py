"""Planar poses as [x, y, theta] vectors (..., 3), the form the 2D SLAM stores: each operation is
:mod:`imuslam.geometry.se2`'s on the matrices (``from_xy_yaw`` / ``to_xy_yaw`` around it)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from imuslam.geometry import se2

FloatArray = NDArray[np.float64]


def wrap(a: ArrayLike) -> FloatArray:
    """Angle(s) wrapped to (-pi, pi]."""
    return np.asarray(np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2 * np.pi))


def _compose1(a: FloatArray, b: FloatArray) -> FloatArray:
    """One pose times one pose without the matrices (the per-scan hot path; equal to se2's)."""
    c, s = np.cos(a[2]), np.sin(a[2])
    return np.array(
        [a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], float(wrap(a[2] + b[2]))]
    )


def compose(T_a_b: ArrayLike, T_b_c: ArrayLike) -> FloatArray:
    """T_a_c = T_a_b T_b_c."""
    a, b = np.asarray(T_a_b, dtype=float), np.asarray(T_b_c, dtype=float)
    if a.shape == (3,) and b.shape == (3,):
        return _compose1(a, b)
    return se2.to_xy_yaw(se2.compose(se2.from_xy_yaw(T_a_b), se2.from_xy_yaw(T_b_c)))


def inverse(T_a_b: ArrayLike) -> FloatArray:
    return se2.to_xy_yaw(se2.inverse(se2.from_xy_yaw(T_a_b)))


def between(T_w_a: ArrayLike, T_w_b: ArrayLike) -> FloatArray:
    """T_a_b = T_w_a^-1 T_w_b."""
    a, b = np.asarray(T_w_a, dtype=float), np.asarray(T_w_b, dtype=float)
    if a.shape == (3,) and b.shape == (3,):
        c, s = np.cos(a[2]), np.sin(a[2])
        dx, dy = b[0] - a[0], b[1] - a[1]
        return np.array([c * dx + s * dy, -s * dx + c * dy, float(wrap(b[2] - a[2]))])
    return se2.to_xy_yaw(se2.between(se2.from_xy_yaw(T_w_a), se2.from_xy_yaw(T_w_b)))


def act(T_a_b: ArrayLike, p_b: ArrayLike) -> FloatArray:
    """Points (P, 2) of frame b into frame a."""
    return se2.act(se2.from_xy_yaw(T_a_b), p_b)


def act_each(T_a_b: ArrayLike, p_b: ArrayLike) -> FloatArray:
    """Each point (P, 2) by its own pose (P, 3)."""
    return se2.act(se2.from_xy_yaw(T_a_b), p_b)
