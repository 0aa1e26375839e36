"""Compiled SO(3) kernels (numba) for the inner loops of filters and integrators: single 3-vectors and
3x3 matrices, no batching. Same formulas as :mod:`imuslam.geometry.so3` (Sola 2018, eqs. 77-79, 143);
``tests/geometry`` checks them against it.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

__all__ = ["exp_into_nb", "exp_nb", "hat_nb", "log_nb", "right_jacobian_nb"]


@numba.njit(cache=True, inline="always")
def hat_nb(w: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """(3,) -> skew matrix (3, 3): ``hat_nb(a) @ b == cross(a, b)``."""
    K = np.zeros((3, 3))
    K[0, 1] = -w[2]
    K[0, 2] = w[1]
    K[1, 0] = w[2]
    K[1, 2] = -w[0]
    K[2, 0] = -w[1]
    K[2, 1] = w[0]
    return K


@numba.njit(cache=True, inline="always")
def exp_into_nb(
    wx: float, wy: float, wz: float, R: FloatArray
) -> None:  # pragma: no cover - compiled
    """Rotation vector (wx, wy, wz) rad -> rotation matrix written into ``R`` (3, 3), no allocation
    (Rodrigues, Taylor terms below 1e-8 rad): for per-point loops."""
    th2 = wx * wx + wy * wy + wz * wz
    th = np.sqrt(th2)
    if th < 1e-8:
        a = 1.0 - th2 / 6.0
        b = 0.5 - th2 / 24.0
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / th2
    R[0, 0] = 1.0 - b * (wy * wy + wz * wz)
    R[0, 1] = -a * wz + b * wx * wy
    R[0, 2] = a * wy + b * wx * wz
    R[1, 0] = a * wz + b * wx * wy
    R[1, 1] = 1.0 - b * (wx * wx + wz * wz)
    R[1, 2] = -a * wx + b * wy * wz
    R[2, 0] = -a * wy + b * wx * wz
    R[2, 1] = a * wx + b * wy * wz
    R[2, 2] = 1.0 - b * (wx * wx + wy * wy)


@numba.njit(cache=True, inline="always")
def exp_nb(w: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """Rotation vector (3,) rad -> rotation matrix (3, 3) (Rodrigues, Taylor terms below 1e-8 rad)."""
    R = np.empty((3, 3))
    exp_into_nb(w[0], w[1], w[2], R)
    return R


@numba.njit(cache=True)
def log_nb(R: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """Rotation matrix (3, 3) -> rotation vector (3,) rad, angle in [0, pi], through the quaternion
    (Shepperd's largest-component choice), accurate near pi."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q = np.empty(4)
    if tr > R[0, 0] and tr > R[1, 1] and tr > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + tr)
        q[0] = 0.25 * s
        q[1] = (R[2, 1] - R[1, 2]) / s
        q[2] = (R[0, 2] - R[2, 0]) / s
        q[3] = (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q[0] = (R[2, 1] - R[1, 2]) / s
        q[1] = 0.25 * s
        q[2] = (R[0, 1] + R[1, 0]) / s
        q[3] = (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q[0] = (R[0, 2] - R[2, 0]) / s
        q[1] = (R[0, 1] + R[1, 0]) / s
        q[2] = 0.25 * s
        q[3] = (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q[0] = (R[1, 0] - R[0, 1]) / s
        q[1] = (R[0, 2] + R[2, 0]) / s
        q[2] = (R[1, 2] + R[2, 1]) / s
        q[3] = 0.25 * s
    if q[0] < 0.0:
        q = -q
    n = np.sqrt(q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    out = np.zeros(3)
    if n < 1e-12:
        # small angle: theta ~ 2 v / w
        out[0] = 2.0 * q[1] / q[0]
        out[1] = 2.0 * q[2] / q[0]
        out[2] = 2.0 * q[3] / q[0]
        return out
    ang = 2.0 * np.arctan2(n, q[0])
    out[0] = ang * q[1] / n
    out[1] = ang * q[2] / n
    out[2] = ang * q[3] / n
    return out


@numba.njit(cache=True)
def right_jacobian_nb(w: FloatArray) -> FloatArray:  # pragma: no cover - compiled
    """Right Jacobian of SO(3) (3, 3) at the rotation vector w (3,). Sola 2018, eq. 143."""
    th2 = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
    th = np.sqrt(th2)
    K = hat_nb(w)
    if th < 1e-5:
        a = 0.5 - th2 / 24.0
        b = 1.0 / 6.0 - th2 / 120.0
    else:
        a = (1.0 - np.cos(th)) / th2
        b = (th - np.sin(th)) / (th2 * th)
    return np.eye(3) - a * K + b * (K @ K)
