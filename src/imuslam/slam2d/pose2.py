"""Planar poses [x, y, theta] (..., 3): compose, inverse, between, act (vectorised).

Provisional: replaced by ``imuslam.geometry.se2`` when that lands.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def wrap(a: FloatArray | float) -> FloatArray:
    """Angle(s) wrapped to (-pi, pi]."""
    return np.asarray(np.pi - np.mod(np.pi - np.asarray(a, dtype=float), 2 * np.pi))


def compose(T_a_b: FloatArray, T_b_c: FloatArray) -> FloatArray:
    """T_a_c = T_a_b T_b_c."""
    a, b = np.asarray(T_a_b, float), np.asarray(T_b_c, float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [a[..., 0] + c * b[..., 0] - s * b[..., 1], a[..., 1] + s * b[..., 0] + c * b[..., 1],
         wrap(a[..., 2] + b[..., 2])], axis=-1,
    )  # fmt: skip


def inverse(T_a_b: FloatArray) -> FloatArray:
    a = np.asarray(T_a_b, float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    return np.stack(
        [-c * a[..., 0] - s * a[..., 1], s * a[..., 0] - c * a[..., 1], wrap(-a[..., 2])], axis=-1
    )


def between(T_w_a: FloatArray, T_w_b: FloatArray) -> FloatArray:
    """T_a_b = T_w_a^-1 T_w_b."""
    return compose(inverse(T_w_a), T_w_b)


def act(T_a_b: FloatArray, p_b: FloatArray) -> FloatArray:
    """Points (P, 2) of frame b into frame a."""
    c, s = np.cos(T_a_b[2]), np.sin(T_a_b[2])
    return np.asarray(p_b, float) @ np.array([[c, s], [-s, c]]) + T_a_b[:2]


def to_matrix3(T: FloatArray) -> FloatArray:
    """(..., 3) -> 3D rotations (..., 3, 3) about z and positions (..., 3) with z = 0."""
    T = np.asarray(T, float)
    c, s = np.cos(T[..., 2]), np.sin(T[..., 2])
    R = np.zeros(T.shape[:-1] + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def act_each(T_a_b: FloatArray, p_b: FloatArray) -> FloatArray:
    """Each point (P, 2) by its own pose (P, 3)."""
    c, s = np.cos(T_a_b[:, 2]), np.sin(T_a_b[:, 2])
    x, y = p_b[:, 0], p_b[:, 1]
    return np.column_stack([c * x - s * y + T_a_b[:, 0], s * x + c * y + T_a_b[:, 1]])
