"""Z-Y-X (yaw, pitch, roll) Euler angles: ``R_w_b = Rz(yaw) Ry(pitch) Rx(roll)``, angles ordered
``[roll, pitch, yaw]`` rad in every array (ROS' RPY), and their rates.

Body rates from the angle derivatives: ``omega_b = [droll - dyaw s(p), dpitch c(r) + dyaw s(r) c(p),
-dpitch s(r) + dyaw c(r) c(p)]`` (Titterton & Weston, "Strapdown Inertial Navigation Technology",
eq. 3.46, inverted).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = ["euler_rates_to_body", "euler_to_matrix", "matrix_to_euler"]


def euler_to_matrix(angles: ArrayLike) -> FloatArray:
    """(..., 3) [roll, pitch, yaw] rad -> R_w_b (..., 3, 3) = Rz(yaw) Ry(pitch) Rx(roll)."""
    a = np.asarray(angles, dtype=float)
    r, p, y = a[..., 0], a[..., 1], a[..., 2]
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    R = np.empty(a.shape[:-1] + (3, 3))
    R[..., 0, 0] = cy * cp
    R[..., 0, 1] = cy * sp * sr - sy * cr
    R[..., 0, 2] = cy * sp * cr + sy * sr
    R[..., 1, 0] = sy * cp
    R[..., 1, 1] = sy * sp * sr + cy * cr
    R[..., 1, 2] = sy * sp * cr - cy * sr
    R[..., 2, 0] = -sp
    R[..., 2, 1] = cp * sr
    R[..., 2, 2] = cp * cr
    return R


def matrix_to_euler(R: ArrayLike) -> FloatArray:
    """R_w_b (..., 3, 3) -> (..., 3) [roll, pitch, yaw] rad, pitch in [-pi/2, pi/2]; the inverse of
    :func:`euler_to_matrix` away from pitch = +-90 deg (gimbal lock, where roll + yaw is what is defined)."""
    M = np.asarray(R, dtype=float)
    pitch = np.arcsin(np.clip(-M[..., 2, 0], -1.0, 1.0))
    roll = np.arctan2(M[..., 2, 1], M[..., 2, 2])
    yaw = np.arctan2(M[..., 1, 0], M[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def euler_rates_to_body(angles: ArrayLike, rates: ArrayLike) -> FloatArray:
    """Body angular rate (..., 3), rad/s, from [roll, pitch, yaw] (..., 3) and their time derivatives."""
    a = np.asarray(angles, dtype=float)
    d = np.asarray(rates, dtype=float)
    r, p = a[..., 0], a[..., 1]
    dr, dp, dy = d[..., 0], d[..., 1], d[..., 2]
    return np.stack(
        [
            dr - dy * np.sin(p),
            dp * np.cos(r) + dy * np.sin(r) * np.cos(p),
            -dp * np.sin(r) + dy * np.cos(r) * np.cos(p),
        ],
        axis=-1,
    )
