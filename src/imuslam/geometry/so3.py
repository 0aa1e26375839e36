"""SO(3): hat, vee, exp, log and Jacobians, vectorised over leading dimensions.

Exp/log are Rodrigues' formulas with Taylor expansions near zero (Sola, Deray, Atchuthan, "A micro
Lie theory for state estimation in robotics", 2018, eqs. 77-79, 143-146).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

_SMALL = 1e-8


def hat(omega: ArrayLike) -> FloatArray:
    """Skew-symmetric matrix: ``hat(a) @ b == cross(a, b)``. (..., 3) -> (..., 3, 3)."""
    w = np.asarray(omega, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def vee(omega_hat: ArrayLike) -> FloatArray:
    """Inverse of :func:`hat` (antisymmetric part). (..., 3, 3) -> (..., 3)."""
    m = np.asarray(omega_hat, dtype=float)
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        axis=-1,
    )


def exp(theta: ArrayLike) -> FloatArray:
    """Rotation vector (..., 3), rad -> rotation matrix (..., 3, 3). Sola 2018, eq. 77."""
    th = np.asarray(theta, dtype=float)
    angle = np.linalg.norm(th, axis=-1)[..., None, None]
    K = hat(th)
    small = angle < _SMALL
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 1.0 - angle**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a * K + b * (K @ K)


def log(R: ArrayLike) -> FloatArray:
    """Rotation matrix (..., 3, 3) -> rotation vector (..., 3), rad, angle in [0, pi].

    Goes through the quaternion, which stays accurate near pi where the trace formula does not.
    """
    from imuslam.geometry.quaternion import quat_from_matrix, quat_to_rotvec

    return quat_to_rotvec(quat_from_matrix(R))


def rplus(R: ArrayLike, theta: ArrayLike) -> FloatArray:
    """Right perturbation ``R @ exp(theta)``."""
    return np.asarray(R, dtype=float) @ exp(theta)


def rminus(R1: ArrayLike, R2: ArrayLike) -> FloatArray:
    """``log(R2^T @ R1)``: the tangent taking R2 to R1 on the right."""
    R2a = np.asarray(R2, dtype=float)
    return log(np.swapaxes(R2a, -1, -2) @ np.asarray(R1, dtype=float))


def right_jacobian(theta: ArrayLike) -> FloatArray:
    """Right Jacobian of SO(3), (..., 3) -> (..., 3, 3). Sola 2018, eq. 143."""
    th = np.asarray(theta, dtype=float)
    angle = np.linalg.norm(th, axis=-1)[..., None, None]
    K = hat(th)
    small = angle < 1e-5
    safe = np.where(small, 1.0, angle)
    a = np.where(small, 0.5 - angle**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0 - angle**2 / 120.0, (safe - np.sin(safe)) / safe**3)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye - a * K + b * (K @ K)


def left_jacobian(theta: ArrayLike) -> FloatArray:
    """Left Jacobian of SO(3): ``J_l(theta) = J_r(-theta)``. Sola 2018, eq. 145."""
    return right_jacobian(-np.asarray(theta, dtype=float))
