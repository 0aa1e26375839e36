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


def compose(T_a_b: ArrayLike, T_b_c: ArrayLike) -> FloatArray:
    """T_a_c = T_a_b T_b_c."""
    return se2.to_xy_yaw(se2.compose(se2.from_xy_yaw(T_a_b), se2.from_xy_yaw(T_b_c)))


def inverse(T_a_b: ArrayLike) -> FloatArray:
    return se2.to_xy_yaw(se2.inverse(se2.from_xy_yaw(T_a_b)))


def between(T_w_a: ArrayLike, T_w_b: ArrayLike) -> FloatArray:
    """T_a_b = T_w_a^-1 T_w_b."""
    return se2.to_xy_yaw(se2.between(se2.from_xy_yaw(T_w_a), se2.from_xy_yaw(T_w_b)))


def act(T_a_b: ArrayLike, p_b: ArrayLike) -> FloatArray:
    """Points (P, 2) of frame b into frame a."""
    return se2.act(se2.from_xy_yaw(T_a_b), p_b)


def act_each(T_a_b: ArrayLike, p_b: ArrayLike) -> FloatArray:
    """Each point (P, 2) by its own pose (P, 3)."""
    return se2.act(se2.from_xy_yaw(T_a_b), p_b)
